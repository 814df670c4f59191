"""Static equilibrium: PETSc SNES Newton on grad Pi = 0 (its load steps: skelfem.fem.loadstep).

Newton's direction p solves H p = -grad Pi with H = K + sum c g g^T (K factorised by MUMPS or
preconditioned by multigrid, the cables' rank-one parts apart: skelfem.fem.linear), via a python PC.
The default line search ("energy") runs in SNES's pre-check: it starts from
the model's admissible step alpha_max = model.max_step(x, p) <= 1 (e.g. the
collision-free step of self-contact) and backtracks until the trial state is admissible (det F > 0
in every element, no term objects) and satisfies the Armijo condition

    Pi(x + alpha p) <= Pi(x) + c alpha grad Pi . p,

or, once energy differences drown in round-off, reduces |grad Pi|. A trial
state with an inverted element is never accepted. ``curved`` is the same
line search along the second-order curve x + alpha p + alpha^2 a / 2 with the
geodesic acceleration a = -H^{-1} D^2R[p, p] (one more back-substitution and
two residuals per iteration; the straight step is kept when it is lower at
alpha_max): on slender bodies that rotate a lot the straight step stretches
the body by O(alpha^2) and the energy model fails, the curve follows the
rotation. Other strategies
(``residual``: PETSc's backtracking on |grad Pi|, ``none``: full steps,
``trust_region``: PETSc's newtontr) exist to compare against.

Terms with lagged quantities (friction's normal forces, contacts that formed mid-solve) are solved again
after each change of them (``_relag``): while the lags still move, a re-solve stops at LAG_LOOSE of its own
first |R|, and once they hold at a loosely solved state it is solved fully, so the answer is the one of
tight solves (the lags' fixed point, each solve's tolerance). When a term's lags always change in a new step
(``Lagged.lags_follow_the_step``: a cable's friction limits follow its tensions) a load step's first solve
is a loose one too (its state only sets the next lags: 88 -> 78 Newton iterations on finger_knuckles at mu
0.3, a step up of the finger's cycle 7.75 -> 6.6; not a time step's, see ``attempt``). A solve that ends at
a term's verdict (an object that nothing holds) ends with it as its failure. ``NewtonSolver.solve``,
``resolve`` and ``path`` are its load stepper's (``LoadStepper``, which calls ``attempt`` for each Newton
solve).
"""
from __future__ import annotations

import logging
import time

import numpy as np
from petsc4py import PETSc

from ..design.spec import ATOL_RELATIVE, ENERGY_LINE_SEARCHES, LINE_SEARCHES as STRATEGIES, force_scale
from .equilibrium import Equilibrium
from .report import BUDGET_SPENT, SolveError, SolveReport  # noqa: F401 (SolveError re-exported)
from .linesearch import EnergyLineSearch, resolve_strategy
from .loadstep import LoadStepper
from ..design.resources import direct_limit, stiff_elastic_bones
from .linear import LowRankSolver, choose_linear
from .multigrid import KRYLOV_RTOL
from .options import options_held, snes_petsc_options
from ..terms.capabilities import ContactEvents, Lagged, Verdict

log = logging.getLogger("skelfem")


MAX_LAG_UPDATES = 30   # re-solves with updated lagged quantities (friction's normal forces) per step
MAX_CONTACT_EVENTS = 100   # solves stopped where contacts formed (Model.contact_event), per step
MAX_FAILED_ROUNDS = 3  # re-solves in a row that fail although their lags changed: no equilibrium near
LAG_LOOSE = 1e-2       # a re-solve whose lags will change again stops at this times its own first |R|

ETA_MAX = 0.01         # the loosest forcing term of an inexact Newton step (iterative linear solves)


_REASONS = {
    PETSc.SNES.ConvergedReason.DIVERGED_MAX_IT: "max_iterations",
    PETSc.SNES.ConvergedReason.DIVERGED_LINE_SEARCH: "line_search_failed",
    PETSc.SNES.ConvergedReason.DIVERGED_FNORM_NAN: "diverged",
    PETSc.SNES.ConvergedReason.DIVERGED_FUNCTION_COUNT: "diverged",
    PETSc.SNES.ConvergedReason.DIVERGED_LINEAR_SOLVE: "linear_solve_failed",
    PETSc.SNES.ConvergedReason.DIVERGED_DTOL: "diverged",
    PETSc.SNES.ConvergedReason.DIVERGED_TR_DELTA: "trust_region_collapsed",
    PETSc.SNES.ConvergedReason.DIVERGED_INNER: "inner_solve_failed",
    PETSc.SNES.ConvergedReason.DIVERGED_LOCAL_MIN: "local_minimum_of_residual",
    PETSc.SNES.ConvergedReason.DIVERGED_FUNCTION_DOMAIN: "inverted_elements",
    PETSc.SNES.ConvergedReason.DIVERGED_JACOBIAN_DOMAIN: "inverted_elements",
}


