"""Load stepping: the load factor ramped over load steps, a warm re-solve and the parameter path,
each step a Newton solve (skelfem.fem.newton) from a predicted state.

Contractions, loads and pin moves are ramped over ``steps`` load steps (a secant predictor
extrapolates the last increment); a failed step is retried with half the increment (up to
``max_cuts`` times). A warm re-solve after a change of live parameters starts from a tangent
predictor; if it fails, the step of the change is cut along the parameter path instead (``path``),
from the last equilibrium and its history.

``LoadStepper`` sees the Newton solver through the small interface ``Newton`` below: one Newton
solve from the model's state (``attempt``), that solve's residuals, the factorisation it left, the
last converged state and the line search's backtracking (the tangent predictor's step); the
settings of the stepping (``max_cuts``, ``max_verdict_cuts``, ``deadline``) are its own.
"""
from __future__ import annotations

import logging
import time
from typing import Any, Protocol

import numpy as np

from .report import BUDGET_SPENT, SolveReport
from .multigrid import KRYLOV_RTOL

log = logging.getLogger("skelfem")


class Newton(Protocol):
    """What load stepping needs of a Newton solver (skelfem.fem.newton.NewtonSolver)."""

    model: Any
    lin: Any                   # the linear solver: solve, take_krylov, rtol, kind, fallbacks, loose_steps
    search: Any                # the energy line search: backtrack
    equilibrium: Any           # the last converged state: mark, forget, holds
    history: list[float]       # |R| of each iteration of the last attempt

    def attempt(self, stop_at: float | None = None) -> tuple[bool, str, int]: ...

    def note_force_scale(self) -> None: ...

    @property
    def factorised(self) -> bool: ...

    def forget(self) -> None: ...


