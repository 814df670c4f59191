"""Static equilibrium: PETSc SNES Newton on grad Pi = 0, with load stepping.

Newton's direction p solves H p = -grad Pi with H = K + sum c g g^T: the
sparse matrix K factorised (MUMPS LDL^T, the matrix pattern fixed so the
symbolic factorisation is reused) and the rank-one parts of taut cables
added by the Woodbury formula (skelfem.linear), through a PETSc python PC.
The default line search ("energy") runs in SNES's pre-check: it starts from
the model's admissible step alpha_max = model.max_step(x, p) <= 1 (e.g. the
collision-free step of self-contact) and backtracks until the trial state is admissible (det F > 0
in every element, no term objects) and satisfies the Armijo condition

    Pi(x + alpha p) <= Pi(x) + c alpha grad Pi . p,

or, once energy differences drown in round-off, reduces |grad Pi|. A trial
state with an inverted element is never accepted. Other strategies
(``residual``: PETSc's backtracking on |grad Pi|, ``none``: full steps,
``trust_region``: PETSc's newtontr) exist to compare against.

Contractions, loads and pin moves are ramped over ``steps`` load steps; a
failed step is retried with half the increment (up to ``max_cuts`` times).
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from .design import LINE_SEARCHES as STRATEGIES
from .linear import LowRankSolver, default_petsc_options  # noqa: F401 (re-exported)

log = logging.getLogger("skelfem")

MAX_PREDICTED_GRADIENT = 0.5   # largest predicted change of |grad u| in one continuation step
STEP_RTOL = 1e-5               # Newton tolerance (relative to the force scale) of intermediate steps
PATH_EPS = 1e-6                # step in s of the difference quotient dR/ds


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


class SolveError(RuntimeError):
    """Raised by callers that need an equilibrium and did not get one."""


@dataclass
class SolveReport:
    converged: bool
    status: str
    newton_iterations: int = 0
    load_steps: int = 0
    residual_history: list = field(default_factory=list)   # one list of |R| per load step
    attempts: list = field(default_factory=list)           # every Newton run: factor, iterations, status
    energy: float = float("nan")
    min_jacobian: float = float("nan")
    time: float = 0.0


class NewtonSolver:
    """SNES Newton for one Model; reusable across solves (warm starts)."""

    def __init__(self, model, spec=None, petsc_options: dict | None = None, prefix: str = "skelfem_"):
        self.model = model
        spec = spec if spec is not None else model.design.solver
        self.strategy = spec.line_search
        if self.strategy not in STRATEGIES:
            raise ValueError(f"unknown line search {self.strategy!r}")
        if self.strategy != "energy" and model.bounds_steps:
            raise ValueError(f"line search {self.strategy!r} cannot limit steps to the model's "
                             "admissible ones; use 'energy'")
        self.max_iterations, self.rtol, self.atol = spec.max_iterations, spec.rtol, spec.atol
        self.geodesic = True          # curved line search (geodesic acceleration) when a plain step fails
        self.xtol = 1e-11             # relative size of a full Newton step that ends the solve
        self.max_cuts = 8
        self._newton_step = np.inf    # |p| of the last undamped Newton step
        self.reference_residual = 0.0  # largest first |R| of a solve from rest (the problem's force scale)
        self.etol = 1e-15             # Newton decrement -grad Pi . p relative to |Pi| that ends the solve
        self._decrement_converged = False
        self.A = model.create_matrix()
        self.lin = LowRankSolver(self.A, model.comm, petsc_options, prefix + "k_")
        self.b = model.u.vector.duplicate()
        self.x = model.u.vector.copy()      # SNES iterate; model.u is scratch for evaluations
        self._history: list[float] = []
        self._failure: str | None = None
        self._f0 = 0.0
        self._rtol = self.rtol           # the tolerance of the running Newton solve
        self._last_trial = None       # (state, Pi) of the last accepted line-search trial
        self._factorised = False      # lin holds a factorisation of K near the current state
        self.snes = self._create_snes(prefix)

    # -- SNES set-up -------------------------------------------------------------------
    def jacobian(self, x: PETSc.Vec) -> None:
        """Assemble K at x and factorise it with the rank-one parts (what every Newton solve uses)."""
        self.model.jacobian(x, self.A)
        self.lin.update(self.model.low_rank())

    def _create_snes(self, prefix: str) -> PETSc.SNES:
        snes = PETSc.SNES().create(self.model.comm)
        snes.setOptionsPrefix(prefix)
        snes.setFunction(lambda s, x, b: self.model.residual(x, b), self.b)
        snes.setJacobian(lambda s, x, A, P: self.jacobian(x), self.A)
        options = {}
        if self.strategy == "trust_region":
            snes.setType("newtontr")
        else:
            snes.setType("newtonls")
            options = {"snes_linesearch_type": "bt" if self.strategy == "residual" else "basic",
                       **options}
            if self.strategy == "energy":
                snes.setLineSearchPreCheck(self._energy_line_search)
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

    def destroy(self) -> None:
        self.snes.destroy()
        self.lin.destroy()
        for v in (self.A, self.b, self.x):
            v.destroy()

    def _converged(self, snes, it, norms):
        """|R| <= max(atol, rtol |R_0|), or a full Newton step below xtol * size."""
        xnorm, ynorm, fnorm = norms
        self._history.append(float(fnorm))
        if it == 0:
            # the force scale: |R| at the start of a solve from rest; a warm start, whose first
            # residual is small, is held to the same absolute accuracy, not to rtol of its own |R_0|
            self._f0 = max(fnorm, self.reference_residual)
        log.debug("  newton %2d  |R| = %.3e  |dx| = %.3e", it, fnorm, ynorm)
        if not np.isfinite(fnorm):
            return PETSc.SNES.ConvergedReason.DIVERGED_FNORM_NAN
        if fnorm <= max(self.atol, self._rtol * self._f0):
            return PETSc.SNES.ConvergedReason.CONVERGED_FNORM_ABS
        if self._decrement_converged:
            return PETSc.SNES.ConvergedReason.CONVERGED_FNORM_RELATIVE
        step = self._newton_step if self.strategy == "energy" else ynorm
        if it > 0 and step <= self.xtol * max(xnorm, self.model.size):
            return PETSc.SNES.ConvergedReason.CONVERGED_SNORM_RELATIVE
        if self._failure is not None:
            return PETSc.SNES.ConvergedReason.DIVERGED_LINE_SEARCH
        if it >= self.max_iterations:
            return PETSc.SNES.ConvergedReason.DIVERGED_MAX_IT
        return PETSc.SNES.ConvergedReason.ITERATING

    def _energy_line_search(self, x, y):
        """SNES pre-check: scale the step -y so that x - y is admissible and lowers Pi."""
        model = self.model
        p = -y.array_r.copy()                       # Newton direction (SNES steps x - y)
        r = self.b.array_r.copy()                   # grad Pi at x, set by SNES
        x0 = x.array_r.copy()
        slope = float(model.comm.allreduce(r @ p))
        e0 = self._energy_at(x)
        self._newton_step = float(np.sqrt(model.comm.allreduce(p @ p)))
        if 0.0 <= -slope <= self.etol * max(abs(e0), 1e-300):
            # Newton decrement at round-off level: x is the minimiser to machine precision
            self._decrement_converged = True
            return self._take(x, y, p, self._max_step(x0, p)) or True
        if slope > 0.0:                             # not a descent direction: turn around
            p, slope = -p, -slope
        f0 = float(np.sqrt(model.comm.allreduce(r @ r)))
        alpha0 = self._max_step(x0, p)
        accel = None
        if self.geodesic and not self._full_step_accepted(x, x0, p, e0, slope, alpha0):
            accel = self._acceleration(x, x0, p, r)
        alpha, accepted = self._backtrack(x, x0, p, e0, slope, f0, alpha0, accel=accel)
        model.sync(x)
        if not accepted:
            self._failure = "line_search_failed"
            y.set(0.0)
        else:
            step = alpha * p + (0.5 * alpha ** 2 * accel if accel is not None else 0.0)
            y.array_w[:] = -(step + model.step_correction(x0, step / alpha, alpha))
        log.debug("  line search: alpha %.3g, decrement %.3e, energy %.9e", alpha if accepted else 0.0,
                  -slope, e0)
        return True

    def _max_step(self, x0: np.ndarray, p: np.ndarray) -> float:
        """The model's admissible step along p, agreed over ranks."""
        return self.model.max_step(x0, p)

    def _full_step_accepted(self, x, x0, p, e0, slope, alpha0, c1=1e-4) -> bool:
        """Whether the plain step alpha0 p is admissible and passes the Armijo test."""
        trial = x.duplicate()
        try:
            trial.array_w[:] = x0 + alpha0 * p + self.model.step_correction(x0, p, alpha0)
            if not self.model.admissible(trial):
                return False
            e = self.model.energy(trial)
            ok = e <= e0 + c1 * alpha0 * slope
            if ok:
                self._last_trial = (trial.array_r.copy(), e)
            return ok
        finally:
            trial.destroy()
            self.model.sync(x)

    def _acceleration(self, x, x0, p, r=None, r_at_x=None) -> np.ndarray:
        """Geodesic acceleration a = -H^{-1} D^2R[p, p] of the Newton step (second-order curve).

        x(alpha) = x0 + alpha p + alpha^2 a / 2 follows the solution curve to
        second order: where the body rotates, the straight step stretches it
        by O(alpha^2) and the line search must cut; the curve bends back along
        the arc. D^2R[p, p] by central differences over a step h p with
        h max|grad p| = 1e-2; one back-substitution on the current factorisation.
        """
        model = self.model
        vec = x.duplicate()
        res = x.duplicate()
        try:
            vec.array_w[:] = p
            g = model.max_gradient(vec)
            h = 1e-2 / g if g > 0 else 1.0
            if r is None:
                vec.array_w[:] = x0
                model.residual(vec, res)
                r = res.array_r.copy()
            d2 = -2.0 * r
            for sign in (1.0, -1.0):
                vec.array_w[:] = x0 + sign * h * p
                model.residual(vec, res)
                d2 = d2 + res.array_r
            res.array_w[:] = d2 / h ** 2
            self.lin.solve(res, vec)
            return -vec.array_r.copy()
        finally:
            vec.destroy()
            res.destroy()
            model.sync(x)

    def _backtrack(self, x, x0, p, e0, slope, f0, alpha0=1.0, c1=1e-4, accel=None):
        """Armijo backtracking with quadratic interpolation on phi(a) = Pi(x + a p), a <= alpha0.

        A trial state that is not admissible has phi = +inf. Within round-off
        of e0 a step is accepted if it lowers |grad Pi|. Bones move along the
        exact rotation whose linearisation is p (see Elasticity.step_correction),
        so a stiff bone's rotation does not turn into stretch.
        """
        model = self.model
        trial = x.duplicate()

        def phi(a):
            step = a * p if accel is None else a * p + 0.5 * a * a * accel
            trial.array_w[:] = x0 + step + model.step_correction(x0, step / a, a)
            return model.energy(trial) if model.admissible(trial) else np.inf

        noise = max(model.energy_noise, 1e-12 * abs(e0))
        if alpha0 <= 0.0:
            trial.destroy()
            return 0.0, False
        alpha, e = alpha0, phi(alpha0)
        try:
            for _ in range(40):
                if e <= e0 + c1 * alpha * slope:
                    self._last_trial = (trial.array_r.copy(), e)
                    return alpha, True
                if np.isfinite(e) and abs(e - e0) <= noise:
                    trial.array_w[:] = x0 + alpha * p
                    model.residual(trial, self.b)
                    better = self.b.norm() < f0
                    model.residual(x, self.b)
                    if better:
                        return alpha, True
                if np.isfinite(e):
                    curvature = (e - e0 - alpha * slope) / alpha ** 2
                    a_new = -slope / (2.0 * curvature) if curvature > 0 else 0.5 * alpha
                    alpha = float(np.clip(a_new, 0.1 * alpha, 0.5 * alpha))
                else:
                    alpha *= 0.5
                e = phi(alpha)
            return 0.0, False
        finally:
            trial.destroy()

    def _energy_at(self, x) -> float:
        """Pi(x), reusing the energy of the last accepted trial state if x is that state (to round-off)."""
        last, self._last_trial = self._last_trial, None
        if last is not None and len(last[0]) == len(x.array_r):
            diff = np.abs(x.array_r - last[0]).max(initial=0.0)
            scale = max(np.abs(last[0]).max(initial=0.0), self.model.size)
            if self.model.comm.allreduce(diff <= 1e-13 * scale, op=MPI.LAND):
                return last[1]
        return self.model.energy(x)

    def _take(self, x, y, p, alpha) -> bool:
        """Set the SNES step to alpha p if x + alpha p is admissible (and alpha > 0), else to zero."""
        trial = x.copy()
        trial.array_w[:] += alpha * p
        ok = alpha > 0.0 and self.model.admissible(trial)
        trial.destroy()
        self.model.sync(x)
        if ok:
            y.array_w[:] = -alpha * p
        else:
            y.set(0.0)
        return ok

    # -- solves ---------------------------------------------------------------------------
    def _newton(self, rtol: float | None = None) -> tuple[bool, str, int]:
        """Newton from the current state at the current loads, to |R| <= rtol * the force scale."""
        self._history, self._failure, self._newton_step = [], None, np.inf
        self._decrement_converged = False
        self._last_trial = None
        self._rtol = self.rtol if rtol is None else rtol
        self.model.u.vector.copy(self.x)
        self.model.apply_bcs(self.x)
        if not self.model.admissible(self.x):
            return False, "inverted_elements", 0
        self.snes.solve(None, self.x)
        self.model.sync(self.x)
        reason = self.snes.getConvergedReason()
        its = self.snes.getIterationNumber()
        self._factorised = self._factorised or its > 0
        if reason > 0:
            if not self.model.admissible(self.x):
                return False, "inverted_elements", its
            return True, "converged", its
        log.debug("SNES reason %s", reason)
        return False, self._failure or _REASONS.get(reason, f"diverged ({reason})"), its

    # -- continuation: Euler predictor, Newton corrector ------------------------------------------
    def _path_residuals(self, path, s: float) -> tuple[PETSc.Vec, PETSc.Vec]:
        """(R(u; s), dR/ds(u; s)): the residual at the current state and its rate along the path.

        The rate is a forward difference over a small step in s, so it keeps
        the active set of u (a taut cable stays taut, a slack one slack).
        """
        model, x = self.model, self.model.u.vector
        r0, rate = x.duplicate(), x.duplicate()
        path(s)
        model.gradient(x, r0)
        path(s + PATH_EPS)
        model.gradient(x, rate)
        path(s)
        rate.axpy(-1.0, r0)
        rate.scale(1.0 / PATH_EPS)
        return r0, rate

    def _predict(self, path, s: float, ds: float) -> tuple[float, float]:
        """Euler predictor from the equilibrium at s; returns (t, alpha) and leaves the loads at t.

        With H the Hessian factorised next to u (the last Newton matrix: one
        back-substitution per right-hand side, no assembly), the state moves
        along p = -H^{-1} (R + (t - s) dR/ds), i.e. to u(s) + du/ds (t - s) to
        first order. t <= s + ds is cut so that the predicted change of the
        displacement gradient, (t - s) max |grad du/ds|, stays below
        MAX_PREDICTED_GRADIENT (large rotations are taken in steps the
        linearisation can follow). The energy line search at t scales the
        step (alpha). Pinned rows move from g(s) to g(t) with the step.
        """
        model = self.model
        x = model.u.vector
        r0, rate = self._path_residuals(path, s)
        d0, d1 = x.duplicate(), x.duplicate()
        try:
            self._dirichlet_rows(r0, rate, s, path)
            self.lin.solve(r0, d0)
            self.lin.solve(rate, d1)
        except np.linalg.LinAlgError:
            t = min(s + ds, 1.0)
            path(t)
            return t, 0.0
        finally:
            r0.destroy()
            rate.destroy()
        change = model.max_gradient(d1)
        tangent = -d1.array_r.copy()                       # du/ds
        accel = self._acceleration(x, x.array_r.copy(), tangent, r_at_x=None) if self.geodesic else None
        if change * ds > MAX_PREDICTED_GRADIENT:
            ds = MAX_PREDICTED_GRADIENT / change
        if accel is not None:                              # the second-order term at most half the first
            ratio = np.sqrt(model.comm.allreduce(accel @ accel) / max(model.comm.allreduce(tangent @ tangent),
                                                                      1e-300))
            if ratio * ds > 1.0:
                ds = 1.0 / ratio
        t = min(s + ds, 1.0)
        p = (t - s) * tangent - d0.array_r
        for v in (d0, d1):
            v.destroy()
        path(t)
        return t, self._line_step(p, None if accel is None else (t - s) ** 2 * accel)

    def _dirichlet_rows(self, r0, rate, s, path) -> None:
        """Dirichlet rows of the two right-hand sides: x - g(s) and -dg/ds (the pins' own motion)."""
        model = self.model
        x = model.u.vector
        g = x.duplicate()
        path(s + PATH_EPS)
        model.apply_bcs(g)                   # g(s + eps) on pinned rows (0 elsewhere)
        g1 = g.array_r.copy()
        g.set(0.0)
        path(s)
        model.apply_bcs(g)                   # g(s)
        fixed = model.fixed[:len(g1)]
        r0.array_w[fixed] = x.array_r[fixed] - g.array_r[fixed]
        rate.array_w[fixed] = -(g1[fixed] - g.array_r[fixed]) / PATH_EPS
        g.destroy()

    def _line_step(self, p: np.ndarray, accel: np.ndarray | None = None) -> float:
        """Move the state along x + alpha p (+ alpha^2 accel / 2) as far as the energy line search
        allows; returns alpha (0 if none)."""
        model = self.model
        x = model.u.vector.copy()
        try:
            model.gradient(x, self.b)
            r = self.b.array_r
            slope = float(model.comm.allreduce(r @ p))
            if not np.isfinite(slope) or slope >= 0.0:
                return 0.0
            x0 = x.array_r.copy()
            f0 = float(np.sqrt(model.comm.allreduce(r @ r)))
            alpha, ok = self._backtrack(x, x0, p, model.energy(x), slope, f0, self._max_step(x0, p), accel=accel)
            if not ok:
                return 0.0
            step = alpha * p + (0.5 * alpha ** 2 * accel if accel is not None else 0.0)
            x.array_w[:] = x0 + step + model.step_correction(x0, step / alpha, alpha)
            x.copy(model.u.vector)
            return float(alpha)
        finally:
            model.sync(model.u.vector)
            x.destroy()

    def _force_scale(self, path) -> float:
        """|R| at the current state with the loads at the path's end: the scale rtol refers to."""
        model, x = self.model, self.model.u.vector
        path(1.0)
        model.residual(x, self.b)
        scale = self.b.norm()
        return float(scale) if np.isfinite(scale) else 0.0

    def _follow(self, path, steps: int, report: SolveReport) -> bool:
        """Continuation from s = 0 (the current equilibrium) to s = 1 along path(s).

        Each step: an Euler predictor (see _predict), then Newton to the step
        tolerance (STEP_RTOL: the path is only followed, not resolved) or, at
        s = 1, to the full tolerance. A step that converged in few iterations
        lets the next one double (up to 1 / steps); one that failed is
        retried from the last equilibrium at half the size, up to max_cuts
        times. Every Newton iteration of every attempt is counted, and so is
        every factorisation made only for a predictor.
        """
        model = self.model
        s, ds_max = 0.0, 1.0 / max(int(steps), 1)
        ds, cuts = ds_max, 0
        saved = model.u.vector.copy()
        try:
            while s < 1.0 - 1e-12:
                if not self._factorised:
                    path(s)
                    self.jacobian(model.u.vector)
                    self._factorised = True
                    report.newton_iterations += 1
                    report.attempts.append({"factor": float(s), "iterations": 1, "status": "factorised"})
                t, alpha = self._predict(path, s, ds)
                final = t >= 1.0 - 1e-12
                ok, status, its = self._newton(None if final else max(STEP_RTOL, self.rtol))
                report.newton_iterations += its
                report.attempts.append({"factor": float(t), "iterations": int(its), "status": status,
                                        "predictor_step": alpha})
                if ok:
                    report.load_steps += 1
                    report.residual_history.append(self._history)
                    log.info("step %d: s = %.4g, predictor %.3g, %d Newton iterations, |R| %.2e -> %.2e",
                             report.load_steps, t, alpha, its,
                             self._history[0] if self._history else 0.0,
                             self._history[-1] if self._history else 0.0)
                    model.end_step()
                    model.u.vector.copy(saved)
                    s, ds = t, (min(2.0 * (t - s), ds_max) if its <= 4 else t - s)
                    continue
                log.info("step to s = %.4g failed (%s)", t, status)
                saved.copy(model.u.vector)
                path(s)
                model.sync(model.u.vector)
                self._factorised = False
                cuts += 1
                if cuts > self.max_cuts:
                    report.status = status
                    report.residual_history.append(self._history)
                    return False
                ds = (t - s) / 2.0
            return True
        finally:
            saved.destroy()

    def solve(self, steps: int = 1, start: float = 0.0, end: float = 1.0) -> SolveReport:
        """Follow the load factor from start to end (steps: the largest step is (end - start) / steps)."""
        t0 = time.perf_counter()
        model = self.model
        model.changes.clear()
        report = SolveReport(False, "not_started")

        def path(s):
            model.set_factor(start + s * (end - start))
        self.reference_residual = max(self.reference_residual, self._force_scale(path))
        path(0.0)
        if self._follow(path, steps, report):
            report.converged, report.status = True, "converged"
        return self._finish(report, t0)

    def _finish(self, report: SolveReport, t0: float) -> SolveReport:
        model = self.model
        report.energy = model.energy(model.u.vector)
        report.min_jacobian = model.min_jacobian(model.u.vector)
        report.time = time.perf_counter() - t0
        return report

    def resolve(self, steps: int = 1) -> SolveReport:
        """Warm re-solve from the last equilibrium: follow the changed parameters (model.changes).

        One Euler predictor and Newton at full tolerance when the change is
        small, more steps when the predicted change is large. If that fails,
        the state is restored and the load is ramped from the rest state in
        `steps` steps, as a cold solve would; the report counts the
        iterations of both.
        """
        t0 = time.perf_counter()
        model = self.model
        saved = model.u.vector.copy()
        model.set_factor(1.0)
        report = SolveReport(False, "not_started")
        if any(not np.array_equal(o, n) for o, n in model.changes.values()):
            ok = self._follow(model.parameter_path, 1, report)
        else:
            ok, status, its = self._newton()
            report.newton_iterations, report.load_steps = its, int(ok)
            report.residual_history = [self._history] if ok else []
            report.attempts.append({"factor": 1.0, "iterations": int(its), "status": status})
            report.status = status
            if ok:
                model.end_step()
        model.changes.clear()
        for attempt in report.attempts:
            attempt["warm"] = True
        if ok:
            report.converged, report.status = True, "converged"
            saved.destroy()
            return self._finish(report, t0)
        log.info("warm re-solve failed (%s); ramping from rest", report.status)
        self._factorised = False
        model.u.vector.set(0.0)
        model.sync(model.u.vector)
        cold = self.solve(steps)
        saved.destroy()
        cold.newton_iterations += report.newton_iterations
        cold.attempts = report.attempts + cold.attempts
        cold.time = time.perf_counter() - t0
        return cold
