"""Optimising a 2D design with its exact gradients: L-BFGS-B over a task's variables (skelfem optimize-design).

The task (skelfem.design.design_task) names design variables with bounds and
objectives, each a sum over targets (a set of live parameters, e.g. a
contraction, and for a reach a marker's target point):

    J(p) = sum_objectives weight * sum_targets J_t(u_t(p); p),

each J_t solved on the design at p (the mesh moved by the morph) and
differentiated by the adjoint (skelfem.analysis.design_gradient): one solve
and one back-substitution per target, whatever the number of variables.
SciPy's L-BFGS-B runs on the variables scaled to their bounds' widths.
When the morph refuses a moved mesh (it would degrade) or a solve fails, the
run stops there with the best design found and says why.

At the end the best design is meshed anew and solved fresh (``fresh``): its
objective beside the optimiser's value measures what the moved mesh's
discretisation changed.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .design_gradient import DesignGradient, MarkerTarget, Tension


class Stop(Exception):
    """The optimisation cannot go on (a failed solve, the budget spent); the best design so far stands."""


class Refused(Stop):
    """A trial design the design rules or the morph refuse (a bone through the outline, a flattened
    triangle): L-BFGS-B's line search is sent back with a worse value; MAX_REFUSED in a row stop the run."""


MAX_REFUSED = 8


@dataclass
class DesignOptimum:
    keys: list
    start: np.ndarray            # the variables' values at the start (design units)
    best: np.ndarray             # at the best design found
    start_objective: float
    objective: float             # the optimiser's value at best
    evaluations: int
    history: list = field(default_factory=list)     # (evaluation, objective, gradient norm)
    status: str = ""
    raw: dict = field(default_factory=dict)          # the best design's TOML data
    time: float = 0.0


def override_text(key: str, value) -> str:
    """A --set string for a target's setting."""
    if isinstance(value, (list, tuple)):
        return f"{key}=[" + ", ".join(repr(float(v)) for v in value) + "]"
    return f"{key}={float(value)!r}"


def objective_of(objective, target):
    """The design-gradient objective of one target of a task objective."""
    return MarkerTarget(objective.name, target.at) if objective.kind == "reach" else Tension(objective.name)


class TaskObjective:
    """J(p) and dJ/dp of a task on a DesignGradient."""

    def __init__(self, dg: DesignGradient, task):
        self.dg, self.task = dg, task
        self.evaluations = 0

    def __call__(self, p) -> tuple[float, np.ndarray]:
        dg, total, grad = self.dg, 0.0, np.zeros(len(self.dg.keys))
        for objective in self.task.objectives:
            for target in objective.targets:
                try:
                    result = dg.solve(p, overrides=[override_text(k, v) for k, v in target.set])
                except ValueError as exc:          # DesignError, MeshDegrades: the session is as it was
                    raise Refused(str(exc)) from None
                self.evaluations += 1
                if not result.converged:
                    raise Stop(f"the solve failed at evaluation {self.evaluations} ({result.status})")
                J, g = dg.gradient(objective_of(objective, target))
                total += objective.weight * J
                grad += objective.weight * g
        return total, grad

    def value(self, session) -> float:
        """J of a session's design as it is (no gradient): each target set live and solved."""
        total = 0.0
        base = {k: v for k, v in session.model.parameters().items()}
        for objective in self.task.objectives:
            for target in objective.targets:
                session.set(dict(target.set))
                result = session.solve()
                if not result.converged:
                    raise Stop(f"the fresh solve failed ({result.status})")
                total += objective.weight * objective_of(objective, target).value(session.model)
                session.set({k: base[k] for k, _ in target.set if k in base})
        return total


def optimize_design(session, task, progress=None) -> DesignOptimum:
    """Minimise the task's objective over its variables from the session's design (its mesh as generated)."""
    from scipy.optimize import minimize

    t0 = time.perf_counter()
    dg = DesignGradient(session, [v.key for v in task.variables])
    start = np.array([v.start for v in task.variables])
    width = np.array([v.upper - v.lower for v in task.variables])
    lower = np.array([v.lower for v in task.variables]) - start
    upper = np.array([v.upper for v in task.variables]) - start
    f = TaskObjective(dg, task)
    best = {"J": np.inf, "p": np.zeros(len(start))}
    history = []

    per_call = _targets(task)

    refused = {"row": 0, "last": None}

    def fun(x):
        if f.evaluations + per_call > task.max_evaluations:
            raise Stop(f"the budget of {task.max_evaluations} solves is spent")
        p = x * width
        try:
            J, g = f(p)
        except Refused as exc:
            refused["row"] += 1
            if not np.isfinite(best["J"]) or refused["row"] > MAX_REFUSED:
                raise
            refused["last"] = str(exc)
            # worse than anything seen, with the best point's slope: the line search steps back
            return 2.0 * abs(best["J"]) + 1.0 + history[0][1], best["g"] * width
        refused["row"] = 0
        history.append((f.evaluations, float(J), float(np.linalg.norm(g * width))))
        if J < best["J"]:
            best.update(J=float(J), p=p.copy(), g=g.copy())
        if progress is not None:
            progress(f.evaluations, J)
        return J, g * width

    status = ""
    try:
        res = minimize(fun, np.zeros(len(start)), jac=True, method="L-BFGS-B",
                       bounds=list(zip(lower / width, upper / width)),
                       options={"maxfun": max(task.max_evaluations // max(per_call, 1), 1), "maxiter": 1000})
        status = str(res.message)
    except Stop as exc:
        status = f"stopped: {exc}"
    if refused["last"] and not status.startswith("stopped"):
        status += f" (trial designs refused on the way: {refused['last']})"
    start_objective = history[0][1] if history else float("nan")
    return DesignOptimum([v.key for v in task.variables], start, start + best["p"], start_objective,
                         best["J"], f.evaluations, history, status, dg.handles.raw(best["p"]),
                         time.perf_counter() - t0)


def _targets(task) -> int:
    return sum(len(o.targets) for o in task.objectives)