class LoadStepper:
    """Load steps, warm re-solves and parameter paths of one Newton solver."""

    def __init__(self, newton: Newton):
        self.newton = newton
        self.max_cuts = 8             # halvings of a load (or path) step before the solve gives up
        self.max_verdict_cuts = 0     # a path step that leaves an object unheld is cut this often at most
        # time.monotonic() after which a warm re-solve (resolve) stops after its current Newton step, its
        # state kept as a start for the next (status BUDGET_SPENT, not converged); None: no deadline. Only
        # for models whose answer does not depend on the path (no friction history to leave half-updated)
        self.deadline: float | None = None

    @property
    def model(self):
        return self.newton.model

    def _secant(self, prev, a_prev: float, a: float, target: float) -> None:
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
            self._secant(prev, a_prev, a, target)
            model.set_factor(target)
            ok, status, its = self.newton.attempt()
            self.newton.note_force_scale()
            history = self.newton.history
            report.newton_iterations += its
            report.attempts.append({"factor": float(target), "iterations": int(its), "status": status})
            if ok:
                report.load_steps += 1
                report.residual_history.append(history)
                report.linear_iterations.append(self.newton.lin.take_krylov())
                log.info("load step %d: factor %.4g, %d Newton iterations, |R| %.2e -> %.2e",
                         report.load_steps, target, its, history[0] if history else 0.0,
                         history[-1] if history else 0.0)
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
                report.residual_history.append(history)
                report.linear_iterations.append(self.newton.lin.take_krylov())
                break
            da = (target - a) / 2.0
        else:
            report.converged, report.status = True, "converged"
        for v in (saved, prev):
            if v is not None:
                v.destroy()
        return self._finish(report, t0)

    def _finish(self, report: SolveReport, t0: float) -> SolveReport:
        model = self.model
        if report.converged:
            self.newton.equilibrium.mark(model)
        else:
            self.newton.equilibrium.forget()
        self.newton.lin.rtol = KRYLOV_RTOL                    # what follows a solve (sensitivities) solves tightly
        report.linear_solver = self.newton.lin.kind
        rest = self.newton.lin.take_krylov()                  # a failed attempt's, not followed by a step
        if rest:
            report.linear_iterations.append(rest)
        report.linear_fallbacks, report.linear_loose_steps = self.newton.lin.fallbacks, self.newton.lin.loose_steps
        self.newton.lin.fallbacks = self.newton.lin.loose_steps = 0
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
        model, lin = self.model, self.newton.lin
        if not self.newton.factorised or all(np.array_equal(o, n) for o, n in model.changes.values()):
            return 0.0
        x = model.u.vector.copy()
        r0, d, b = x.duplicate(), x.duplicate(), x.duplicate()
        eps = 1e-4
        try:
            for s, vec in ((0.0, r0), (eps, b)):
                model.parameter_path(s)
                model.residual(x, vec)
            b.axpy(-1.0, r0)
            b.scale(1.0 / eps)                              # dR/dp (p_1 - p_0) at u_0
            model.parameter_path(1.0)
            try:
                lin.solve(b, d)
            except np.linalg.LinAlgError:
                return 0.0
            p = -d.array_r.copy()                           # pinned rows: g(p_1) - g(p_0)
            model.gradient(x, b)                            # grad Pi with the new parameters, all rows
            r = b.array_r
            slope = float(model.comm.allreduce(r @ p))
            if not np.isfinite(slope) or slope >= 0.0:
                return 0.0
            x0 = x.array_r.copy()
            f0 = float(np.sqrt(model.comm.allreduce(r @ r)))
            alpha, ok = self.newton.search.backtrack(x, x0, p, model.energy(x), slope, f0, model.max_step(x0, p))
            if not ok:
                return 0.0
            x.array_w[:] = x0 + alpha * p + model.step_correction(x0, p, alpha)
            x.copy(model.u.vector)
            return float(alpha)
        finally:
            model.parameter_path(1.0)
            model.sync(model.u.vector)
            for v in (x, r0, d, b):
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

        With a ``deadline`` (and no path dependence), Newton stops after the first step that ends past it,
        or takes none when the tangent predictor took a step and ended past it: the report is not
        converged, its status BUDGET_SPENT, and the state, the last accepted iterate (or the predicted
        one), is where the next resolve goes on from (the editor's frames while a handle is dragged).
        """
        t0 = time.perf_counter()
        model = self.model
        if not again and self.newton.equilibrium.holds(model):
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
        stop_at = self.deadline if not model.path_dependent else None
        if stop_at is not None and predicted > 0 and time.monotonic() >= stop_at:
            # the predictor spent the frame's time: its state is the frame, and Newton goes on from it next time
            saved.destroy()
            return self._finish(SolveReport(False, BUDGET_SPENT, 0, 0, [], [
                {"factor": 1.0, "iterations": 0, "status": BUDGET_SPENT, "warm": True,
                 "predictor_step": predicted}]), t0)
        ok, status, its = self.newton.attempt(stop_at=stop_at)
        if status == BUDGET_SPENT and model.admissible(model.u.vector):   # a preview: the next call goes on
            saved.destroy()
            return self._finish(SolveReport(False, status, its, 0, [self.newton.history], [
                {"factor": 1.0, "iterations": int(its), "status": status, "warm": True,
                 "predictor_step": predicted}]), t0)
        report = SolveReport(ok, status, its, int(ok), [self.newton.history] if ok else [],
                             [{"factor": 1.0, "iterations": int(its), "status": status, "warm": True,
                               "predictor_step": predicted}],
                             linear_iterations=[self.newton.lin.take_krylov()] if ok else [])
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
                ok, status, its = self.newton.attempt()
                report.newton_iterations += its
                report.attempts.append({"path": float(target), "iterations": int(its), "status": status,
                                        "predictor_step": predicted})
                if ok:
                    report.load_steps += 1
                    report.residual_history.append(self.newton.history)
                    report.linear_iterations.append(self.newton.lin.take_krylov())
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
                self.newton.forget()             # K was factorised at the failed attempt's state
                cuts += 1
                verdicts += status.startswith("no equilibrium")
                if cuts > self.max_cuts or verdicts > self.max_verdict_cuts:
                    report.status = status
                    report.residual_history.append(self.newton.history)
                    report.linear_iterations.append(self.newton.lin.take_krylov())
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
