"""Print orientation: which face of a part goes on the bed, and the support that orientation needs.

A part is tried lying on each of the six axis directions of its design frame
(the mould halves and 2D bones are boxes and extrusions: their flat faces lie
along those axes). For each, the triangles of its closed, oriented surface
are rotated so that that direction points down, and

- the *support area* is the projected area (onto the bed) of the faces that
  overhang: outward normal pointing down by more than ``OVERHANG`` degrees
  from the vertical wall (n_z < -sin(OVERHANG)), and not lying on the bed;
- the *bed area* is the area of the faces lying flat on the bed.

The orientation with the least support area wins; ties (within 1 % of the
part's largest triangle's area) go to the larger bed area (the same
tolerance), then to the order of ``DIRECTIONS`` (the design's own
orientation first). The rotation maps
design coordinates to print coordinates, the translation puts the bed at
z = 0; both are written into fabrication.json so that the parts can be put
back together.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

OVERHANG = 45.0          # degrees: a face leaning out further than this from the vertical needs support
DIRECTIONS = ("-z", "+z", "-y", "+y", "-x", "+x")     # the part's face that goes down, in design axes


@dataclass
class PrintPose:
    down: str                 # the design axis direction that points down on the bed
    rotation: np.ndarray      # (3, 3): print = rotation @ design + translation
    translation: np.ndarray   # (3,)
    support_area: float       # mm^2, projected
    bed_area: float           # mm^2

    def apply(self, points: np.ndarray) -> np.ndarray:
        return points @ self.rotation.T + self.translation

    def to_dict(self) -> dict:
        return {"down": self.down, "rotation": self.rotation.round(12).tolist(),
                "translation": [float(v) for v in self.translation],
                "support_area": float(self.support_area), "bed_area": float(self.bed_area),
                "needs_support": bool(self.support_area > 0.0)}


def turn_putting_down(direction: str) -> tuple[np.ndarray, float]:
    """(unit axis, angle in rad) of the turn taking the design axis ``direction`` (e.g. "+z") to -z."""
    axis = "xyz".index(direction[1])
    d = np.zeros(3)
    d[axis] = 1.0 if direction[0] == "+" else -1.0
    target = np.array([0.0, 0.0, -1.0])
    if np.allclose(d, target):
        return np.array([1.0, 0.0, 0.0]), 0.0
    if np.allclose(d, -target):                     # upside down: a half turn about x
        return np.array([1.0, 0.0, 0.0]), np.pi
    k = np.cross(d, target)
    return k / np.linalg.norm(k), np.pi / 2


def rotation_putting_down(direction: str) -> np.ndarray:
    """The proper rotation of turn_putting_down (Rodrigues), exact in its zeros and ones."""
    k, angle = turn_putting_down(direction)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    c, s = np.rint(np.cos(angle)), np.rint(np.sin(angle))
    return np.eye(3) + s * K + (1 - c) * K @ K


def _faces(points: np.ndarray, tris: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(area (m,), unit outward normal (m, 3)) of every triangle (counter-clockwise seen from outside)."""
    a, b, c = points[tris[:, 0]], points[tris[:, 1]], points[tris[:, 2]]
    n = np.cross(b - a, c - a)
    area = 0.5 * np.linalg.norm(n, axis=1)
    return area, n / np.maximum(2.0 * area, 1e-300)[:, None]


def pose(points: np.ndarray, tris: np.ndarray, direction: str) -> PrintPose:
    """The part lying on ``direction``: its support and bed areas."""
    R = rotation_putting_down(direction)
    p = points @ R.T
    z0 = float(p[:, 2].min())
    area, n = _faces(p, tris)
    tol = 1e-6 * max(float(np.ptp(p, axis=0).max()), 1.0)
    on_bed = np.all(np.abs(p[tris, 2] - z0) <= tol, axis=1)
    overhang = (n[:, 2] < -np.sin(np.radians(OVERHANG))) & ~on_bed
    support = float((area[overhang] * -n[overhang, 2]).sum())
    bed = float(area[on_bed & (n[:, 2] < -0.999)].sum())
    return PrintPose(direction, R, np.array([0.0, 0.0, -z0]), support, bed)


def best_pose(points: np.ndarray, tris: np.ndarray) -> PrintPose:
    """The orientation that needs the least support (see the module doc)."""
    poses = [pose(points, tris, d) for d in DIRECTIONS]
    area, _ = _faces(points, tris)
    tie = 0.01 * max(float(area.max(initial=0.0)), 1e-12)
    least = min(p.support_area for p in poses)
    close = [p for p in poses if p.support_area <= least + tie]
    widest = max(p.bed_area for p in close)
    return next(p for p in close if p.bed_area >= widest - tie)      # DIRECTIONS' order breaks a tie


def move_into_pose(occ, dimtags: list, pose_: PrintPose) -> None:
    """Turn and shift OCC entities into the pose: a rotation and a translation (rigid, so OCC keeps
    the exact surfaces; a general affine map would turn them into splines)."""
    k, angle = turn_putting_down(pose_.down)
    if angle:
        occ.rotate(dimtags, 0.0, 0.0, 0.0, *k, angle)
    occ.translate(dimtags, *pose_.translation)