def forcing(residuals: list[float], last: float, target: float = 0.0) -> float:
    """Eisenstat and Walker's second forcing term for Newton step k: eta = 0.9 (|F_k| / |F_k-1|)^2,
    safeguarded (not below 0.9 last^2 while that is above 0.1) and kept in [KRYLOV_RTOL, ETA_MAX]:
    loose while Newton is far from the solution, as tight as a direct solve near it, and no tighter
    than the residual test (|F| <= target) needs, 0.5 target / |F_k|."""
    if len(residuals) < 2 or residuals[-2] <= 0.0:
        return ETA_MAX
    eta = 0.9 * (residuals[-1] / residuals[-2]) ** 2
    if 0.9 * last ** 2 > 0.1:
        eta = max(eta, 0.9 * last ** 2)
    if residuals[-1] > 0.0:
        eta = max(eta, min(ETA_MAX, 0.5 * target / residuals[-1]))
    return float(min(max(eta, KRYLOV_RTOL), ETA_MAX))


class NewtonSolver:
    """SNES Newton for one Model; reusable across solves (warm starts)."""

    def __init__(self, model, spec=None, petsc_options: dict | None = None, prefix: str = "skelfem_"):
        self.model = model
        spec = spec if spec is not None else model.design.solver
        self.strategy = spec.line_search
        if self.strategy not in STRATEGIES:
            raise ValueError(f"unknown line search {self.strategy!r}")
        if self.strategy == "auto":
            self.strategy = resolve_strategy(model.design)
        self.energy_search = self.strategy in ENERGY_LINE_SEARCHES
        if not self.energy_search and model.rigid:     # a design's own spec is refused when it is read
            raise ValueError(f"line search {self.strategy!r} cannot keep rigid bones rigid; use 'energy'")
        if not self.energy_search and model.bounds_steps:
            raise ValueError(f"line search {self.strategy!r} cannot limit steps to the model's "
                             "admissible ones; use 'energy'")
        self.max_iterations, self.rtol, self.atol = spec.max_iterations, spec.rtol, spec.atol
        if self.atol is None:                  # relative to the design's force scale (any unit scale)
            self.atol = ATOL_RELATIVE * force_scale(model.design)
        self.xtol = 1e-11             # relative size of a full Newton step that ends the solve
        self.reference_residual = 0.0  # largest first |R| of a solve from rest (the problem's force scale)
        self._loose, self._round_f0 = 0.0, 0.0   # a loose re-solve (see _relag) and its own first |R|
        self.linear = choose_linear(spec.linear, model)
        model.embed_border = self.linear == "direct"    # iterative: the rigid border stays outside K
        self.A = model.create_matrix()
        self._retired: list[PETSc.Mat] = []    # Newton matrices replaced (new_matrix), not yet destroyed
        modes = model.rigid_body_modes if self.linear == "iterative" else None   # where the nodes are now
        stiff = stiff_elastic_bones(model.design) if self.linear == "iterative" else []
        W = (lambda: model.stiff_bone_modes(stiff)) if stiff else None
        self.lin = LowRankSolver(self.A, model.comm, petsc_options, prefix + "k_", modes, W,
                                 model.coarse_space() if modes is not None else None)
        self.lin.direct_limit = direct_limit(model.dim)     # a fallback MUMPS beyond it: the step fails
        self.b = model.u.vector.duplicate()
        self.x = model.u.vector.copy()      # SNES iterate; model.u is scratch for evaluations
        self.history: list[float] = []     # |R| of each iteration of the last attempt
        self._verdict_failure: str | None = None    # why a term found no equilibrium ahead (Verdict.verdict)
        self._f0 = 0.0
        self.search = EnergyLineSearch(model, self.b, self.lin.solve, curved=self.strategy == "curved")
        self._event = False           # the last SNES solve stopped at a contact event (Model.contact_event)
        self._stop_at: float | None = None     # the deadline of the Newton solve running now (attempt)
        self._budget_spent = False
        self._watch_events = any(isinstance(t, ContactEvents) for t in model.terms)
        self._verdicts = [t for t in model.terms                                         # asked every step
                          if isinstance(t, Verdict) and type(t).verdict is not Verdict.verdict]
        self._factorised = False      # lin holds a factorisation of K near the current state
        self.equilibrium = Equilibrium()     # the last converged state (a re-solve with nothing changed)
        self.snes = self._create_snes(prefix)
        self.stepper = LoadStepper(self)     # solve, resolve and path: load steps of these Newton solves

    # -- SNES set-up -------------------------------------------------------------------
    def assemble(self, x: PETSc.Vec) -> None:
        """K at x into self.A; into a new matrix if a term's pattern grew (contacts that formed)."""
        A = self.model.assemble_jacobian(x, self.A)
        if A is not self.A:
            self.new_matrix(A)

    def jacobian(self, x: PETSc.Vec) -> None:
        """Assemble K at x and factorise it with the rank-one parts (what every Newton solve uses)."""
        self.assemble(x)
        self.lin.update(self.model.low_rank_columns(), self.model.border)
        if self.lin.kind == "iterative":          # an inexact Newton step (the forcing term)
            target = max(self.atol, self.rtol * self._f0, self._loose * self._round_f0)
            self.lin.rtol = forcing(self.history, self.lin.rtol, target)

    @property
    def factorised(self) -> bool:
        """Whether lin holds K (factorised, or its multigrid) next to the current state: a converged solve's."""
        return self._factorised

    def _residual(self, x: PETSc.Vec, b: PETSc.Vec) -> None:
        """SNES's function; the step's solve is done: the solver's blocks make room for the pack."""
        self.lin.forget_blocks()
        self.model.residual(x, b)

    def _create_snes(self, prefix: str) -> PETSc.SNES:
        snes = PETSc.SNES().create(self.model.comm)
        snes.setOptionsPrefix(prefix)
        snes.setFunction(lambda s, x, b: self._residual(x, b), self.b)
        snes.setJacobian(lambda s, x, A, P: self.jacobian(x), self.A)
        if self.strategy == "trust_region":
            snes.setType("newtontr")
        else:
            snes.setType("newtonls")
            if self.energy_search:
                snes.setLineSearchPreCheck(self._precheck)
        snes.setTolerances(rtol=0.0, atol=0.0, stol=0.0, max_it=self.max_iterations)
        snes.setConvergenceTest(self._converged)
        with options_held(prefix, snes_petsc_options(self.strategy)):
            snes.setFromOptions()
        ksp = snes.getKSP()
        ksp.setType("preonly")
        self.lin.as_pc(ksp.getPC())
        return snes

    def _precheck(self, x: PETSc.Vec, y: PETSc.Vec) -> bool:
        """SNES's pre-check: the step is solved, so the solver's blocks make room for the line search."""
        self.lin.forget_blocks()
        return self.search.precheck(x, y)

    def new_matrix(self, A: PETSc.Mat | None = None) -> None:
        """A new Newton matrix (default: the model's; its terms' pattern grew). The old one is destroyed
        before the next SNES solve: SNES may hold it until the evaluation that replaced it ends."""
        A = self.model.create_matrix() if A is None else A
        self.snes.setJacobian(lambda s, x, A_, P: self.jacobian(x), A)
        self._retired.append(self.A)
        self.A = self.lin.K = A
        self.lin.reset()
        self.equilibrium.forget()

    def _retire(self) -> None:
        while self._retired:
            self._retired.pop().destroy()

    def forget(self) -> None:
        """Drop what was computed for the model before it changed (Model.refresh): factorisation, trials."""
        self._factorised = False
        self.equilibrium.forget()
        self.search.reset()

    def destroy(self) -> None:
        self._retire()
        self.snes.destroy()
        self.lin.destroy()
        for v in (self.A, self.b, self.x):
            v.destroy()

    def _converged(self, snes, it, norms):
        """|R| <= max(atol, rtol |R_0|), or a full Newton step below xtol * size."""
        xnorm, ynorm, fnorm = norms
        self.history.append(float(fnorm))
        if it > 0 and self._watch_events:
            self.model.sync(self.x)
            if self.model.contact_event():      # a new contact that friction does not hold yet: lag now
                log.debug("  newton %2d  |R| = %.3e: new contacts, their friction from here", it, fnorm)
                self._event = True
                return PETSc.SNES.ConvergedReason.DIVERGED_FUNCTION_DOMAIN
        if it == 0:
            # the force scale: |R| at the start of a solve from rest; a warm start, whose first
            # residual is small, is held to the same absolute accuracy, not to rtol of its own |R_0|
            self._f0 = max(fnorm, self.reference_residual)
            self._round_f0 = fnorm
        log.debug("  newton %2d  |R| = %.3e  |dx| = %.3e", it, fnorm, ynorm)
        if not np.isfinite(fnorm):
            return PETSc.SNES.ConvergedReason.DIVERGED_FNORM_NAN
        if fnorm <= max(self.atol, self.rtol * self._f0, self._loose * self._round_f0):
            return PETSc.SNES.ConvergedReason.CONVERGED_FNORM_ABS
        if self.search.decrement_converged:
            return PETSc.SNES.ConvergedReason.CONVERGED_FNORM_RELATIVE
        step = self.search.newton_step if self.energy_search else ynorm
        if it > 0 and step <= self.xtol * max(xnorm, self.model.size):
            return PETSc.SNES.ConvergedReason.CONVERGED_SNORM_RELATIVE
        if self.search.failure is not None or self._verdict_failure is not None or (it > 0 and self._verdict()):
            return PETSc.SNES.ConvergedReason.DIVERGED_LINE_SEARCH
        if it > 0 and self._stop_at is not None and time.monotonic() >= self._stop_at:
            self._budget_spent = True
            return PETSc.SNES.ConvergedReason.DIVERGED_MAX_IT
        if it >= self.max_iterations:
            return PETSc.SNES.ConvergedReason.DIVERGED_MAX_IT
        return PETSc.SNES.ConvergedReason.ITERATING

    def _verdict(self) -> bool:
        """Whether a term finds no equilibrium ahead of the iterate (Verdict.verdict; e.g. an object falling
        with nothing in its way): Newton ends with it as its failure instead of falling on."""
        if not self._verdicts:
            return False
        self.model.sync(self.x)
        self._verdict_failure = next((why for why in (t.verdict(self.model) for t in self._verdicts) if why), None)
        return self._verdict_failure is not None

    # -- solves ---------------------------------------------------------------------------
    def attempt(self, stop_at: float | None = None, loose_first: bool = True) -> tuple[bool, str, int]:
        """Newton from the model's state at the current load factor and parameters, solved again while
        the terms' lagged quantities change: (converged, status, iterations), the model's state where
        it ended. stop_at: a time.monotonic() after which the first SNES solve ends after its current
        step (status BUDGET_SPENT, the state the last accepted iterate: the editor's frames).
        loose_first: the first solve is a loose one when a term's lags follow the step (a load step; a
        time step solves it fully: flick.toml at mu 0.3 took 3,509 Newton iterations with loose first
        solves against 2,395)."""
        self.history, self._verdict_failure = [], None
        self.search.reset()
        self._event = False
        self._budget_spent = False
        self._stop_at = stop_at
        self.model.u.vector.copy(self.x)
        self.model.apply_bcs(self.x)
        if not self.model.admissible(self.x):
            return False, "inverted_elements", 0
        loose = loose_first and self._lags_follow()
        self._loose = LAG_LOOSE if loose else 0.0
        try:
            reason = self._snes()
        finally:
            self._loose = 0.0
        if reason is None:                # a singular Newton matrix: this attempt failed
            return False, "linear_solve_failed", max(len(self.history) - 1, 0)
        its = self.snes.getIterationNumber()
        self._stop_at = None            # a deadline covers this one SNES solve, never the re-solves below
        if self._budget_spent:          # the deadline came: the state is the last accepted Newton iterate
            return False, BUDGET_SPENT, its
        if self._event:                 # stopped where contacts formed (anchored there): go on with them
            return self._relag(its)
        if self.model.update_lag():     # lagged friction (or contacts a failed solve ran into): solve again
            return self._relag(its)
        if loose and reason > 0:        # the lags hold at a loosely solved state: solve it fully
            return self._relag(its, loose=0.0)
        if reason > 0:
            if not self.model.admissible(self.x):
                return False, "inverted_elements", its
            self._factorised = self._factorised or its > 0
            why = self.model.failure()                     # e.g. a free object that nothing holds
            return (False, why, its) if why else (True, "converged", its)
        log.debug("SNES reason %s", reason)
        return False, self._diverged(reason), its

    def note_force_scale(self) -> None:
        """The last attempt's first |R| joins the problem's force scale (``reference_residual``)."""
        if self.history:
            self.reference_residual = max(self.reference_residual, self.history[0])

    def _lags_follow(self) -> bool:
        """Whether a term's lags always change in a new step (Lagged.lags_follow_the_step: cable friction):
        the step's first solve is then a loose one, like the re-solves after it (see _relag)."""
        return any(isinstance(t, Lagged) and t.lags_follow_the_step() for t in self.model.terms)

    def _relag(self, its: int, loose: float = LAG_LOOSE) -> tuple[bool, str, int]:
        """Newton again after each change of the terms' lagged quantities, until none changes (loose: the
        re-solves' relative tolerance while the lags still change, 0 once they held at a loose state)."""
        self.note_force_scale()                 # the re-solves keep the first solve's force scale
        failed, rounds, events = 0, 0, 0
        tight = self._event                     # the round that takes up new contacts is solved fully
        while rounds < MAX_LAG_UPDATES and events < MAX_CONTACT_EVENTS:
            self._verdict_failure = None
            self.search.reset()
            self._loose = 0.0 if tight else loose
            try:
                ok, status, more = self._newton_once()
            finally:
                self._loose = 0.0
            its += more
            if not ok and status.startswith("no equilibrium"):   # an object gone: new lags cannot hold it
                return False, status, its
            if status == "contact_event":          # not a failure: the new contacts are held from here
                failed, events, tight = 0, events + 1, True
                continue
            tight = False
            changed = self.model.update_lag()
            rounds += 1
            failed = 0 if ok else failed + 1
            if not ok and (not changed or failed >= MAX_FAILED_ROUNDS):   # new lags did not help either
                return False, status, its
            if ok and not changed and loose:      # the lags hold at a loosely solved state: solve it fully
                loose = 0.0
                continue
            if ok and not changed:
                if not self.model.admissible(self.x):
                    return False, "inverted_elements", its
                self._factorised = self._factorised or its > 0
                why = self.model.failure()
                return (False, why, its) if why else (True, "converged", its)
        return False, "friction_not_converged", its

    def _newton_once(self) -> tuple[bool, str, int]:
        """One SNES solve from self.x (no lag update); the model's state follows it. Status
        "contact_event": it stopped where a contact formed that friction does not hold yet."""
        reason = self._snes()
        if reason is None:
            return False, "linear_solve_failed", 0
        if self._event:
            return False, "contact_event", self.snes.getIterationNumber()
        if reason > 0:
            return True, "converged", self.snes.getIterationNumber()
        return False, self._diverged(reason), self.snes.getIterationNumber()

    def _snes(self) -> int | None:
        """One SNES solve from self.x, the model's state following it: SNES's converged reason, or None
        if a Newton matrix was singular (the linear solver is reset for the next attempt)."""
        self._event = False
        self._retire()
        try:
            self.snes.solve(None, self.x)
        except np.linalg.LinAlgError as exc:
            log.debug("%s", exc)
            self.lin.reset()
            self.model.sync(self.model.u.vector)
            return None
        self.model.sync(self.x)
        return self.snes.getConvergedReason()

    def _diverged(self, reason: int) -> str:
        """Why a SNES solve that did not converge failed: the model's word (e.g. a free object sliding
        away), else a term's verdict or the line search's failure, else SNES's reason."""
        why = self.model.failure(converged=False)
        return why or self._verdict_failure or self.search.failure or _REASONS.get(reason, f"diverged ({reason})")

    def newton(self) -> SolveReport:
        """One Newton solve from the model's current state at the current parameters (no load ramp,
        no predictor, no retry): a time step. The state is left as Newton ended it, accepted
        (``end_step``) by the caller only if converged."""
        t0 = time.perf_counter()
        self.model.changes.clear()
        ok, status, its = self.attempt(loose_first=False)
        self.note_force_scale()
        report = SolveReport(ok, status, its, int(ok), [self.history],
                             [{"factor": self.model.factor, "iterations": int(its), "status": status}])
        self.lin.rtol = KRYLOV_RTOL
        report.time = time.perf_counter() - t0
        return report

    # -- load steps (skelfem.fem.loadstep) ----------------------------------------------
    def solve(self, steps: int = 1, start: float = 0.0, end: float = 1.0) -> SolveReport:
        """Ramp the load factor from start to end in `steps` steps (LoadStepper.solve)."""
        return self.stepper.solve(steps, start, end)

    def resolve(self, steps: int = 1, again: bool = False) -> SolveReport:
        """Warm re-solve from the last equilibrium (LoadStepper.resolve)."""
        return self.stepper.resolve(steps, again)

    def path(self, changes: dict, steps: int = 2) -> SolveReport:
        """The changed parameters moved along the parameter path (LoadStepper.path)."""
        return self.stepper.path(changes, steps)
