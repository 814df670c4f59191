"""Jumps: a free object that moves or turns by more than a share of its size within one load step.

A static solve finds an equilibrium at every load step; where the path
between two of them is not continuous (a box that topples, a grasp that
snaps), Newton may still converge, to a state far from the last one, and
the result would look like any other. A :class:`JumpWatch` is told of every
accepted load step (``Model.step_watchers``) and compares each object's pose
(``objects.NAME`` read-out: centroid and rotation) with the last step's: the
reach of the change, |d centroid| + |d angle| x size / 2 (the farthest a
point of the object moved, to first order), above ``JUMP_SHARE`` x size
(the diagonal of its box) is a jump. Such an answer is one equilibrium of
many, reached by a path the statics does not follow: a run in time
([dynamics]) says where the object goes.

The change is measured against what carries the object: the rigid motion
closest to that of its *carriers*, the nodes of other pieces within
``dhat`` plus one mesh size of its nodes at the step's start (Kabsch: a hand
that lifts or turns a held box moves it by as much, which is no jump). An
object nothing touches (falling onto a ground, sliding on one) is measured
against its own last pose.
"""
from __future__ import annotations

import numpy as np
from mpi4py import MPI
from scipy.spatial import cKDTree

from ..terms.rigid import closest_rigid_motion, rotation_readout

JUMP_SHARE = 0.25     # an object's pose may change by this share of its size in one load step


def turn(r0, r1) -> float:
    """The angle (rad) between two rotation read-outs: 2D angles (signed, wrapped to [-pi, pi]) or 3D
    rotation vectors (the magnitude of the relative rotation)."""
    if np.ndim(r0) == 0:
        return float((float(r1) - float(r0) + np.pi) % (2 * np.pi) - np.pi)
    from scipy.spatial.transform import Rotation
    R0, R1 = Rotation.from_rotvec(np.asarray(r0, float)), Rotation.from_rotvec(np.asarray(r1, float))
    return float((R1 * R0.inv()).magnitude())


class JumpWatch:
    """Registered in model.step_watchers for one solve; ``events`` lists the jumps seen (result.json's
    ``events``: kind, piece, load_factor, step, rotation in rad, displacement in mm, each relative to the
    object's carriers, and ``carried``: whether it had any)."""

    def __init__(self, model, share: float = JUMP_SHARE):
        self.share = share
        self.objects = list(model.terms_in("objects"))
        self.step = 0
        self.events: list = []
        if not self.objects:
            return
        self.comm, self.bs = model.V.mesh.comm, model.bs
        n = model.n_owned // model.bs
        self.X = model.V.tabulate_dof_coordinates()[:n, :model.dim]      # owned nodes, reference positions
        self.reach = float(model.design.contact.dhat) + float(model.design.mesh.size)
        self.start = {obj.name: self._state(obj, model) for obj in self.objects}

    def _positions(self, model) -> np.ndarray:
        return self.X + model.u.x.array[:self.X.size].reshape(self.X.shape)

    def _state(self, obj, model) -> tuple:
        """(centroid, rotation matrix, carrier nodes, their positions) of obj in the current state."""
        u = model.u.x.array
        t, R = obj.body.fit(u)
        y = self._positions(model)
        own = obj.dofs[:, 0] // self.bs
        mine = np.zeros(len(y), dtype=bool)
        mine[own] = True
        others = np.flatnonzero(~mine)
        near = np.zeros(0, dtype=np.int64)
        if len(own) and len(others):
            d, _ = cKDTree(y[own]).query(y[others], distance_upper_bound=self.reach)
            near = others[np.isfinite(d)]
        return obj.centroid(u, t, R), R, near, y[near]

    def _carried(self, near: np.ndarray, y0: np.ndarray, model):
        """The rigid motion (c_X, c_y, R) closest to the carriers' over the step, or None without any."""
        if self.comm.allreduce(len(near), op=MPI.SUM) == 0:
            return None
        total = (lambda a: a) if self.comm.size == 1 else (lambda a: self.comm.allreduce(a, op=MPI.SUM))
        return closest_rigid_motion(y0, self._positions(model)[near], total)

    def __call__(self, model) -> None:
        self.step += 1
        for obj in self.objects:
            c0, R0, near, y0 = self.start[obj.name]
            state = self._state(obj, model)
            c1, R1 = state[0], state[1]
            carried = self._carried(near, y0, model)
            if carried is not None:            # where the carriers' rigid motion takes the object
                cx, cy, Rc = carried
                c0, R0 = cy + Rc @ (c0 - cx), Rc @ R0
            moved = float(np.linalg.norm(c1 - c0))
            turned = turn(rotation_readout(R0), rotation_readout(R1))
            if moved + abs(turned) * obj.size / 2 > self.share * obj.size:
                self.events.append({"kind": "jump", "piece": obj.name, "load_factor": float(model.factor),
                                    "step": self.step, "rotation": turned, "displacement": moved,
                                    "carried": carried is not None})
            self.start[obj.name] = state


def describe(events: list) -> str:
    """One line for the summary: which pieces jumped, where and by how much."""
    parts = [f"{e['piece']} moved {e['displacement']:.3g} mm and turned {np.degrees(e['rotation']):.3g} deg "
             f"in load step {e['step']} (factor {e['load_factor']:.3g})" + (f", stage {e['stage']}"
                                                                           if "stage" in e else "")
             for e in events]
    return "; ".join(parts)
