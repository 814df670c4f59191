"""Static equilibrium: PETSc SNES Newton on grad Pi = 0, with load stepping.

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

Contractions, loads and pin moves are ramped over ``steps`` load steps; a
failed step is retried with half the increment (up to ``max_cuts`` times).
A warm re-solve after a change of live parameters that fails cuts the step
of the change along the parameter path instead (``path``), from the last
equilibrium and its history.
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
from ..design.resources import direct_limit, stiff_elastic_bones
from .linear import LowRankSolver
from .multigrid import KRYLOV_RTOL, choose_linear, forcing
from ..terms.base import Term

log = logging.getLogger("skelfem")


MAX_LAG_UPDATES = 30   # re-solves with updated lagged quantities (friction's normal forces) per step
MAX_CONTACT_EVENTS = 100   # solves stopped where contacts formed (Model.contact_event), per step
MAX_FAILED_ROUNDS = 3  # re-solves in a row that fail although their lags changed: no equilibrium near
LAG_LOOSE = 1e-2       # a re-solve whose lags will change again stops at this times its own first |R|


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
        self.max_cuts = 8
        self.max_verdict_cuts = 0     # a path step that leaves an object unheld is cut this often at most
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
        self._history: list[float] = []
        self._failure: str | None = None
        self._f0 = 0.0
        self.search = EnergyLineSearch(model, self.b, self.lin.solve, curved=self.strategy == "curved")
        self._event = False           # the last SNES solve stopped at a contact event (Model.contact_event)
        # time.monotonic() after which a warm re-solve (resolve) stops after its current Newton step, its
        # state kept as a start for the next (status BUDGET_SPENT, not converged); None: no deadline. Only
        # for models whose answer does not depend on the path (no friction history to leave half-updated)
        self.deadline: float | None = None
        self._stop_at: float | None = None     # the deadline of the Newton solve running now
        self._budget_spent = False
        self._watch_events = any(getattr(t, "contact_event", None) is not None for t in model.terms)
        self._verdicts = [t for t in model.terms if type(t).verdict is not Term.verdict]   # asked every step
        self._factorised = False      # lin holds a factorisation of K near the current state
        self.equilibrium = Equilibrium()     # the last converged state (a re-solve with nothing changed)
        self.snes = self._create_snes(prefix)

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
            self.lin.rtol = forcing(self._history, self.lin.rtol, target)

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
        options: dict = {}
        if self.strategy == "trust_region":
            snes.setType("newtontr")
        else:
            snes.setType("newtonls")
            options = {"snes_linesearch_type": "bt" if self.strategy == "residual" else "basic", **options}
            if self.energy_search:
                snes.setLineSearchPreCheck(self._precheck)
        opts = PETSc.Options()
        for key, value in options.items():
            opts[f"{prefix}{key}"] = value
        snes.setTolerances(rtol=0.0, atol=0.0, stol=0.0, max_it=self.max_iterations)
        snes.setConvergenceTest(self._converged)
        snes.setFromOptions()
        for key in options:
            del opts[f"{prefix}{key}"]
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
        self._history.append(float(fnorm))
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
        if self.search.failure is not None or self._failure is not None or (it > 0 and self._verdict()):
            return PETSc.SNES.ConvergedReason.DIVERGED_LINE_SEARCH
        if it > 0 and self._stop_at is not None and time.monotonic() >= self._stop_at:
            self._budget_spent = True
            return PETSc.SNES.ConvergedReason.DIVERGED_MAX_IT
        if it >= self.max_iterations:
            return PETSc.SNES.ConvergedReason.DIVERGED_MAX_IT
        return PETSc.SNES.ConvergedReason.ITERATING

    def _verdict(self) -> bool:
        """Whether a term finds no equilibrium ahead of the iterate (Term.verdict; e.g. an object falling
        with nothing in its way): Newton ends with it as its failure instead of falling on."""
        if not self._verdicts:
            return False
        self.model.sync(self.x)
        self._failure = next((why for why in (t.verdict(self.model) for t in self._verdicts) if why), None)
        return self._failure is not None

    # -- solves ---------------------------------------------------------------------------
    def _newton(self) -> tuple[bool, str, int]:
        """Newton from the current state at the current load factor."""
        self._history, self._failure = [], None
        self.search.reset()
        self._event = False
        self._budget_spent = False
        self.model.u.vector.copy(self.x)
        self.model.apply_bcs(self.x)
        if not self.model.admissible(self.x):
            return False, "inverted_elements", 0
        self._retire()
        try:
            self.snes.solve(None, self.x)
        except np.linalg.LinAlgError as exc:     # a singular Newton matrix: this attempt failed
            log.debug("%s", exc)
            self.lin.reset()
            its = max(len(self._history) - 1, 0)
            self.model.sync(self.model.u.vector)
            return False, "linear_solve_failed", its
        self.model.sync(self.x)
        reason = self.snes.getConvergedReason()
        its = self.snes.getIterationNumber()
        self._stop_at = None            # a deadline covers this one SNES solve, never the re-solves below
        if self._budget_spent:          # the deadline came: the state is the last accepted Newton iterate
            return False, BUDGET_SPENT, its
        if self._event:                 # stopped where contacts formed (anchored there): go on with them
            return self._relag(its)
        if self.model.update_lag():     # lagged friction (or contacts a failed solve ran into): solve again
            return self._relag(its)
        if reason > 0:
            if not self.model.admissible(self.x):
                return False, "inverted_elements", its
            self._factorised = self._factorised or its > 0
            why = self.model.failure()                     # e.g. a free object that nothing holds
            return (False, why, its) if why else (True, "converged", its)
        log.debug("SNES reason %s", reason)
        why = self.model.failure(converged=False)          # e.g. a free object sliding away
        why = why or self._failure or self.search.failure
        return False, why or _REASONS.get(reason, f"diverged ({reason})"), its

    def _relag(self, its: int) -> tuple[bool, str, int]:
        """Newton again after each change of the terms' lagged quantities, until none changes."""
        if self._history:                       # the re-solves keep the first solve's force scale
            self.reference_residual = max(self.reference_residual, self._history[0])
        loose, failed, rounds, events = LAG_LOOSE, 0, 0, 0
        tight = self._event                     # the round that takes up new contacts is solved fully
        while rounds < MAX_LAG_UPDATES and events < MAX_CONTACT_EVENTS:
            self._failure = None
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
                self._factorised = True
                why = self.model.failure()
                return (False, why, its) if why else (True, "converged", its)
        return False, "friction_not_converged", its

    def _newton_once(self) -> tuple[bool, str, int]:
        """One SNES solve from self.x (no lag update); the model's state follows it. Status
        "contact_event": it stopped where a contact formed that friction does not hold yet."""
        self._event = False
        self._retire()
        try:
            self.snes.solve(None, self.x)
        except np.linalg.LinAlgError as exc:
            log.debug("%s", exc)
            self.lin.reset()
            self.model.sync(self.model.u.vector)
            return False, "linear_solve_failed", 0
        self.model.sync(self.x)
        reason = self.snes.getConvergedReason()
        if self._event:
            return False, "contact_event", self.snes.getIterationNumber()
        if reason > 0:
            return True, "converged", self.snes.getIterationNumber()
        why = self.model.failure(converged=False)
        why = why or self._failure or self.search.failure or _REASONS.get(reason, f"diverged ({reason})")
        return False, why, self.snes.getIterationNumber()

    def _predict(self, prev, a_prev: float, a: float, target: float) -> None:
        """Secant predictor: extrapolate the last increment to the new load factor."""
        if prev is None or a <= a_prev:
            return
        model = self.model
        u = model.u.vector
        guess = u.copy()
        guess.axpy((target - a) / (a - a_prev), u - prev)
        model.set_factor(target)
        current = u.copy()
        model.apply_bcs(current)
        model.apply_bcs(guess)
        reachable = model.max_step(u.array_r, guess.array_r - u.array_r) >= 1.0
        if reachable and model.admissible(guess) and (not model.admissible(current)
                                                      or model.energy(guess) < model.energy(current)):
            guess.copy(u)
        for v in (guess, current):
            v.destroy()
        model.set_factor(a)
        model.sync(u)

    def solve(self, steps: int = 1, start: float = 0.0, end: float = 1.0) -> SolveReport:
        """Ramp the load factor from start to end in `steps` steps (cut in half on failure)."""
        t0 = time.perf_counter()
        model = self.model
        model.changes.clear()
        report = SolveReport(False, "not_started")
        a, da, cuts = start, (end - start) / max(int(steps), 1), 0
        da0 = da
        saved = model.u.vector.copy()
        committed = model.history()          # a failed attempt's anchors and slips are taken back
        prev, a_prev = None, a
        while a < end - 1e-12:
            target = min(a + da, end)
            self._predict(prev, a_prev, a, target)
            model.set_factor(target)
            ok, status, its = self._newton()
            if self._history:
                self.reference_residual = max(self.reference_residual, self._history[0])
            report.newton_iterations += its
            report.attempts.append({"factor": float(target), "iterations": int(its), "status": status})
            if ok:
                report.load_steps += 1
                report.residual_history.append(self._history)
                report.linear_iterations.append(self.lin.take_krylov())
                log.info("load step %d: factor %.4g, %d Newton iterations, |R| %.2e -> %.2e",
                         report.load_steps, target, its, self._history[0] if self._history else 0.0,
                         self._history[-1] if self._history else 0.0)
                model.end_step()
                committed = model.history()
                prev = prev or saved.duplicate()
                saved.copy(prev)
                a_prev, a = a, target
                if its <= 8:
                    da = min(2.0 * da, da0)
                model.u.vector.copy(saved)
                continue
            log.info("load step to factor %.4g failed (%s)", target, status)
            saved.copy(model.u.vector)
            model.set_history(committed)
            model.set_factor(a)
            model.sync(model.u.vector)
            cuts += 1
            if cuts > self.max_cuts or status.startswith("no equilibrium"):   # smaller steps cannot help
                report.status = status
                report.residual_history.append(self._history)
                report.linear_iterations.append(self.lin.take_krylov())
                break
            da = (target - a) / 2.0
        else:
            report.converged, report.status = True, "converged"
        for v in (saved, prev):
            if v is not None:
                v.destroy()
        return self._finish(report, t0)

    def newton(self) -> SolveReport:
        """One Newton solve from the model's current state at the current parameters (no load ramp,
        no predictor, no retry): a time step. The state is left as Newton ended it, accepted
        (``end_step``) by the caller only if converged."""
        t0 = time.perf_counter()
        self.model.changes.clear()
        ok, status, its = self._newton()
        if self._history:
            self.reference_residual = max(self.reference_residual, self._history[0])
        report = SolveReport(ok, status, its, int(ok), [self._history],
                             [{"factor": self.model.factor, "iterations": int(its), "status": status}])
        self.lin.rtol = KRYLOV_RTOL
        report.time = time.perf_counter() - t0
        return report

    def _finish(self, report: SolveReport, t0: float) -> SolveReport:
        model = self.model
        if report.converged:
            self.equilibrium.mark(model)
        else:
            self.equilibrium.forget()
        self.lin.rtol = KRYLOV_RTOL                    # what follows a solve (sensitivities) solves tightly
        report.linear_solver = self.lin.kind
        rest = self.lin.take_krylov()                  # a failed attempt's, not followed by a step
        if rest:
            report.linear_iterations.append(rest)
        report.linear_fallbacks, report.linear_loose_steps = self.lin.fallbacks, self.lin.loose_steps
        self.lin.fallbacks = self.lin.loose_steps = 0
        report.energy = model.energy(model.u.vector)
        report.min_jacobian = model.min_jacobian(model.u.vector)
        report.time = time.perf_counter() - t0
        return report

    def _tangent_predictor(self) -> float:
        """Euler predictor from the last equilibrium u_0 to the changed parameters p_1.

        The step is d = -H_0^{-1} (dR/dp) (p_1 - p_0) = du/dp (p_1 - p_0), the
        first-order change of the equilibrium, with H_0 the Hessian already
        factorised next to u_0 (one back-substitution: no assembly, no
        factorisation). dR/dp (p_1 - p_0) is the difference quotient of R(u_0)
        along the parameter path with the active set of u_0 (a small step
        keeps taut cables taut): a cable that the new rest length leaves
        momentarily slack at u_0 still pulls in the prediction, where a
        Newton step at u_0 would let the body spring past the equilibrium.
        The energy line search with the new parameters scales it like a
        Newton step. Returns the step length taken (0 if none).
        """
        model = self.model
        if not self._factorised or all(np.array_equal(o, n) for o, n in model.changes.values()):
            return 0.0
        x = model.u.vector.copy()
        r0, d = x.duplicate(), x.duplicate()
        eps = 1e-4
        try:
            for s, vec in ((0.0, r0), (eps, self.b)):
                model.parameter_path(s)
                model.residual(x, vec)
            self.b.axpy(-1.0, r0)
            self.b.scale(1.0 / eps)                         # dR/dp (p_1 - p_0) at u_0
            model.parameter_path(1.0)
            try:
                self.lin.solve(self.b, d)
            except np.linalg.LinAlgError:
                return 0.0
            p = -d.array_r.copy()                           # pinned rows: g(p_1) - g(p_0)
            model.gradient(x, self.b)                       # grad Pi with the new parameters, all rows
            r = self.b.array_r
            slope = float(model.comm.allreduce(r @ p))
            if not np.isfinite(slope) or slope >= 0.0:
                return 0.0
            x0 = x.array_r.copy()
            f0 = float(np.sqrt(model.comm.allreduce(r @ r)))
            alpha, ok = self.search.backtrack(x, x0, p, model.energy(x), slope, f0, model.max_step(x0, p))
            if not ok:
                return 0.0
            x.array_w[:] = x0 + alpha * p + model.step_correction(x0, p, alpha)
            x.copy(model.u.vector)
            return float(alpha)
        finally:
            model.parameter_path(1.0)
            model.sync(model.u.vector)
            for v in (x, r0, d):
                v.destroy()

    def resolve(self, steps: int = 1, again: bool = False) -> SolveReport:
        """Warm re-solve: a tangent predictor, then Newton at the new parameters, from the last equilibrium.

        With the state and every parameter as the last converged solve left them, nothing is solved
        (0 iterations: the same state), unless ``again`` asks for a new step at the same load (a
        quasi-static step in which time passes: friction's anchors are carried into it).

        If that fails (other than by an object that is not held, which ends
        the solve), the step of the change is cut: the changed parameters
        go from their old values to their new ones along the parameter path
        (:meth:`path`), each step starting from the last equilibrium reached
        and its history (friction's anchors), never from rest: a grip is
        not squeezed and loaded at once. The report counts every iteration.

        With a ``deadline`` (and no path dependence), Newton stops after the first step that ends past it:
        the report is not converged, its status BUDGET_SPENT, and the state, the last accepted iterate, is
        where the next resolve goes on from (the editor's frames while a handle is dragged).
        """
        t0 = time.perf_counter()
        model = self.model
        if not again and self.equilibrium.holds(model):
            # nothing to re-solve: the state is the converged one for these parameters. With friction a
            # new step from it would start with new anchors and lags and could settle elsewhere (friction's
            # equilibria are not unique): a re-solve with unchanged parameters returns the same state
            model.changes.clear()
            return self._finish(SolveReport(True, "converged", 0, 0, [], [
                {"factor": 1.0, "iterations": 0, "status": "converged", "warm": True, "unchanged": True}]), t0)
        saved = model.u.vector.copy()
        committed = model.history()
        changes = dict(model.changes)
        model.set_factor(1.0)
        predicted = self._tangent_predictor()
        model.changes.clear()
        self._stop_at = self.deadline if not model.path_dependent else None
        try:
            ok, status, its = self._newton()
        finally:
            self._stop_at = None
        if status == BUDGET_SPENT and model.admissible(model.u.vector):   # a preview: the next call goes on
            saved.destroy()
            return self._finish(SolveReport(False, status, its, 0, [self._history], [
                {"factor": 1.0, "iterations": int(its), "status": status, "warm": True,
                 "predictor_step": predicted}]), t0)
        report = SolveReport(ok, status, its, int(ok), [self._history] if ok else [],
                             [{"factor": 1.0, "iterations": int(its), "status": status, "warm": True,
                               "predictor_step": predicted}],
                             linear_iterations=[self.lin.take_krylov()] if ok else [])
        if ok or not changes or status.startswith("no equilibrium"):   # an object not held: no smaller step
            if ok:                                                    # of the same change holds it either
                model.end_step()
            saved.destroy()
            return self._finish(report, t0)
        log.info("warm re-solve failed (%s); cutting the step along the parameter path", status)
        saved.copy(model.u.vector)
        model.set_history(committed)       # the failed attempt's new anchors and slips are not history
        model.sync(model.u.vector)
        saved.destroy()
        path = self.path(changes, max(int(steps), 2))
        path.newton_iterations += its
        path.attempts = report.attempts + path.attempts
        path.time = time.perf_counter() - t0
        return path

    def path(self, changes: dict, steps: int = 2) -> SolveReport:
        """Move the changed parameters ({key: (old, new)}) from old to new in steps along the parameter
        path, from the current state (an equilibrium at the old values), each step warm from the last
        one accepted, with a tangent predictor; a failed step is retried with half the increment (up to
        ``max_cuts`` times; ``max_verdict_cuts`` times when an object is not held: the verdict is about
        the equilibrium at the new values, which a smaller step reaches too). The parameters end at their
        new values."""
        t0 = time.perf_counter()
        model = self.model
        report = SolveReport(False, "not_started")
        s, ds, cuts, verdicts = 0.0, 1.0 / steps, 0, 0
        ds0 = ds
        saved = model.u.vector.copy()
        committed = model.history()

        def at(key: str, t: float):
            old, new = changes[key]
            return old + t * (new - old)
        try:
            while s < 1.0 - 1e-12:
                target = min(s + ds, 1.0)
                model.changes = {k: (at(k, s), at(k, target)) for k in changes}
                model.parameter_path(1.0)
                model.set_factor(1.0)
                predicted = self._tangent_predictor()
                model.changes.clear()
                ok, status, its = self._newton()
                report.newton_iterations += its
                report.attempts.append({"path": float(target), "iterations": int(its), "status": status,
                                        "predictor_step": predicted})
                if ok:
                    report.load_steps += 1
                    report.residual_history.append(self._history)
                    report.linear_iterations.append(self.lin.take_krylov())
                    log.info("path step %d: to %.4g of the change, %d Newton iterations", report.load_steps,
                             target, its)
                    model.end_step()
                    committed = model.history()
                    model.u.vector.copy(saved)
                    s = target
                    if its <= 8:
                        ds = min(2.0 * ds, ds0)
                    continue
                log.info("path step to %.4g of the change failed (%s)", target, status)
                saved.copy(model.u.vector)
                model.set_history(committed)
                model.sync(model.u.vector)
                self._factorised = False
                cuts += 1
                verdicts += status.startswith("no equilibrium")
                if cuts > self.max_cuts or verdicts > self.max_verdict_cuts:
                    report.status = status
                    report.residual_history.append(self._history)
                    report.linear_iterations.append(self.lin.take_krylov())
                    break
                ds = (target - s) / 2.0
            else:
                report.converged, report.status = True, "converged"
        finally:
            model.changes = {k: (old, new) for k, (old, new) in changes.items()}
            model.parameter_path(1.0)
            model.changes.clear()
            model.set_factor(1.0)
            saved.destroy()
        return self._finish(report, t0)
