"""Trajectory optimisation: tendon schedules that put a marker on timed targets.

Every tendon (ligaments are never controls) gets a piecewise-linear schedule
on K knots at t_k = k T / (K - 1) (T the run's duration), its values u_ck
bounded by 0 <= u_ck <= upper_c. The objective is

    J(u) = sum_i |y(t_i) - y'_i|^2 + rho sum_c sum_k (u_c,k+1 - u_c,k)^2,

the first part from a forward run, its gradient from the discrete adjoint
(skelfem.adjoint: one forward run and one reverse sweep per evaluation), the
smoothness regulariser rho (mm^2 per mm^2) in closed form. scipy's L-BFGS-B
minimises it within the bounds; it stops once every target is within tol
(default 1e-3 x finger length), or when L-BFGS-B converges or runs out of
evaluations. The best evaluation found is returned, with reached = false if
a target is still further than tol.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

TOL_FRACTION = 1e-3        # default tolerance: this fraction of the finger length
UPPER_FRACTION = 0.25      # default upper bound of a contraction: this fraction of the tendon's length
DEFAULT_SMOOTH = 1e-6      # rho


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

    @property
    def error(self) -> float:
        return float(self.errors.max()) if len(self.errors) else 0.0


def schedule_items(names, knot_times, values) -> dict:
    """{--set key: schedule} of every tendon."""
    return {f"cables.{n}.schedule": [[float(t), float(u)] for t, u in zip(knot_times, row)]
            for n, row in zip(names, values)}


def optimize_schedules(session, marker: str, targets, knots: int = 4, upper: dict | None = None,
                       smooth: float = DEFAULT_SMOOTH, tol: float | None = None, max_evaluations: int = 60,
                       start=None) -> OptimizeResult:
    """Schedules of every tendon on `knots` knots that bring `marker` to targets [(t, point)]."""
    from scipy.optimize import minimize

    from .adjoint import TimedTarget, schedule_gradient
    from .control import finger_length

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
    tol = TOL_FRACTION * finger_length(model) if tol is None else float(tol)
    m, K = len(names), knots
    x0 = np.zeros(m * K) if start is None else np.clip(np.asarray(start, float).ravel(), 0.0, np.repeat(ub, K))
    D = np.diff(np.eye(K), axis=0)                      # (K-1, K) differences
    best = {"J": np.inf}
    counts = {"forward": 0, "adjoint": 0, "failed": 0, "evaluations": 0}
    history = []

    def evaluate(x):
        if counts["evaluations"] >= max_evaluations:
            raise _Budget
        counts["evaluations"] += 1
        U = x.reshape(m, K)
        session.set(schedule_items(names, knot_times, U))
        try:
            r = schedule_gradient(session, timed)
        except RuntimeError:                             # a forward run failed: a wall for L-BFGS-B
            counts["failed"] += 1
            counts["forward"] += 1
            return 1e30, np.zeros_like(x)
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

    status = "max_evaluations"
    its = [0]

    def count(_):
        its[0] += 1

    try:
        res = minimize(evaluate, x0, jac=True, method="L-BFGS-B", bounds=[(0.0, u) for u in np.repeat(ub, K)],
                       callback=count, options={"maxfun": max_evaluations, "maxiter": max_evaluations,
                                                "ftol": 1e-15, "gtol": 1e-12})
        status = "converged" if res.success else ("max_evaluations" if res.status == 1 else "line_search_failed")
    except _Reached:
        status = "reached"
    except _Budget:
        status = "max_evaluations"
    iterations = its[0]
    if "x" not in best:
        raise RuntimeError("no forward run of the optimisation succeeded")
    U = best["x"].reshape(m, K)
    session.set(schedule_items(names, knot_times, U))
    reached = bool(best["errors"].max() <= tol)
    return OptimizeResult(names, knot_times, U, best["positions"], best["errors"], reached,
                          "reached" if reached else status, float(best["J"]), iterations,
                          counts["forward"], counts["adjoint"], counts["failed"], time.perf_counter() - t0,
                          history, ub)
