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


class _Stop(Exception):
    """Ends scipy's search from inside its objective (scipy has no other way out): every target is within
    tol ("reached") or the evaluations are spent ("max_evaluations")."""

    def __init__(self, status: str):
        super().__init__(status)
        self.status = status


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
    from .adjoint import TimedTarget
    from .control import body_extent

    if method not in METHODS:
        raise ValueError(f"unknown method {method!r} (one of {', '.join(METHODS)})")
    t0 = time.perf_counter()
    design, model = session.design, session.model
    names = [c.name for c in design.tendons]
    if not names:
        raise ValueError("no tendon to steer")
    knot_times = np.round(np.linspace(0.0, design.dynamics.duration, knots), 12)
    lengths = {c.name: float(np.linalg.norm(np.diff(c.path, axis=0), axis=1).sum()) for c in design.tendons}
    ub = np.array([(upper or {}).get(n, UPPER_FRACTION * lengths[n]) for n in names])
    timed = [TimedTarget(marker, float(t), np.asarray(p, float)) for t, p in targets]
    tol = TOL_FRACTION * body_extent(model) if tol is None else float(tol)
    search = ScheduleSearch(session, names, knot_times, timed, ub, smooth, tol, max_evaluations)
    from_rest = start is None and method == "lbfgsb"
    if start is None:
        # from rest for L-BFGS-B; Gauss-Newton starts inside the box: at u = 0 the tendons go slack
        # during the motion and the (taut-branch) linearisation misleads it
        start = np.zeros(search.size) if method == "lbfgsb" else np.repeat(START_FRACTION * ub, knots)
    x0 = np.clip(np.asarray(start, float).ravel(), 0.0, search.upper)
    if method == "gauss-newton":
        status, iterations = _gauss_newton(search, x0)
    else:
        status, iterations = _lbfgsb(search, x0, from_rest)
    return search.result(status, iterations, time.perf_counter() - t0)


