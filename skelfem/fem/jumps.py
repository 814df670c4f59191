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
"""
from __future__ import annotations

import numpy as np

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
    ``events``: kind, piece, load_factor, step, rotation in rad, displacement in mm)."""

    def __init__(self, model, share: float = JUMP_SHARE):
        self.share = share
        self.objects = list(model.terms_in("objects"))
        self.poses = {obj.name: self._pose(obj, model) for obj in self.objects}
        self.step = 0
        self.events: list = []

    @staticmethod
    def _pose(obj, model) -> tuple:
        r = obj.readout(model)[obj.name]
        return np.asarray(r["position"], float), r["rotation"]

    def __call__(self, model) -> None:
        self.step += 1
        for obj in self.objects:
            c1, r1 = self._pose(obj, model)
            c0, r0 = self.poses[obj.name]
            moved, turned = float(np.linalg.norm(c1 - c0)), turn(r0, r1)
            if moved + abs(turned) * obj.size / 2 > self.share * obj.size:
                self.events.append({"kind": "jump", "piece": obj.name, "load_factor": float(model.factor),
                                    "step": self.step, "rotation": turned, "displacement": moved})
            self.poses[obj.name] = (c1, r1)


def describe(events: list) -> str:
    """One line for the summary: which pieces jumped, where and by how much."""
    parts = [f"{e['piece']} moved {e['displacement']:.3g} mm and turned {np.degrees(e['rotation']):.3g} deg "
             f"in load step {e['step']} (factor {e['load_factor']:.3g})" + (f", stage {e['stage']}"
                                                                           if "stage" in e else "")
             for e in events]
    return "; ".join(parts)
