"""Static equilibrium: PETSc SNES Newton on grad Pi = 0, with load stepping.

Newton's direction p solves H p = -grad Pi (MUMPS LDL^T, the matrix pattern
fixed so the symbolic factorisation is reused). The default line search
("energy") runs in SNES's pre-check: it starts from the scene's admissible
step alpha_max = scene.max_step(x, p) <= 1 (e.g. the collision-free step of
self-contact) and backtracks until the trial state is admissible (det F > 0
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
from petsc4py import PETSc

from .design import LINE_SEARCHES as STRATEGIES

log = logging.getLogger("skelfem")


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
    energy: float = float("nan")
    min_jacobian: float = float("nan")
    time: float = 0.0


def default_petsc_options() -> dict:
    """A fresh dict of PETSc options for the Newton linear solves.

    Every Jacobian here is symmetric (UFL Hessian, cable and contact blocks,
    Dirichlet rows and columns replaced symmetrically), so MUMPS's LDL^T
    (PETSc "cholesky", indefinite-safe) replaces LU: about 20 % less per
    factorisation with the same iterates.
    """
    return {"ksp_type": "preonly", "pc_type": "cholesky",
            "pc_factor_mat_solver_type": "mumps"}


class NewtonSolver:
    """SNES Newton for one Scene; reusable across solves (warm starts)."""

    def __init__(self, scene, spec=None, petsc_options: dict | None = None, prefix: str = "skelfem_"):
        self.scene = scene
        self.strategy = getattr(spec, "line_search", "energy") if spec else "energy"
        if self.strategy not in STRATEGIES:
            raise ValueError(f"unknown line search {self.strategy!r}")
        if self.strategy != "energy" and scene.bounds_steps:
            raise ValueError(f"line search {self.strategy!r} cannot limit steps to the scene's "
                             "admissible ones; use 'energy'")
        self.max_iterations = getattr(spec, "max_iterations", 50) if spec else 50
        self.rtol = getattr(spec, "rtol", 1e-9) if spec else 1e-9
        self.atol = getattr(spec, "atol", 1e-10) if spec else 1e-10
        self.xtol = 1e-11             # relative size of a full Newton step that ends the solve
        self.max_cuts = 8
        self._newton_step = np.inf    # |p| of the last undamped Newton step
        self.etol = 1e-15             # Newton decrement -grad Pi . p relative to |Pi| that ends the solve
        self._decrement_converged = False
        self.A = scene.create_matrix()
        self.b = scene.u.vector.duplicate()
        self.x = scene.u.vector.copy()      # SNES iterate; scene.u is scratch for evaluations
        self._history: list[float] = []
        self._failure: str | None = None
        self._f0 = 0.0
        self.snes = self._create_snes(prefix, {**default_petsc_options(), **(petsc_options or {})})

    # -- SNES set-up -------------------------------------------------------------------
    def _create_snes(self, prefix: str, options: dict) -> PETSc.SNES:
        snes = PETSc.SNES().create(self.scene.comm)
        snes.setOptionsPrefix(prefix)
        snes.setFunction(lambda s, x, b: self.scene.residual(x, b), self.b)
        snes.setJacobian(lambda s, x, A, P: self.scene.jacobian(x, A), self.A)
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
        snes.getKSP().setFromOptions()
        snes.getKSP().getPC().setFromOptions()
        for key in options:
            del opts[f"{prefix}{key}"]
        return snes

    @property
    def ksp(self) -> PETSc.KSP:
        """The linear solver, holding the factorised Jacobian of the last iteration."""
        return self.snes.getKSP()

    def _converged(self, snes, it, norms):
        """|R| <= max(atol, rtol |R_0|), or a full Newton step below xtol * size."""
        xnorm, ynorm, fnorm = norms
        self._history.append(float(fnorm))
        if it == 0:
            self._f0 = fnorm
        log.debug("  newton %2d  |R| = %.3e  |dx| = %.3e", it, fnorm, ynorm)
        if not np.isfinite(fnorm):
            return PETSc.SNES.ConvergedReason.DIVERGED_FNORM_NAN
        if fnorm <= max(self.atol, self.rtol * self._f0):
            return PETSc.SNES.ConvergedReason.CONVERGED_FNORM_ABS
        if self._decrement_converged:
            return PETSc.SNES.ConvergedReason.CONVERGED_FNORM_RELATIVE
        step = self._newton_step if self.strategy == "energy" else ynorm
        if it > 0 and step <= self.xtol * max(xnorm, self.scene.size):
            return PETSc.SNES.ConvergedReason.CONVERGED_SNORM_RELATIVE
        if self._failure is not None:
            return PETSc.SNES.ConvergedReason.DIVERGED_LINE_SEARCH
        if it >= self.max_iterations:
            return PETSc.SNES.ConvergedReason.DIVERGED_MAX_IT
        return PETSc.SNES.ConvergedReason.ITERATING

    def _energy_line_search(self, x, y):
        """SNES pre-check: scale the step -y so that x - y is admissible and lowers Pi."""
        scene = self.scene
        p = -y.array_r.copy()                       # Newton direction (SNES steps x - y)
        r = self.b.array_r.copy()                   # grad Pi at x, set by SNES
        x0 = x.array_r.copy()
        slope = float(scene.comm.allreduce(r @ p))
        e0 = scene.energy(x)
        self._newton_step = float(np.sqrt(scene.comm.allreduce(p @ p)))
        if 0.0 <= -slope <= self.etol * max(abs(e0), 1e-300):
            # Newton decrement at round-off level: x is the minimiser to machine precision
            self._decrement_converged = True
            return self._take(x, y, p, self._max_step(x0, p)) or True
        if slope > 0.0:                             # not a descent direction: turn around
            p, slope = -p, -slope
        f0 = float(np.sqrt(scene.comm.allreduce(r @ r)))
        alpha, accepted = self._backtrack(x, x0, p, e0, slope, f0, self._max_step(x0, p))
        scene._sync(x)
        if not accepted:
            self._failure = "line_search_failed"
            y.set(0.0)
        else:
            y.array_w[:] = -(alpha * p + scene.rigid_correction(x0, p, alpha))
        log.debug("  line search: alpha %.3g, decrement %.3e, energy %.9e", alpha if accepted else 0.0,
                  -slope, e0)
        return True

    def _max_step(self, x0: np.ndarray, p: np.ndarray) -> float:
        """The scene's admissible step along p, agreed over ranks."""
        from mpi4py import MPI
        return float(self.scene.comm.allreduce(self.scene.max_step(x0, p), op=MPI.MIN))

    def _backtrack(self, x, x0, p, e0, slope, f0, alpha0=1.0, c1=1e-4):
        """Armijo backtracking with quadratic interpolation on phi(a) = Pi(x + a p), a <= alpha0.

        A trial state that is not admissible has phi = +inf. Within round-off
        of e0 a step is accepted if it lowers |grad Pi|. Bones move along the
        exact rotation whose linearisation is p (see Scene.rigid_correction),
        so a stiff bone's rotation does not turn into stretch.
        """
        scene = self.scene
        trial = x.duplicate()

        def phi(a):
            trial.array_w[:] = x0 + a * p + scene.rigid_correction(x0, p, a)
            return scene.energy(trial) if scene.admissible(trial) else np.inf

        noise = max(scene.energy_noise, 1e-12 * abs(e0))
        if alpha0 <= 0.0:
            trial.destroy()
            return 0.0, False
        alpha, e = alpha0, phi(alpha0)
        try:
            for _ in range(40):
                if e <= e0 + c1 * alpha * slope:
                    return alpha, True
                if np.isfinite(e) and abs(e - e0) <= noise:
                    trial.array_w[:] = x0 + alpha * p
                    scene.residual(trial, self.b)
                    better = self.b.norm() < f0
                    scene.residual(x, self.b)
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

    def _take(self, x, y, p, alpha) -> bool:
        """Set the SNES step to alpha p if x + alpha p is admissible (and alpha > 0), else to zero."""
        trial = x.copy()
        trial.array_w[:] += alpha * p
        ok = alpha > 0.0 and self.scene.admissible(trial)
        trial.destroy()
        self.scene._sync(x)
        if ok:
            y.array_w[:] = -alpha * p
        else:
            y.set(0.0)
        return ok

    # -- solves ---------------------------------------------------------------------------
    def _newton(self) -> tuple[bool, str, int]:
        """Newton from the current state at the current load factor."""
        self._history, self._failure, self._newton_step = [], None, np.inf
        self._decrement_converged = False
        self.scene.u.vector.copy(self.x)
        self.scene.apply_bcs(self.x)
        if not self.scene.admissible(self.x):
            return False, "inverted_elements", 0
        self.snes.solve(None, self.x)
        self.scene._sync(self.x)
        reason = self.snes.getConvergedReason()
        its = self.snes.getIterationNumber()
        if reason > 0:
            if not self.scene.admissible(self.x):
                return False, "inverted_elements", its
            return True, "converged", its
        log.debug("SNES reason %s", reason)
        return False, self._failure or _REASONS.get(reason, f"diverged ({reason})"), its

    def _predict(self, prev, a_prev: float, a: float, target: float) -> None:
        """Secant predictor: extrapolate the last increment to the new load factor."""
        if prev is None or a <= a_prev:
            return
        scene = self.scene
        u = scene.u.vector
        guess = u.copy()
        guess.axpy((target - a) / (a - a_prev), u - prev)
        scene.set_factor(target)
        current = u.copy()
        scene.apply_bcs(current)
        scene.apply_bcs(guess)
        reachable = self._max_step(u.array_r, guess.array_r - u.array_r) >= 1.0
        if reachable and scene.admissible(guess) and (not scene.admissible(current)
                                                      or scene.energy(guess) < scene.energy(current)):
            guess.copy(u)
        for v in (guess, current):
            v.destroy()
        scene.set_factor(a)
        scene._sync(u)

    def solve(self, steps: int = 1, start: float = 0.0, end: float = 1.0) -> SolveReport:
        """Ramp the load factor from start to end in `steps` steps (cut in half on failure)."""
        t0 = time.perf_counter()
        scene = self.scene
        report = SolveReport(False, "not_started")
        a, da, cuts = start, (end - start) / max(int(steps), 1), 0
        da0 = da
        saved = scene.u.vector.copy()
        prev, a_prev = None, a
        while a < end - 1e-12:
            target = min(a + da, end)
            self._predict(prev, a_prev, a, target)
            scene.set_factor(target)
            ok, status, its = self._newton()
            report.newton_iterations += its
            if ok:
                report.load_steps += 1
                report.residual_history.append(self._history)
                log.info("load step %d: factor %.4g, %d Newton iterations, |R| %.2e -> %.2e",
                         report.load_steps, target, its,
                         self._history[0] if self._history else 0.0,
                         self._history[-1] if self._history else 0.0)
                prev = prev or saved.duplicate()
                saved.copy(prev)
                a_prev, a = a, target
                if its <= 8:
                    da = min(2.0 * da, da0)
                scene.u.vector.copy(saved)
                continue
            log.info("load step to factor %.4g failed (%s)", target, status)
            saved.copy(scene.u.vector)
            scene.set_factor(a)
            scene._sync(scene.u.vector)
            cuts += 1
            if cuts > self.max_cuts:
                report.status = status
                report.residual_history.append(self._history)
                break
            da = (target - a) / 2.0
        else:
            report.converged, report.status = True, "converged"
        for v in (saved, prev):
            if v is not None:
                v.destroy()
        report.energy = scene.energy(scene.u.vector)
        report.min_jacobian = scene.min_jacobian(scene.u.vector)
        report.time = time.perf_counter() - t0
        return report