class ScheduleSearch:
    """One optimisation: the problem (tendons, knots, bounds, timed targets, rho, tol, the budget of
    evaluations) and what the search found so far (the best evaluation, the counts, the history).
    Each evaluation sets the schedules of x on the session and runs it forward."""

    def __init__(self, session, names: list, knot_times: np.ndarray, timed: list, ub: np.ndarray,
                 smooth: float, tol: float, max_evaluations: int):
        self.session, self.names, self.knot_times, self.timed = session, names, knot_times, timed
        self.ub, self.smooth, self.tol, self.max_evaluations = ub, smooth, tol, max_evaluations
        self.m, self.K = len(names), len(knot_times)
        self.D = np.diff(np.eye(self.K), axis=0)            # (K-1, K) differences
        self.best: dict = {"J": np.inf}
        self.counts = {"forward": 0, "adjoint": 0, "failed": 0, "evaluations": 0}
        self.history: list = []                             # (J, max error) per evaluation
        self._cached: tuple | None = None                   # (x's bytes, residuals and Jacobian) of the last

    @property
    def size(self) -> int:
        return self.m * self.K

    @property
    def upper(self) -> np.ndarray:
        """The upper bound of each of x's entries (tendon by tendon, knot by knot)."""
        return np.repeat(self.ub, self.K)

    def set_schedules(self, x: np.ndarray) -> np.ndarray:
        """Spend one evaluation of the budget: set the schedules of x; returns them as (m, K)."""
        if self.counts["evaluations"] >= self.max_evaluations:
            raise _Stop("max_evaluations")
        self.counts["evaluations"] += 1
        U = x.reshape(self.m, self.K)
        self.session.set(schedule_items(self.names, self.knot_times, U))
        return U

    def record(self, J: float, x: np.ndarray, positions: np.ndarray, errors: np.ndarray) -> None:
        """Keep an evaluation (the best so far, the history); stop once every target is within tol."""
        self.history.append((float(J), float(errors.max())))
        if J < self.best["J"]:
            self.best.update(J=J, x=x.copy(), positions=positions, errors=errors)
        if errors.max() <= self.tol:
            raise _Stop("reached")

    def objective(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        """J and its gradient (adjoint) at x. A failed forward run is a wall for L-BFGS-B: FAILED_FACTOR
        times the worst J seen, so that its line search interpolates back to a step part way (1e30 sent
        it back to the start, where it stopped)."""
        from .adjoint import schedule_gradient

        U = self.set_schedules(x)
        self.counts["forward"] += 1
        try:
            r = schedule_gradient(self.session, self.timed)
        except RuntimeError:
            self.counts["failed"] += 1
            seen = [h[0] for h in self.history]
            return (FAILED_FACTOR * max(seen) if seen else 1e30), np.zeros_like(x)
        self.counts["adjoint"] += 1
        J = r.value + self.smooth * float(np.sum((U @ self.D.T) ** 2))
        g = np.concatenate([r.gradient.get(n, np.zeros(self.K)) for n in self.names]) + \
            (2.0 * self.smooth * (U @ self.D.T) @ self.D).ravel()
        errors = np.array([np.linalg.norm(p - tt.target) for p, tt in zip(r.positions, self.timed)])
        self.record(J, x, np.array(r.positions), errors)
        return J, g

    def residuals(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(residual vector, Jacobian) at x (forward sensitivities), kept for least_squares' separate
        fun and jac calls at the same x. A failed forward run ends the search."""
        from .adjoint import schedule_sensitivities

        key = x.tobytes()
        if self._cached is not None and self._cached[0] == key:
            return self._cached[1]
        U = self.set_schedules(x)
        self.counts["forward"] += 1
        try:
            r, Jac, _ = schedule_sensitivities(self.session, self.timed)
        except RuntimeError:
            self.counts["failed"] += 1
            raise _Stop("max_evaluations") from None
        self.counts["adjoint"] += 1                         # a tangent sweep
        m, K = self.m, self.K
        Jfull = np.zeros((len(r), m * K))
        cols = {n: i for i, n in enumerate(self.names)}
        scheduled = [n for n in self.names if self.session.design.cable(n).schedule is not None]
        for j, n in enumerate(scheduled):
            Jfull[:, cols[n] * K:(cols[n] + 1) * K] = Jac[:, j * K:(j + 1) * K]
        sq = np.sqrt(self.smooth)
        value = (np.concatenate([r, (sq * (U @ self.D.T)).ravel()]),
                 np.vstack([Jfull, np.kron(np.eye(m), sq * self.D)]))
        self._cached = (key, value)
        errors = np.linalg.norm(r.reshape(len(self.timed), -1), axis=1)
        positions = r.reshape(len(self.timed), -1) + np.array([tt.target for tt in self.timed])
        self.record(float(value[0] @ value[0]), x, positions, errors)
        return value

    def result(self, status: str, iterations: int, seconds: float) -> OptimizeResult:
        """The best evaluation's schedules, set on the session, as an OptimizeResult."""
        best = self.best
        if "x" not in best:
            raise RuntimeError("no forward run of the optimisation succeeded")
        U = best["x"].reshape(self.m, self.K)
        self.session.set(schedule_items(self.names, self.knot_times, U))
        reached = bool(best["errors"].max() <= self.tol)
        return OptimizeResult(self.names, self.knot_times, U, best["positions"], best["errors"], reached,
                              "reached" if reached else status, float(best["J"]), iterations,
                              self.counts["forward"], self.counts["adjoint"], self.counts["failed"], seconds,
                              self.history, self.ub, _gradient_kind(self.session.model))


def _gauss_newton(search: ScheduleSearch, x0: np.ndarray) -> tuple[str, int]:
    """scipy's bounded trust-region least squares (trf) from x0: (status, iterations)."""
    from scipy.optimize import least_squares

    status = "max_evaluations"
    try:
        res = least_squares(lambda x: search.residuals(x)[0], x0, jac=lambda x: search.residuals(x)[1],
                            bounds=(np.zeros(search.size), search.upper), method="trf",
                            x_scale=1.0, max_nfev=search.max_evaluations, ftol=1e-15, xtol=1e-15, gtol=1e-15)
        status = "converged" if res.status > 0 else "max_evaluations"
    except _Stop as stop:
        status = stop.status
    return status, search.counts["evaluations"]          # trf: one Jacobian per evaluation


def _lbfgsb(search: ScheduleSearch, x0: np.ndarray, from_rest: bool) -> tuple[str, int]:
    """L-BFGS-B on J with the adjoint gradient from x0: (status, iterations). From rest, the start's
    evaluation is made first (and not spent twice); with no gradient there (every tendon slack through
    the run, a body sagging under gravity) it starts inside the box instead."""
    from scipy.optimize import minimize

    iterations = 0
    first: dict = {}

    def count(_):
        nonlocal iterations
        iterations += 1

    def objective(x):
        got = first.pop(x.tobytes(), None)
        return got if got is not None else search.objective(x)

    status = "max_evaluations"
    try:
        if from_rest:
            J0, g0 = search.objective(x0)
            if np.any(g0):
                first[x0.tobytes()] = (J0, g0)
            else:
                x0 = np.repeat(START_FRACTION * search.ub, search.K)
                log.info("optimize: no gradient from rest (tendons slack); starting at %g of each bound",
                         START_FRACTION)
        res = minimize(objective, x0, jac=True, method="L-BFGS-B", bounds=[(0.0, u) for u in search.upper],
                       callback=count, options={"maxfun": search.max_evaluations, "maxiter": search.max_evaluations,
                                                "ftol": 1e-15, "gtol": 1e-12})
        status = "converged" if res.success else ("max_evaluations" if res.status == 1 else "line_search_failed")
    except _Stop as stop:
        status = stop.status
    return status, iterations


def _gradient_kind(model) -> str:
    """"exact", or "friction held" where the gradient holds friction at each step (cable friction, MPI)."""
    from .adjoint import follows_anchors
    return "friction held" if model.path_dependent and not follows_anchors(model) else "exact"
