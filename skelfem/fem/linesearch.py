"""Newton's line searches on Pi: the energy (Armijo, admissible steps) and curved (geodesic acceleration) strategies.

``EnergyLineSearch`` is an object the Newton solver holds (skelfem.fem.newton), with a small interface:
it is given the model (the energy at a trial point, admissibility, the step bound
``Model.max_step`` and the bones' step correction), the vector SNES writes grad Pi into, and a
back-substitution with the current Newton matrix (the curved step's acceleration); it owns the
watchdog's state and the last accepted trial, and reports to Newton what it found
(``newton_step``, ``decrement_converged``, ``failure``). Nothing else is shared.
"""
from __future__ import annotations

import logging
from typing import Any, Callable

import numpy as np
from mpi4py import MPI

log = logging.getLogger("skelfem")


C1 = 1e-4          # Armijo constant
MAX_ROTATION = 0.5  # rad: a curved step turns the body at most this much (max |grad p|); a straight step
#                     stretches a turning strip by about MAX_ROTATION^2 / 2 (12 % here, 50 % at 1 rad, where
#                     Newton's next step could not bring a coiling strip back, see docs/model.md)
WATCHDOG = 5       # stalled steps of the curved strategy after which, if Pi is still above the reference
#                    (the state before its first relaxed, energy-raising, full step), Newton goes back to it:
#                    relaxed steps, and steps that close less than WATCHDOG_CLOSE of the gap to it
WATCHDOG_CLOSE = 0.1   # (docs/model.md: counting only relaxed steps, a block sunk into a floor by one crawled
#                        450 iterations; counting every step, a finger pushed into a stiff wall by one, on its
#                        way back in 14, was sent back and crawled monotone)
ETOL = 1e-15       # Newton decrement -grad Pi . p relative to |Pi| that ends the solve


