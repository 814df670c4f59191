"""The frames of a 3D drag: Newton corrections with the linear solver the last solve left, no new one.

While a bone of a 3D design is dragged, each move keeps the mesh and moves its
nodes (skelfem.mesh.morph3d), and the state carries over. A Newton step would
then assemble and factorise the Newton matrix again (10k DOFs: ~0.35 s of a
frame; 36k: ~1.3 s). A frame here instead takes *modified* Newton steps:

    K_0 d = -R(u; X),   u <- u + alpha d,

with K_0 the matrix the linear solver already holds (MUMPS's factors, or the
multigrid hierarchy and its operator above 30k DOFs: reused, not rebuilt), R
the residual on the moved nodes, alpha from a backtracking search on the
energy (Armijo), until the frame's time is spent. K_0 is the Hessian at the
last equilibrium on the mesh as meshed: near the dragged state, so the steps
descend and converge linearly, never faster than Newton but each for the price
of a residual, a back-substitution and a few energies.

A step that takes longer than STEP_SECONDS (the last one's time, in proportion to the DOFs: finger3d at
49k DOFs, a back-substitution with MUMPS's factors 0.04-0.3 s with the load) is not started for a new pose:
that frame is the moved state itself (the nodes moved with the bones, the state carried over: a predictor,
zero steps), and the steps are taken when the same design is asked again (the hand at rest) and on release.
So is a new pose's frame whose modified steps cannot lower the residual: the Newton step that would follow
(finger3d at 10k DOFs: ~0.2 s, a factorisation) waits for the same design asked again.

The state of such a frame is a preview (status ``frame_budget``, never
"converged": moved nodes); letting go re-meshes and solves with Newton to the
batch tolerance as every release does. ``StaleFrames.usable`` says whether the
solver still holds what was factorised (the same solver and matrix objects as
at the last converged solve: a re-mesh makes a new solver, a grown matrix
pattern a new matrix, and either ends it).
"""
from __future__ import annotations

import time

import numpy as np

MAX_STEPS = 8          # modified Newton steps of one frame at most (the frame's time usually ends it first)
ARMIJO = 1e-4
MIN_ALPHA = 1.0 / 64
STEP_SECONDS = 0.15    # a step slower than this (the last one's time) is not started for a new pose


class Frame:
    """A frame's outcome, read as the engine reads a Session's Result (status, iterations, to_dict)."""

    converged = False
    status = "frame_budget"

    def __init__(self, session, steps: int, seconds: float, predictor: bool = False):
        self.newton_iterations = steps
        self.predictor = predictor            # no step taken: the moved state (see the module doc)
        kind = "the moved state (no step)" if predictor else "modified Newton (the held factorisation)"
        model = session.model
        cells = model.mesh.topology.index_map(model.mesh.topology.dim).size_global
        self._dict = {"format": 1, "design": session.design.name, "converged": False, "status": self.status,
                      "newton_iterations": steps, "dofs": int(session.dofs), "cells": int(cells),
                      "frame": {"kind": kind, "steps": steps, "seconds": round(seconds, 4)}}

    def to_dict(self) -> dict:
        return dict(self._dict)


class StaleFrames:
    """What the linear solver holds (see the module doc), and frames made with it."""

    def __init__(self):
        self._held: tuple | None = None       # (solver, matrix) of the last converged solve
        self.step_seconds = 0.0               # the last frame's time per step (0: not known yet) ...
        self.step_dofs = 1                    # ... on a mesh of this many DOFs

    def note(self, session, result) -> None:
        """After a solve: one that took Newton steps (or converged with a factorisation) leaves the
        factorisation of its last Newton matrix, near its state, to reuse; a frame of ours changes nothing."""
        solver = session.solver
        if isinstance(result, Frame) or solver is None:
            return
        if result.newton_iterations > 0 or (result.converged and solver.factorised):
            self._held = (solver, solver.A)

    def usable(self, session) -> bool:
        held, solver = self._held, session.solver
        return held is not None and held[0] is solver and held[1] is solver.A

    def frame(self, session, deadline: float, new: bool = True) -> Frame | None:
        """Modified Newton steps from the session's state until `deadline` (time.monotonic); None if the
        held factorisation cannot be used (the caller takes Newton's way). new: a new pose (not the same
        design asked again): no step if the last took longer than STEP_SECONDS, and none where the held
        factorisation's cannot lower the residual: the moved state, 0 steps (Newton's step, which factorises
        again, waits for the same design asked again)."""
        if not self.usable(session) or session.model.path_dependent:
            return None
        t0 = time.perf_counter()
        if new and self.step_estimate(session) > STEP_SECONDS:
            return Frame(session, 0, 0.0, predictor=True)
        try:
            steps = stale_steps(session.solver, deadline)
        except np.linalg.LinAlgError:
            self._held = None
            return None
        seconds = time.perf_counter() - t0
        if steps:
            self.step_seconds, self.step_dofs = seconds / steps, max(1, int(session.dofs))
        return Frame(session, steps, seconds, predictor=new and not steps)

    def step_estimate(self, session) -> float:
        """A step's time on the session's mesh: the last one's, in proportion to the DOFs (a release's new
        mesh has about as many as the one dragged before; a mesh of another size is corrected by its first
        step)."""
        return self.step_seconds * int(session.dofs) / self.step_dofs


def stale_steps(solver, deadline: float, max_steps: int = MAX_STEPS) -> int:
    """Modified Newton steps on solver's model with its held linear solver; returns the steps taken.

    A step is taken with the largest alpha in 1, 1/2, ... 1/64 that lowers the energy (Armijo) and the
    residual's norm both: the held matrix is not the Hessian here, and the energy alone let a step that
    lowered it raise |R| thirty-fold (finger3d, after a first step that took |R| from 5.8 to 0.06)."""
    model, lin = solver.model, solver.lin
    x = model.u.vector.copy()
    r, d = x.duplicate(), x.duplicate()
    steps = 0
    try:
        model.apply_bcs(x)
        model.residual(x, r)
        norm = r.norm()
        for _ in range(max_steps):
            lin.solve(r, d)
            p = -d.array_r.copy()
            model.gradient(x, d)
            slope = float(model.comm.allreduce(d.array_r @ p))
            if not np.isfinite(slope) or slope >= 0.0:
                break
            x0, e0 = x.array_r.copy(), model.energy(x)
            alpha = min(1.0, model.max_step(x0, p))
            while alpha >= MIN_ALPHA:
                x.array_w[:] = x0 + alpha * p + model.step_correction(x0, p, alpha)
                if model.energy(x) <= e0 + ARMIJO * alpha * slope and model.admissible(x):
                    model.residual(x, r)
                    if r.norm() < norm:
                        break
                alpha *= 0.5
            if alpha < MIN_ALPHA:
                x.array_w[:] = x0
                break
            norm = r.norm()
            steps += 1
            if time.monotonic() >= deadline:
                break
        model.sync(x)
        return steps
    finally:
        for v in (x, r, d):
            v.destroy()
