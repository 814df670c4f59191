"""Optimising a 2D design with its exact gradients over a task's variables (skelfem optimize-design).

The task (skelfem.design.design_task) names design variables with bounds,
objectives, each a sum over targets (a set of live parameters, e.g. a
contraction, and for a reach a marker's target point), and fabrication
constraints:

    J(p) = sum_objectives weight * sum_targets J_t(u_t(p); p),    c(p) >= 0,

each J_t solved on the design at p (the mesh moved by the morph) and
differentiated by the adjoint (skelfem.analysis.design_gradient): one solve
per distinct target setting and one back-substitution per target, whatever
the number of variables. c are point-segment clearances of the design's
polygons and sketches (skelfem.design.clearances), exact in p through the
handles' velocities. SciPy's SLSQP runs on the variables scaled to their
bounds' widths when there are constraints (they are smooth and the optimum
lies on them: SLSQP meets them to ~1e-6 mm), L-BFGS-B when there are bounds
only. A trial design the morph or the design rules refuse sends the line
search back; a failed solve stops the run with the best design found
(the best that meets the constraints) and says why.

Every evaluation can be handed to a recorder and read back (``known``): the
optimisers are deterministic given the same values, so a run resumed from
an interrupted one's evaluations retraces its path through them without
solving and goes on from where it stopped.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..design.clearances import Clearances, start_points
from .design_gradient import DesignGradient, MarkerTarget, Tension


class Stop(Exception):
    """The optimisation cannot go on (a failed solve, the budget spent); the best design so far stands."""


class Refused(Stop):
    """A trial design the design rules or the morph refuse (a bone through the outline, a flattened
    triangle): the optimiser's line search is sent back with a worse value; MAX_REFUSED in a row stop the run."""


MAX_REFUSED = 8


@dataclass
class DesignOptimum:
    keys: list
    start: np.ndarray            # the variables' values at the start (design units)
    best: np.ndarray             # at the best design found
    start_objective: float
    objective: float             # the optimiser's value at best
    evaluations: int
    history: list = field(default_factory=list)     # (solves, objective, gradient norm, constraint violation)
    status: str = ""
    raw: dict = field(default_factory=dict)          # the best design's TOML data
    time: float = 0.0
    replayed: int = 0                                # evaluations read from a checkpoint, not solved
    clearances: dict = field(default_factory=dict)   # {constraint: its least margin at best, mm}


def override_text(key: str, value) -> str:
    """A --set string for a target's setting."""
    if isinstance(value, (list, tuple)):
        return f"{key}=[" + ", ".join(repr(float(v)) for v in value) + "]"
    return f"{key}={float(value)!r}"


def objective_of(objective, target):
    """The design-gradient objective of one target of a task objective."""
    return MarkerTarget(objective.name, target.at) if objective.kind == "reach" else Tension(objective.name)


def target_sets(task) -> list[tuple[tuple, list]]:
    """[(set, [(objective, target), ...])]: the targets grouped by their settings, in the task's order (one
    solve serves every target of a group)."""
    out: dict = {}
    for objective in task.objectives:
        for target in objective.targets:
            out.setdefault(target.set, []).append((objective, target))
    return list(out.items())


class TaskObjective:
    """J(p) and dJ/dp of a task on a DesignGradient: one solve per distinct ``set``, one adjoint per target."""

    def __init__(self, dg: DesignGradient, task):
        self.dg, self.task = dg, task
        self.evaluations = 0                 # forward solves

    def __call__(self, p) -> tuple[float, np.ndarray]:
        dg, total, grad = self.dg, 0.0, np.zeros(len(self.dg.keys))
        for settings, members in target_sets(self.task):
            try:
                result = dg.solve(p, overrides=[override_text(k, v) for k, v in settings])
            except ValueError as exc:          # DesignError, MeshDegrades: the session is as it was
                raise Refused(str(exc)) from None
            self.evaluations += 1
            if not result.converged:
                raise Stop(f"the solve failed at evaluation {self.evaluations} ({result.status})")
            for objective, target in members:
                J, g = dg.gradient(objective_of(objective, target))
                total += objective.weight * J
                grad += objective.weight * g
        return total, grad

    def value(self, session, estimate: bool = False) -> tuple[float, float]:
        """(J, its error estimate) of a session's design as it is, no gradient: each target set live and
        solved (the estimate, skelfem.estimate, when asked: else nan)."""
        total, error = 0.0, 0.0 if estimate else float("nan")
        base = {k: v for k, v in session.model.parameters().items()}
        for settings, members in target_sets(self.task):
            session.set(dict(settings))
            result = session.solve(estimate=estimate)
            if not result.converged:
                raise Stop(f"the fresh solve failed ({result.status})")
            for objective, target in members:
                total += objective.weight * objective_of(objective, target).value(session.model)
                if estimate:
                    error += objective.weight * objective_error(objective, target, session.model, result.errors)
            session.set({k: base[k] for k, _ in settings if k in base})
        return total, error