class EnergyLineSearch:
    """The energy line search of a Newton solve: SNES's pre-check (``precheck``) scales each Newton step
    so that the trial state is admissible (``Model.max_step``) and lowers the total energy (Armijo
    backtracking, with a watchdog that lets a few full steps raise it), optionally along a curve.

    model: the energy at a trial state, its admissibility, the step bound and step correction;
    gradient: the vector SNES holds grad Pi at its iterate in (also the backtracking's scratch);
    solve(b, x): x = H^{-1} b with the current Newton matrix (the curved strategy's acceleration).
    After each ``precheck``, ``newton_step`` is |p| of the undamped Newton step,
    ``decrement_converged`` whether the Newton decrement reached round-off and ``failure`` why no step
    was found (None: a step was set)."""

    def __init__(self, model, gradient, solve: Callable[[Any, Any], None], curved: bool = False):
        self.model, self.gradient, self.solve = model, gradient, solve
        self.curved = curved
        self.watchdog = WATCHDOG if curved else 0   # full steps that may raise Pi before it must be below
        #                                             the reference
        self.etol = ETOL
        self.reset()

    def reset(self) -> None:
        """A new Newton solve (or a changed model): no watchdog reference, no trial to reuse, no outcome."""
        self.newton_step = np.inf               # |p| of the last undamped Newton step
        self.decrement_converged = False
        self.failure: str | None = None
        self._last_trial: tuple | None = None   # (state, Pi) of the last accepted trial
        self._watch: dict | None = None         # the watchdog's reference (state, energy, step) while relaxed
        self._watch_allowed = True

    def precheck(self, x, y) -> bool:
        """SNES pre-check: scale the step -y so that x - y is admissible and lowers Pi
        (or, with the watchdog, take the full step and check the energy a few iterations later)."""
        model = self.model
        p = -y.array_r.copy()                       # Newton direction (SNES steps x - y)
        r = self.gradient.array_r.copy()            # grad Pi at x, set by SNES
        x0 = x.array_r.copy()
        slope = float(model.comm.allreduce(r @ p))
        e0 = self._energy_at(x)
        self.newton_step = float(np.sqrt(model.comm.allreduce(p @ p)))
        if 0.0 <= -slope <= self.etol * max(abs(e0), 1e-300):
            # Newton decrement at round-off level: x is the minimiser to machine precision
            self.decrement_converged = True
            return self._take(x, y, p, self._max_step(x0, p)) or True
        if slope > 0.0:                             # not a descent direction: turn around
            p, slope = -p, -slope
        f0 = float(np.sqrt(model.comm.allreduce(r @ r)))
        wd = self._watch
        if wd is not None:
            if e0 <= wd["e0"] + C1 * wd["alpha0"] * wd["slope"]:
                self._watch = wd = None             # the relaxed steps paid off: back to monotone
                log.debug("  watchdog: energy %.9e below the reference", e0)
            elif self._watch_expired(wd, e0):
                self._watch, self._watch_allowed = None, False
                log.debug("  watchdog: energy %.9e still above the reference %.9e: back to it", e0, wd["e0"])
                return self._fall_back(x, y, wd)
        alpha0 = self._max_step(x0, p)
        if self.curved and MAX_ROTATION > 0.0:
            g = self._max_gradient(x, p)
            if g * alpha0 > MAX_ROTATION:
                alpha0 = MAX_ROTATION / g
        accel = self._choose_curve(x, x0, p, r, e0, slope, alpha0) if self.curved else None
        if wd is not None or (self.watchdog and self._watch_allowed and not model.bounds_steps):
            e_full = self._phi(x, x0, p, accel, alpha0) if alpha0 > 0.0 else np.inf
            if np.isfinite(e_full) and not e_full <= e0 + C1 * alpha0 * slope:
                # the full step is admissible but raises Pi: take it anyway (watchdog)
                if wd is None:
                    self._watch = wd = {"x0": x0, "e0": e0, "p": p, "slope": slope, "f0": f0,
                                        "alpha0": alpha0, "accel": accel, "n": 0, "last": 0.0}
                wd["n"] += 1                        # stalled; at the next check again, as it opened the gap
                self._set_step(y, x0, p, accel, alpha0)
                self._last_trial = None
                log.debug("  watchdog: full step (%d stalled), energy %.9e -> %.9e", wd["n"], e0, e_full)
                return True
            if not np.isfinite(e_full) and wd is not None:
                self._watch, self._watch_allowed = None, False
                return self._fall_back(x, y, wd)
        alpha, accepted = self.backtrack(x, x0, p, e0, slope, f0, alpha0, accel=accel)
        model.sync(x)
        if not accepted:
            self.failure = "line_search_failed"
            y.set(0.0)
        else:
            self._set_step(y, x0, p, accel, alpha)
        log.debug("  line search: alpha %.3g, decrement %.3e, energy %.9e", alpha if accepted else 0.0,
                  -slope, e0)
        return True

    def _watch_expired(self, wd: dict, e0: float) -> bool:
        """Whether the watchdog gives up on its relaxed steps at Pi = e0 (above the reference): after
        WATCHDOG stalled steps. Every relaxed step is one when taken, and every step, relaxed or monotone,
        that closed less than WATCHDOG_CLOSE of the gap between Pi and the reference's is one (judged here,
        at the next step: a relaxed step, which opens the gap, counts twice). Newton heading back into its
        basin closes most of the gap at every step; a search that crawls does not."""
        gap, last = e0 - wd["e0"], wd["last"]
        wd["last"] = gap
        if gap > (1.0 - WATCHDOG_CLOSE) * last:
            wd["n"] += 1
        return wd["n"] >= self.watchdog

    def _set_step(self, y, x0, p, accel, alpha) -> None:
        """y such that x0 - y is the trial state of step alpha (SNES steps x - y)."""
        y.array_w[:] = -self._step(x0, p, accel, alpha)

    def _fall_back(self, x, y, wd) -> bool:
        """Back to the watchdog's reference state and Armijo backtracking along its Newton step."""
        model = self.model
        ref = x.duplicate()
        try:
            ref.array_w[:] = wd["x0"]
            alpha, accepted = self.backtrack(ref, wd["x0"], wd["p"], wd["e0"], wd["slope"], wd["f0"],
                                              wd["alpha0"], accel=wd["accel"])
        finally:
            ref.destroy()
            model.sync(x)
        if not accepted:
            self.failure = "line_search_failed"
            y.set(0.0)
            return True
        y.array_w[:] = x.array_r - self._trial(wd["x0"], wd["p"], wd["accel"], alpha)
        log.debug("  watchdog fall-back: alpha %.3g from the reference", alpha)
        return True

    def _max_gradient(self, x, p) -> float:
        vec = x.duplicate()
        try:
            vec.array_w[:] = p
            return self.model.max_gradient(vec)
        finally:
            vec.destroy()

    def _choose_curve(self, x, x0, p, r, e0, slope, alpha0):
        """The geodesic acceleration if the curved step is lower than the straight one at alpha0, else None."""
        model = self.model
        if alpha0 <= 0.0 or model.bounds_steps:
            return None
        e_line = self._phi(x, x0, p, None, alpha0)
        accel = self._acceleration(x, x0, p, r)
        e_curve = self._phi(x, x0, p, accel, alpha0)
        log.debug("  curve: |a|/|p| %.3g, Pi - Pi0 at alpha %.3g: line %.4e, curve %.4e",
                  float(np.sqrt(model.comm.allreduce(accel @ accel) / model.comm.allreduce(p @ p))),
                  alpha0, e_line - e0, e_curve - e0)
        return accel if e_curve < e_line else None

    def _max_step(self, x0: np.ndarray, p: np.ndarray) -> float:
        """The model's admissible step along p, agreed over ranks."""
        return self.model.max_step(x0, p)

    def _step(self, x0, p, accel, a) -> np.ndarray:
        """The step a p (+ a^2 accel / 2) from x0, bones moved along their exact rotation."""
        if accel is None:
            return a * p + self.model.step_correction(x0, p, a)
        direction = p + 0.5 * a * accel
        return a * direction + self.model.step_correction(x0, direction, a)

    def _trial(self, x0, p, accel, a) -> np.ndarray:
        """The trial state x0 + _step(...)."""
        return x0 + self._step(x0, p, accel, a)

    def _phi(self, x, x0, p, accel, a) -> float:
        """Pi at the trial state of step a (+inf if not admissible)."""
        model = self.model
        trial = x.duplicate()
        try:
            trial.array_w[:] = self._trial(x0, p, accel, a)
            return model.energy(trial) if model.admissible(trial) else np.inf
        finally:
            trial.destroy()
            model.sync(x)

    def _acceleration(self, x, x0, p, r) -> np.ndarray:
        """Geodesic acceleration a = -H^{-1} D^2R[p, p] of the Newton step (second-order curve).

        x(alpha) = x0 + alpha p + alpha^2 a / 2 follows the solution curve to
        second order. D^2R[p, p] by central differences of the residual over
        h p with h max|grad p| = 1e-2 (r: the residual at x0); one
        back-substitution on the current factorisation.
        """
        model = self.model
        vec, res = x.duplicate(), x.duplicate()
        try:
            vec.array_w[:] = p
            g = model.max_gradient(vec)
            h = 1e-2 / g if g > 0 else 1.0
            d2 = -2.0 * r
            for sign in (1.0, -1.0):
                vec.array_w[:] = x0 + sign * h * p
                model.residual(vec, res)
                d2 = d2 + res.array_r
            res.array_w[:] = d2 / h ** 2
            self.solve(res, vec)
            return -vec.array_r.copy()
        finally:
            vec.destroy()
            res.destroy()
            model.sync(x)

    def backtrack(self, x, x0, p, e0, slope, f0, alpha0=1.0, c1=C1, accel=None) -> tuple[float, bool]:
        """Armijo backtracking with quadratic interpolation on phi(a) = Pi(x + a p), a <= alpha0
        (along x + a p + a^2 accel / 2 if accel is given).

        A trial state that is not admissible has phi = +inf. Within round-off
        of e0 a step is accepted if it lowers |grad Pi|. Bones move along the
        exact rotation whose linearisation is p (see Elasticity.step_correction),
        so a stiff bone's rotation does not turn into stretch.
        """
        model = self.model
        trial = x.duplicate()

        def phi(a):
            trial.array_w[:] = self._trial(x0, p, accel, a)
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
                    model.residual(trial, self.gradient)
                    better = self.gradient.norm() < f0
                    model.residual(x, self.gradient)
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
        step = self._step(x.array_r, p, None, alpha) if alpha > 0.0 else 0.0 * p
        trial.array_w[:] += step
        ok = alpha > 0.0 and self.model.admissible(trial)
        trial.destroy()
        self.model.sync(x)
        if ok:
            y.array_w[:] = -step
        else:
            y.set(0.0)
        return ok


def resolve_strategy(design) -> str:
    """What line_search = "auto" means for a design: "curved" for bodies without bones, else "energy".

    The exact bone rotation (Elasticity.step_correction) keeps stiff bones
    robust under the monotone energy line search; a geodesic acceleration
    through a stiff bone is dominated by its stiffness and does not help, and
    relaxed steps cost bony designs iterations. Soft bodies without bones
    are the ones that crawl under the monotone search.
    """
    return "energy" if getattr(design, "bones", None) else "curved"
