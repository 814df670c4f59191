"""Soft IK and trajectory following (paper, section V.B).

Soft IK finds tendon contractions u that bring a marker y(u) = X + S x*(u) to a
target y':

    min_u  O(u) = |y(u) - y'|^2 + rho |u|^2     subject to  0 <= u <= u_max.

Each iteration linearises y at the current equilibrium with J = dy/du
(skelfem.analysis.sensitivity, adjoint mode: one factorisation, gdim solves) and takes
the bounded Levenberg-Marquardt step

    D = argmin |r + J D|^2 + rho |u + D|^2 + mu |D|^2,   0 <= u + D <= u_max,

r = y - y', a small bounded linear least-squares problem (scipy's lsq_linear),
with |D|_inf capped (default 0.05 x finger length: larger steps overshoot
along the marker's curved paths and cost long Newton solves).
The trial equilibrium x*(u + D) is found by Newton warm-started from x*(u) at
load factor 1. The step is accepted if O decreases; the damping mu follows the
ratio of actual to predicted decrease (Nielsen's rule). A failed Newton solve
halves D and raises mu; an unconverged state is never accepted.

Ligaments are not controls: they never enter u (the paper zeroes their entries
of dO/du). The iteration stops when |y - y'| < tol (default 1e-3 x finger
length), when the model promises or an accepted step gains less than a small
fraction of tol, or after `max_solves` forward solves; an unreachable target
ends at the closest admissible pose found, with reached = False. Near a fold
of the equilibrium path (e.g. a co-contracted finger about to buckle) tiny
steps jump to another branch with a larger error; they are rejected, so the
IK stops at the fold.

Tracking runs Soft IK target after target, each warm-started from the previous
solution (contractions and equilibrium).
"""
from __future__ import annotations

import contextlib
import logging
import time
from dataclasses import dataclass, field

import numpy as np
from petsc4py import PETSc

from .sensitivity import KINK, Linearization, contractions, set_contractions, stretch, tendons
from ..fem.newton import SolveError

log = logging.getLogger("skelfem")

TOL_FRACTION = 1e-3     # default tolerance: this fraction of the finger length
STEP_FRACTION = 0.05    # default cap on one step's |D|_inf: this fraction of the finger length
STALL_FRACTION = 0.1    # an accepted step gaining less than this x tol (while |r| >= tol) ends the IK


MAX_SHORTENING = 0.9    # a tendon's contraction is at most this share of its sketch's length


@dataclass
class IKResult:
    """One Soft IK solve: the pose found for one target."""
    target: np.ndarray
    position: np.ndarray          # achieved y, mm
    contractions: np.ndarray      # u, mm, one per tendon
    error: float                  # |y - y'|, mm
    reached: bool                 # error < tol
    status: str                   # "reached", "stalled", "max_solves"
    forward_solves: int           # Newton solves (accepted or not) for this target
    failed_solves: int
    iterations: int               # accepted steps
    time: float                   # s
    errors: list = field(default_factory=list)   # |y - y'| at the start and after each accepted step


def body_extent(model) -> float:
    """Extent of the body along its longest axis, mm (objects do not count)."""
    from ..mesh.geometry import body_box
    lo, hi = body_box(model.tm, model.design)
    return float(np.max(hi - lo))


@contextlib.contextmanager
def _no_cuts(solver):
    """A failed warm-started solve is reported, not retried from a lower load factor."""
    saved = solver.stepper.max_cuts
    solver.stepper.max_cuts = 0
    try:
        yield
    finally:
        solver.stepper.max_cuts = saved


