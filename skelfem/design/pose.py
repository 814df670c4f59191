"""A 3D bone's pose: its solids moved and turned as one rigid piece (the editor's bone handles write it).

A ``[[bones]]`` entry of a ``dim = 3`` design may carry

    move = [dx, dy, dz]                                       # mm
    rotate = { angle = 12.0, axis = [0, 0, 1], centre = [10, 23, 10] }   # degrees, about the centre

and its solids are then placed at ``x = centre + move + R (X - centre)``,
R the turn by ``angle`` about ``axis`` (right-handed), X a point of the
solids as written: the same convention as a pin's ``move`` and ``rotate``.
Without them the bone is where its solids say. Boxes and extrusions stay
boxes and extrusions as written; the pose is applied to the OpenCASCADE
solid (``skelfem.design.occ.add_solid``), so every check that builds the
solids (inside the body, apart from the other bones, cables inside) sees
the placed bone.

The pose travels with each primitive of the bone as ``"pose"`` in its
parameters (``{"angle", "axis", "centre", "move"}``, plain numbers and
arrays), so whatever hashes or builds primitives needs nothing more.
"""
from __future__ import annotations

import numpy as np

MAX_ANGLE = 360.0      # degrees: a bone turns by at most one revolution (skelfem.design.shapes reads it)


def rotation(axis, degrees: float) -> np.ndarray:
    """The 3x3 matrix turning by `degrees` about the unit `axis` (Rodrigues)."""
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    th = np.radians(degrees)
    K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + np.sin(th) * K + (1.0 - np.cos(th)) * (K @ K)


def affine(pose: dict | None) -> tuple[np.ndarray, np.ndarray]:
    """(R, b) with the placed point x = R X + b; the identity for no pose."""
    if pose is None:
        return np.eye(3), np.zeros(3)
    R = rotation(pose["axis"], pose["angle"])
    c = np.asarray(pose["centre"], dtype=float)
    return R, c + np.asarray(pose["move"], dtype=float) - R @ c


def relative(old: dict | None, new: dict | None) -> tuple[np.ndarray, np.ndarray]:
    """(R, b) taking a point of the bone placed by `old` to where `new` places it."""
    R0, b0 = affine(old)
    R1, b1 = affine(new)
    R = R1 @ R0.T
    return R, b1 - R @ b0


def placed(solids: tuple, pose: dict | None) -> tuple:
    """The bone's primitives, each carrying the pose (as is when there is none)."""
    if pose is None:
        return solids
    return tuple({kind: {**params, "pose": pose}} for prim in solids for kind, params in prim.items())


def apply(occ, tag: int, pose: dict | None) -> None:
    """Place the OpenCASCADE volume `tag` by pose: turned about its centre, then moved."""
    if pose is None:
        return
    if pose["angle"]:
        occ.rotate([(3, tag)], *(float(v) for v in pose["centre"]), *(float(v) for v in pose["axis"]),
                   float(np.radians(pose["angle"])))
    move = [float(v) for v in pose["move"]]
    if any(move):
        occ.translate([(3, tag)], *move)