def objective_error(objective, target, model, errors: dict) -> float:
    """The error estimate of one target's J from its observables' (skelfem.estimate): J evaluated with the
    observables moved by their estimated discretisation change, against J, plus their algebraic errors'
    first-order effect."""
    if objective.kind == "tension":
        e = errors[f"cables.{objective.name}.tension"]
        return abs(e["change"]) + e["algebraic"]
    markers = model.term("markers")
    y = markers.positions(model.u.x.array)[markers.names.index(objective.name)]
    r = y - np.asarray(target.at, dtype=float)
    e = [errors[f"markers.{objective.name}.{axis}"] for axis in ("x", "y")]
    rich = r + np.array([e[0]["change"], e[1]["change"]])
    return abs(float(rich @ rich - r @ r)) + 2.0 * float(np.abs(r) @ np.array([e[0]["algebraic"], e[1]["algebraic"]]))


class DesignConstraints:
    """A task's [constraints] (skelfem.design.clearances) at the handles' points: values c(x) >= 0 (mm) and their
    exact Jacobian in the scaled variables x = p / width (the points' velocities, dPoints/dp, are exact)."""

    def __init__(self, task, handles, width):
        self.clear = Clearances(handles.start, dict(task.constraints))
        self.handles, self.width = handles, width
        self.n = len(start_points(handles.start))
        if not np.allclose(handles.P0[:self.n], start_points(handles.start)):
            raise ValueError("the design's points are not in the order the constraints expect")

    def points(self, p):
        return self.handles.points(p)[:self.n]

    def values(self, x) -> np.ndarray:
        return self.clear.values(self.points(np.asarray(x) * self.width))

    def jacobian(self, x) -> np.ndarray:
        p = np.asarray(x) * self.width
        V = self.handles.velocities(p)[:self.n]
        return np.einsum("mij,ijk->mk", self.clear.jacobian(self.points(p)), V) * self.width

    def least(self, p) -> dict:
        return self.clear.least(self.points(p))


class Evaluations:
    """J and dJ/dx at scaled points x, each solved once (L-BFGS-B asks for both at once, SLSQP apart) or read
    from ``known`` (a checkpoint's entries: the run retraces its path from them without solving); the budget,
    the best point (the best feasible one, with constraints), and the trial designs refused."""

    def __init__(self, f: TaskObjective, task, width, constraints=None, known=(), record=None, progress=None):
        self.f, self.task, self.width, self.constraints = f, task, width, constraints
        self.known = {_key(e["x"]): e for e in known}
        self.record, self.progress = record, progress
        self.per_call = len(target_sets(task))
        self.solves = 0                  # this run's and the replayed entries'
        self.replayed = 0                # evaluations read from ``known``
        self.counted: set = set()
        self.best = {"J": np.inf, "p": np.zeros(len(width)), "g": None}
        self.history: list = []
        self.refused_row, self.refused_last = 0, None
        self.last: tuple = (None, None)

    def _entry(self, x) -> dict:
        key = _key(x)
        entry = self.known.get(key)
        if entry is not None:
            if key not in self.counted:
                self.counted.add(key)
                self.solves += int(entry["solves"])
                self.replayed += 1
            return entry
        if self.solves + self.per_call > self.task.max_evaluations:
            raise Stop(f"the budget of {self.task.max_evaluations} solves is spent")
        before = self.f.evaluations
        try:
            J, g = self.f(np.asarray(x) * self.width)
            entry = {"x": [float(v) for v in x], "J": float(J), "g": [float(v) for v in g], "refused": None}
        except Refused as exc:
            entry = {"x": [float(v) for v in x], "J": None, "g": None, "refused": str(exc)}
        entry["solves"] = self.f.evaluations - before
        self.solves += entry["solves"]
        self.known[key] = entry
        self.counted.add(key)
        if self.record is not None:
            self.record(entry)
        return entry

    def __call__(self, x) -> tuple[float, np.ndarray]:
        x = np.asarray(x, dtype=float)
        if self.last[0] is not None and np.array_equal(self.last[0], x):
            return self.last[1]
        out = self._evaluate(x)
        self.last = (x.copy(), out)
        return out

    def _evaluate(self, x) -> tuple[float, np.ndarray]:
        entry = self._entry(x)
        if entry["refused"] is not None:
            self.refused_row += 1
            if not np.isfinite(self.best["J"]) or self.refused_row > MAX_REFUSED:
                raise Refused(entry["refused"])
            self.refused_last = entry["refused"]
            # worse than anything seen, with the best point's slope: the line search steps back
            return 2.0 * abs(self.best["J"]) + 1.0 + self.history[0][1], self.best["g"] * self.width
        self.refused_row = 0
        J, g, p = entry["J"], np.array(entry["g"]), x * self.width
        violation = 0.0 if self.constraints is None else max(0.0, -float(self.constraints.values(x).min()))
        self.history.append((self.solves, J, float(np.linalg.norm(g * self.width)), violation))
        if J < self.best["J"] and violation <= FEASIBLE:
            self.best.update(J=J, p=p.copy(), g=g.copy())
        if self.progress is not None:
            self.progress(self.solves, J)
        return J, g * self.width

    def value(self, x) -> float:
        return self(x)[0]

    def gradient(self, x) -> np.ndarray:
        return self(x)[1]


