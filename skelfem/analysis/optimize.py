"""Trajectory optimisation: tendon schedules that put a marker on timed targets.

Every tendon (ligaments are never controls) gets a piecewise-linear schedule
on K knots at t_k = k T / (K - 1) (T the run's duration), its values u_ck
bounded by 0 <= u_ck <= upper_c. The objective is

    J(u) = sum_i |y(t_i) - y'_i|^2 + rho sum_c sum_k (u_c,k+1 - u_c,k)^2,

the first part from a forward run, its gradient from the discrete adjoint
(skelfem.analysis.adjoint: one forward run and one reverse sweep per evaluation;
through friction, one tangent sweep of every knot together), the
smoothness regulariser rho (mm^2 per mm^2) in closed form. scipy's L-BFGS-B
minimises it within the bounds; it stops once every target is within tol
(default 1e-3 x finger length), or when L-BFGS-B converges or runs out of
evaluations. ``method="gauss-newton"`` instead solves the bounded
least-squares problem with scipy's trust-region reflective method on the
Jacobian of the residuals from the forward (tangent) sensitivities. The best evaluation found is returned,
with reached = false if
a target is still further than tol. Through contact and ground friction
the gradient is exact on the forward run's branch; through cable friction,
or on several MPI processes, it holds friction at each step
(``gradient = "friction held"``, see skelfem.analysis.adjoint); the errors
are those of exact forward runs.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

log = logging.getLogger("skelfem")

TOL_FRACTION = 1e-3        # default tolerance: this fraction of the finger length
UPPER_FRACTION = 0.25      # default upper bound of a contraction: this fraction of the tendon's length
DEFAULT_SMOOTH = 1e-6      # rho
START_FRACTION = 0.1       # Gauss-Newton's start: this fraction of each upper bound
FAILED_FACTOR = 10.0       # L-BFGS-B: a failed forward run's J is this times the worst J seen


class _Reached(Exception):
    """Raised inside the objective to stop L-BFGS-B once every target is within tol."""


class _Budget(Exception):
    """Raised inside the objective once max_evaluations forward runs are spent."""


@dataclass
class OptimizeResult:
    names: list                     # tendons, in design order
    knot_times: np.ndarray          # (K,)
    schedules: np.ndarray           # (n_tendons, K) mm
    positions: np.ndarray           # achieved marker positions at the targets' times
    errors: np.ndarray              # mm, per target
    reached: bool
    status: str
    objective: float
    iterations: int = 0
    forward_runs: int = 0
    adjoint_sweeps: int = 0
    failed_runs: int = 0
    time: float = 0.0
    history: list = field(default_factory=list)     # (objective, max error) per evaluation
    upper: np.ndarray | None = None
    gradient: str = "exact"         # "friction held": approximate through friction (skelfem.analysis.adjoint)

    @property
    def error(self) -> float:
        return float(self.errors.max()) if len(self.errors) else 0.0


def schedule_items(names, knot_times, values) -> dict:
    """{--set key: schedule} of every tendon."""
    return {f"cables.{n}.schedule": [[float(t), float(u)] for t, u in zip(knot_times, row)]
            for n, row in zip(names, values)}


METHODS = ("lbfgsb", "gauss-newton")


def optimize_schedules(session, marker: str, targets, knots: int = 4, upper: dict | None = None,
                       smooth: float = DEFAULT_SMOOTH, tol: float | None = None, max_evaluations: int = 60,
                       start=None, method: str = "lbfgsb") -> OptimizeResult:
    """Schedules of every tendon on `knots` knots that bring `marker` to targets [(t, point)].

    method "lbfgsb": L-BFGS-B on J with the adjoint gradient (one reverse sweep per run);
    "gauss-newton": scipy's bounded trust-region least squares (trf) on the residuals
    y(t_i) - y'_i and sqrt(rho) (u_k+1 - u_k), Jacobian from the forward sensitivities
    (one multi-column tangent sweep per run).
    """
    from scipy.optimize import least_squares, minimize

    from .adjoint import TimedTarget, schedule_gradient, schedule_sensitivities

    if method not in METHODS:
        raise ValueError(f"unknown method {method!r} (one of {', '.join(METHODS)})")
    from .control import body_extent

    t0 = time.perf_counter()
    design, model = session.design, session.model
    spec = design.dynamics
    names = [c.name for c in design.tendons]
    if not names:
        raise ValueError("no tendon to steer")
    knot_times = np.round(np.linspace(0.0, spec.duration, knots), 12)
    lengths = {c.name: float(np.linalg.norm(np.diff(c.path, axis=0), axis=1).sum()) for c in design.tendons}
    ub = np.array([(upper or {}).get(n, UPPER_FRACTION * lengths[n]) for n in names])
    timed = [TimedTarget(marker, float(t), np.asarray(p, float)) for t, p in targets]
    tol = TOL_FRACTION * body_extent(model) if tol is None else float(tol)
    m, K = len(names), knots
    from_rest = start is None and method == "lbfgsb"
    if start is None:
        # from rest for L-BFGS-B; Gauss-Newton starts inside the box: at u = 0 the tendons go slack
        # during the motion and the (taut-branch) linearisation misleads it
        start = np.zeros(m * K) if method == "lbfgsb" else np.repeat(START_FRACTION * ub, K)
    x0 = np.clip(np.asarray(start, float).ravel(), 0.0, np.repeat(ub, K))
    D = np.diff(np.eye(K), axis=0)                      # (K-1, K) differences
    best = {"J": np.inf}
    counts = {"forward": 0, "adjoint": 0, "failed": 0, "evaluations": 0}
    history = []

    def schedules(x):
        """Spend one evaluation of the budget: set the schedules of x; returns them as (m, K)."""
        if counts["evaluations"] >= max_evaluations:
            raise _Budget
        counts["evaluations"] += 1
        U = x.reshape(m, K)
        session.set(schedule_items(names, knot_times, U))
        return U

    def evaluate(x):
        U = schedules(x)
        try:
            r = schedule_gradient(session, timed)
        except RuntimeError:                             # a forward run failed: a wall for L-BFGS-B, ...
            counts["failed"] += 1
            counts["forward"] += 1
            # ... FAILED_FACTOR times the worst J seen: its line search interpolates back to a step part way
            # (1e30 sent it back to the start, where it stopped)
            seen = [h[0] for h in history]
            return (FAILED_FACTOR * max(seen) if seen else 1e30), np.zeros_like(x)
        counts["forward"] += 1
        counts["adjoint"] += 1
        reg = smooth * float(np.sum((U @ D.T) ** 2))
        J = r.value + reg
        g = np.concatenate([r.gradient.get(n, np.zeros(K)) for n in names]) + \
            (2.0 * smooth * (U @ D.T) @ D).ravel()
        errors = np.array([np.linalg.norm(p - tt.target) for p, tt in zip(r.positions, timed)])
        history.append((float(J), float(errors.max())))
        if J < best["J"]:
            best.update(J=J, x=x.copy(), positions=np.array(r.positions), errors=errors)
        if errors.max() <= tol:
            raise _Reached
        return J, g

    def residuals(x):
        """(residual vector, Jacobian) at x, cached for least_squares' separate fun / jac calls."""
        key = x.tobytes()
        if cache.get("key") == key:
            return cache["value"]
        U = schedules(x)
        try:
            r, Jac, _ = schedule_sensitivities(session, timed)
        except RuntimeError:
            counts["failed"] += 1
            counts["forward"] += 1
            raise _Budget from None
        counts["forward"] += 1
        counts["adjoint"] += 1                           # a tangent sweep
        Jfull = np.zeros((len(r), m * K))
        cols = {n: i for i, n in enumerate(names)}
        scheduled = [n for n in names if session.design.cable(n).schedule is not None]
        for j, n in enumerate(scheduled):
            Jfull[:, cols[n] * K:(cols[n] + 1) * K] = Jac[:, j * K:(j + 1) * K]
        sq = np.sqrt(smooth)
        reg_r = (sq * (U @ D.T)).ravel()
        reg_J = np.kron(np.eye(m), sq * D)
        value = (np.concatenate([r, reg_r]), np.vstack([Jfull, reg_J]))
        cache.update(key=key, value=value)
        errors = np.linalg.norm(r.reshape(len(timed), -1), axis=1)
        J = float(value[0] @ value[0])
        history.append((J, float(errors.max())))
        positions = r.reshape(len(timed), -1) + np.array([tt.target for tt in timed])
        if J < best["J"]:
            best.update(J=J, x=x.copy(), positions=positions, errors=errors)
        if errors.max() <= tol:
            raise _Reached
        return value

    cache: dict = {}
    status = "max_evaluations"
    its = [0]
    if method == "gauss-newton":
        try:
            res = least_squares(lambda x: residuals(x)[0], x0, jac=lambda x: residuals(x)[1],
                                bounds=(np.zeros(m * K), np.repeat(ub, K)), method="trf",
                                x_scale=1.0, max_nfev=max_evaluations, ftol=1e-15, xtol=1e-15, gtol=1e-15)
            status = "converged" if res.status > 0 else "max_evaluations"
        except _Reached:
            status = "reached"
        except _Budget:
            status = "max_evaluations"
        its[0] = counts["evaluations"]                   # trf: one Jacobian per evaluation
        return _result(session, names, knot_times, best, tol, status, its[0], counts, history, ub, m, K, t0)

    def count(_):
        its[0] += 1

    first: dict = {}

    def objective(x):
        """evaluate, but the start's evaluation (made below) is not spent twice."""
        got = first.pop(x.tobytes(), None)
        return got if got is not None else evaluate(x)

    try:
        if from_rest:
            J0, g0 = evaluate(x0)
            if np.any(g0):
                first[x0.tobytes()] = (J0, g0)
            else:                    # every tendon slack through the run (a body sagging under gravity): no
                x0 = np.repeat(START_FRACTION * ub, K)   # direction from rest; start inside the box instead
                log.info("optimize: no gradient from rest (tendons slack); starting at %g of each bound",
                         START_FRACTION)
        res = minimize(objective, x0, jac=True, method="L-BFGS-B", bounds=[(0.0, u) for u in np.repeat(ub, K)],
                       callback=count, options={"maxfun": max_evaluations, "maxiter": max_evaluations,
                                                "ftol": 1e-15, "gtol": 1e-12})
        status = "converged" if res.success else ("max_evaluations" if res.status == 1 else "line_search_failed")
    except _Reached:
        status = "reached"
    except _Budget:
        status = "max_evaluations"
    return _result(session, names, knot_times, best, tol, status, its[0], counts, history, ub, m, K, t0)


def _result(session, names, knot_times, best, tol, status, iterations, counts, history, ub, m, K, t0):
    if "x" not in best:
        raise RuntimeError("no forward run of the optimisation succeeded")
    U = best["x"].reshape(m, K)
    session.set(schedule_items(names, knot_times, U))
    reached = bool(best["errors"].max() <= tol)
    return OptimizeResult(names, knot_times, U, best["positions"], best["errors"], reached,
                          "reached" if reached else status, float(best["J"]), iterations,
                          counts["forward"], counts["adjoint"], counts["failed"], time.perf_counter() - t0,
                          history, ub, _gradient_kind(session.model))


def _gradient_kind(model) -> str:
    """"exact", or "friction held" where the gradient holds friction at each step (cable friction, MPI)."""
    from .adjoint import follows_anchors
    return "friction held" if model.path_dependent and not follows_anchors(model) else "exact"