class SoftIK:
    """Soft IK for one marker of a Session's design, keeping the last accepted equilibrium.

    The session must hold a converged equilibrium for the tendons' current
    contractions (see `settle`).
    """

    def __init__(self, session, marker: str, upper=None, reg: float = 0.0,
                 tol: float | None = None, max_solves: int = 40, max_step: float | None = None,
                 damping: float = 1e-3):
        """upper: {tendon: u_max} (others unbounded); reg: rho, mm^2 per mm^2; tol: mm
        (default 1e-3 x the body's extent); max_step: cap on ``|D|_inf``, mm (default
        0.05 x the body's extent); damping: initial mu relative to max diag(J^T J).
        """
        model = self.model = session.model
        self.session, self.solver = session, session.solver
        names = model.term("markers").names if model.terms_in("markers") else []
        if marker not in names:
            raise KeyError(f"marker '{marker}' not in design (have: {', '.join(names) or 'none'})")
        self.marker, self.index = marker, names.index(marker)
        self.names = [t.name for t in tendons(model)]
        self.lower = np.zeros(len(self.names))
        self.upper = self._upper_bounds(upper or {})
        self.reg = float(reg)
        self.length = body_extent(model)
        self.tol = TOL_FRACTION * self.length if tol is None else float(tol)
        self.max_solves = int(max_solves)
        self.max_step = STEP_FRACTION * self.length if max_step is None else float(max_step)
        self.damping = float(damping)          # initial mu relative to max diag(J^T J)
        self.u = np.clip(contractions(model), self.lower, self.upper)
        self.one_sided = np.zeros(len(self.names), dtype=bool)   # tendons at the kink (see jacobian)
        self._L0 = np.array([t.cable.L0 for t in tendons(model)])
        self._x = model.u.vector.copy()        # the last accepted equilibrium x*(u)
        self._history = model.history()        # and its friction history (anchors, slip states)
        self.forward_solves = 0                # over the object's life
        self.failed_solves = 0
        self.newton_iterations = 0
        self.approximate_jacobians = 0         # steps steered without friction's coupling (see jacobian)

    def _upper_bounds(self, upper: dict) -> np.ndarray:
        """Each tendon's largest contraction: the user's bound, and never more than MAX_SHORTENING of
        its sketch's length (the design refuses a contraction of the whole length, so an IK answer
        beyond it could not be simulated)."""
        design = self.session.design
        hi = np.array([MAX_SHORTENING * float(np.linalg.norm(np.diff(design.cable(n).path, axis=0), axis=1).sum())
                       for n in self.names])
        for name, value in upper.items():
            if name not in self.names:
                raise KeyError(f"'{name}' is not a tendon of the design (tendons: {', '.join(self.names)})")
            if not value > 0.0:
                raise ValueError(f"maximum contraction of '{name}' must be > 0, got {value}")
            i = self.names.index(name)
            hi[i] = min(hi[i], float(value))
        return hi

    # -- equilibria -------------------------------------------------------------------------
    def settle(self, steps: int = 1):
        """Solve the equilibrium for the current u from the current state (load ramp allowed)."""
        set_contractions(self.model, self.u)
        report = self.solver.solve(steps)
        if not report.converged:
            self.restore()
            raise SolveError(f"equilibrium for u = {self.u} failed ({report.status})")
        self.session.solved = True
        self.model.u.vector.copy(self._x)
        self._history = self.model.history()
        return report

    def trial(self, u: np.ndarray) -> bool:
        """Newton at load factor 1 for contractions u, warm-started from x*(self.u).

        True: the model holds x*(u), to be accepted or restored. False: the
        solve failed and the accepted equilibrium is back in place.
        """
        self._x.copy(self.model.u.vector)
        set_contractions(self.model, u)
        self.forward_solves += 1
        with _no_cuts(self.solver):
            report = self.solver.solve(1)
        self.newton_iterations += report.newton_iterations
        if not report.converged:
            self.failed_solves += 1
            self.restore()
        return report.converged

    def accept(self, u: np.ndarray) -> None:
        """Make the trial state x*(u) the accepted one (and its friction history)."""
        self.u = np.array(u, dtype=float)
        self.model.u.vector.copy(self._x)
        self._history = self.model.history()

    def restore(self) -> None:
        """Put back the last accepted equilibrium and its contractions."""
        model = self.model
        set_contractions(model, self.u)
        model.set_factor(1.0)
        self._x.copy(model.u.vector)
        model.set_history(self._history)          # a refused trial leaves no slip behind
        model.u.vector.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)

    def position(self) -> np.ndarray:
        """The marker's position y at the model's current state."""
        return self.model.term("markers").positions(self.model.u.x.array)[self.index].copy()

    def jacobian(self) -> np.ndarray:
        """J = dy/du at the current equilibrium, (gdim, m).

        Tendons exactly at their rest length get the taut-branch column, valid
        for D_c >= 0 only; step() keeps them there (self.one_sided).
        """
        lin = Linearization(self.model, self.solver)
        try:
            self.one_sided = np.isin(np.arange(len(self.names)), lin.kinked)
            try:
                return lin.marker_jacobian(self.index)
            except RuntimeError as exc:            # friction's coupling too strong for GMRES: steer without it
                if not lin.lagged:
                    raise
                log.warning("Soft IK: %s; this step uses the Jacobian with friction's normal forces held", exc)
                lin.lagged = []
                self.approximate_jacobians += 1
                return lin.marker_jacobian(self.index)
        finally:
            lin.destroy()

    def slack(self) -> np.ndarray:
        """sigma_c = max(0, L - l) per tendon at the current state, mm: contraction with no effect."""
        u = self.model.u.x.array
        return np.array([max(0.0, -stretch(t, u)) for t in tendons(self.model)])

    def take_up_slack(self) -> bool:
        """u_c += sigma_c for slack tendons that may (upper bound): x*(u) stays the equilibrium.

        A slack tendon's column of J is zero, so the model never pulls it; at
        its rest length it gets the taut-branch column instead.
        """
        sigma = self.slack()
        take = (sigma > KINK * self._L0) & (self.u + sigma <= self.upper)
        if not take.any():
            return False
        self.u = self.u + np.where(take, sigma, 0.0)
        set_contractions(self.model, self.u)
        log.debug("  IK: took up slack %s mm", np.round(np.where(take, sigma, 0.0), 4))
        return True

    # -- the objective and the step -----------------------------------------------------------
    def objective(self, r: np.ndarray, u: np.ndarray) -> float:
        """O = ``|r|^2 + rho |u|^2`` with r = y - y'."""
        return float(r @ r + self.reg * u @ u)

    def step(self, J: np.ndarray, r: np.ndarray, mu: float) -> tuple[np.ndarray, float]:
        """Bounded LM step D from self.u and the model's objective at u + D."""
        from scipy.optimize import lsq_linear
        u = self.u
        free = self.upper > self.lower
        n = int(free.sum())
        D = np.zeros(len(u))
        if n:
            A = np.vstack([J[:, free], np.sqrt(self.reg) * np.eye(n), np.sqrt(mu) * np.eye(n)])
            b = np.concatenate([-r, -np.sqrt(self.reg) * u[free], np.zeros(n)])
            lo = np.maximum(self.lower - u, -self.max_step)
            lo = np.where(self.one_sided, np.maximum(lo, 0.0), lo)[free]
            hi = np.minimum(self.upper - u, self.max_step)[free]
            D[free] = lsq_linear(A, b, bounds=(lo, np.maximum(hi, lo + 1e-12)), method="bvls", tol=1e-12).x
        D = np.clip(u + D, self.lower, self.upper) - u
        return D, self.objective(r + J @ D, u + D)

    def _progress(self, O: float, O_model: float) -> float:
        """Decrease of sqrt(O) (a distance, mm) from O to O_model."""
        return np.sqrt(max(O, 0.0)) - np.sqrt(max(O_model, 0.0))

    def _iteration(self, J, target, r, O, lm, stop_at):
        """Try LM steps from x*(u) until one lowers O.

        Returns (accepted, r, O); lm = [mu, nu] is updated in place.
        """
        mu, nu = lm
        accepted = False
        while self.forward_solves < stop_at:
            D, O_model = self.step(J, r, mu)
            if np.abs(D).max() <= 1e-9 * max(1.0, np.abs(self.u).max()) \
                    or self._progress(O, O_model) <= 1e-3 * self.tol:
                break                                   # nothing left to gain from this model
            ok = self.trial(self.u + D)
            while not ok and self.forward_solves < stop_at:
                mu, D = mu * nu, 0.5 * D                # a failed solve shrinks the step
                O_model = self.objective(r + J @ D, self.u + D)
                ok = self.trial(self.u + D)
            if not ok:
                break
            r_new = self.position() - target
            O_new = self.objective(r_new, self.u + D)
            log.debug("  IK step |D| %.3g mm, mu %.3g: |r| %.4g -> %.4g (model %.4g)", np.abs(D).max(), mu,
                      np.sqrt(O), np.sqrt(O_new), np.sqrt(max(O_model, 0.0)))
            if O_new < O:
                gain = (O - O_new) / max(O - O_model, 1e-300)
                self.accept(self.u + D)
                mu, nu = mu * max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3), 2.0
                r, O, accepted = r_new, O_new, True
                break
            self.restore()
            mu, nu = mu * nu, 2.0 * nu
        lm[:] = [mu, nu]
        return accepted, r, O

    # -- Soft IK -----------------------------------------------------------------------------------
    def solve(self, target, max_solves: int | None = None) -> IKResult:
        """Bring the marker towards target; ends at the closest admissible pose found."""
        t0, solves0, failed0 = time.perf_counter(), self.forward_solves, self.failed_solves
        stop_at = solves0 + (self.max_solves if max_solves is None else int(max_solves))
        target = np.asarray(target, dtype=float)
        r = self.position() - target
        O = self.objective(r, self.u)
        errors = [float(np.linalg.norm(r))]
        lm, status = None, "stalled"
        while True:
            if errors[-1] < self.tol:
                status = "reached"
                break
            if self.forward_solves >= stop_at:
                status = "max_solves"
                break
            J = self.jacobian()
            if lm is None:
                lm = [self.damping * max(float(np.max(np.sum(J * J, axis=0))), 1e-12), 2.0]
            O_before = O
            accepted, r, O = self._iteration(J, target, r, O, lm, stop_at)
            if accepted:
                errors.append(float(np.linalg.norm(r)))
            stuck = not accepted or (errors[-1] >= self.tol
                                     and self._progress(O_before, O) < STALL_FRACTION * self.tol)
            if stuck and self.forward_solves < stop_at and self.take_up_slack():
                O = self.objective(r, self.u)           # same pose, slack tendons now just taut
                continue
            if not accepted:
                status = "max_solves" if self.forward_solves >= stop_at else "stalled"
                break
            if stuck:
                break                                   # accepted, but hardly moving
        error = errors[-1]
        return IKResult(target, self.position(), self.u.copy(), error, error < self.tol, status,
                        self.forward_solves - solves0, self.failed_solves - failed0,
                        len(errors) - 1, time.perf_counter() - t0, errors)


def line_targets(ends: np.ndarray, steps: int) -> np.ndarray:
    """`steps` targets evenly spaced from ends[0] to ends[1], both included."""
    return ends[0] + np.linspace(0.0, 1.0, steps)[:, None] * (ends[1] - ends[0])


def pose_indices(n: int, count: int = 4) -> list[int]:
    """A few evenly spread targets whose poses a tracking picture shows."""
    return sorted(set(np.linspace(0, n - 1, min(n, count)).round().astype(int).tolist()))


def track(ik: SoftIK, targets, on_target=None) -> list[IKResult]:
    """Soft IK along a sequence of targets, each warm-started from the previous pose."""
    results = []
    for i, target in enumerate(np.asarray(targets, dtype=float)):
        res = ik.solve(target)
        results.append(res)
        if on_target is not None:
            on_target(i, res)
    return results