FEASIBLE = 1e-4          # mm: a point within this of every constraint counts as meeting it (SLSQP's iterates
#                          reach the constraints' boundary to about 1e-8)


def _key(x) -> bytes:
    return np.asarray(x, dtype=float).tobytes()


def _minimize(run: Evaluations, task, width, lower, upper, constraints, x0):
    """SciPy's L-BFGS-B (bounds only) or SLSQP (with fabrication constraints) from x0 (scaled)."""
    from scipy.optimize import minimize

    bounds = list(zip(lower / width, upper / width))
    if constraints is None:
        return minimize(run, x0, jac=True, method="L-BFGS-B", bounds=bounds,
                        options={"maxfun": max(task.max_evaluations // max(run.per_call, 1), 1), "maxiter": 1000})
    J0 = run.value(x0)
    return minimize(run.value, x0, jac=run.gradient, method="SLSQP", bounds=bounds,
                    constraints=[{"type": "ineq", "fun": constraints.values, "jac": constraints.jacobian}],
                    options={"maxiter": task.max_evaluations, "ftol": SLSQP_FTOL * max(abs(J0), 1e-12)})


SLSQP_FTOL = 1e-6        # SLSQP stops when J changes by less than this fraction of the start's J


def optimize_design(session, task, progress=None, known=(), record=None) -> DesignOptimum:
    """Minimise the task's objective over its variables from the session's design (its mesh as generated).

    ``known``: the entries of an interrupted run's checkpoint (``record`` was handed each as it was made):
    the run retraces the same path through them without solving, and goes on from where it stopped."""
    t0 = time.perf_counter()
    dg = DesignGradient(session, [v.key for v in task.variables])
    start = np.array([v.start for v in task.variables])
    width = np.array([v.upper - v.lower for v in task.variables])
    lower = np.array([v.lower for v in task.variables]) - start
    upper = np.array([v.upper for v in task.variables]) - start
    constraints = DesignConstraints(task, dg.handles, width) if task.constraints else None
    run = Evaluations(TaskObjective(dg, task), task, width, constraints, known, record, progress)
    try:
        status = str(_minimize(run, task, width, lower, upper, constraints, np.zeros(len(width))).message)
    except Stop as exc:
        status = f"stopped: {exc}"
    if run.refused_last and not status.startswith("stopped"):
        status += f" (trial designs refused on the way: {run.refused_last})"
    start_objective = run.history[0][1] if run.history else float("nan")
    return DesignOptimum([v.key for v in task.variables], start, start + run.best["p"], start_objective,
                         run.best["J"], run.solves, run.history, status, dg.handles.raw(run.best["p"]),
                         time.perf_counter() - t0, run.replayed,
                         constraints.least(run.best["p"]) if constraints is not None else {})
