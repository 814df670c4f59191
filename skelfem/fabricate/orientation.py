"""Print orientation: which face of a part goes on the bed, and the support that orientation needs.

A part is tried lying on each of the six axis directions of its design frame
(the mould halves and 2D bones are boxes and extrusions: their flat faces lie
along those axes) and on each of its ``FACE_CANDIDATES`` largest planar faces
whatever their direction (a round bone's tilted end cap): the triangles are
grouped by their outward normal, each group's triangles on the part's
outermost plane along that normal are the face, and the faces are ranked by
area. For each candidate direction the triangles of the closed, oriented
surface are rotated so that that direction points down, and

- the *support area* is the projected area (onto the bed) of the faces that
  overhang: outward normal pointing down by more than ``OVERHANG`` degrees
  from the vertical wall (n_z < -sin(OVERHANG)), and not lying on the bed;
- the *bed area* is the area of the faces lying flat on the bed.

A pose with nothing flat on the bed (standing on an edge or a rim) is taken
only when no candidate has any. Of the rest, the one with the least support
area wins; ties (within 1 % of the part's largest triangle's area) go to the
larger bed area (the same tolerance), then to the order of the candidates:
the axis directions in ``DIRECTIONS``' order (the design's own orientation
first), then the faces, largest first. The rotation maps design coordinates
to print coordinates, the translation puts the bed at z = 0; both are written
into fabrication.json so that the parts can be put back together.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

OVERHANG = 45.0          # degrees: a face leaning out further than this from the vertical needs support
DIRECTIONS = ("-z", "+z", "-y", "+y", "-x", "+x")     # the part's face that goes down, in design axes
FACE_CANDIDATES = 12     # the largest planar faces tried besides the axis directions
FLAT = 0.999             # a triangle lies flat on the bed when its outward normal has n_z < -FLAT (2.6 degrees)
SAME_NORMAL = 1e-4       # unit normals this close (each component) belong to one planar face


def axis_vector(direction: str) -> np.ndarray:
    """The unit vector of a design axis direction ("+z" -> (0, 0, 1))."""
    d = np.zeros(3)
    d["xyz".index(direction[1])] = 1.0 if direction[0] == "+" else -1.0
    return d


def direction_name(d: np.ndarray) -> str:
    """An axis direction by its name ("-z"), any other by its components: "(0, 0.894, -0.447)"."""
    for name in DIRECTIONS:
        if np.allclose(d, axis_vector(name), atol=1e-9):
            return name
    return "(" + ", ".join(f"{v:.3g}" for v in np.where(np.abs(d) < 5e-4, 0.0, d)) + ")"


@dataclass
class PrintPose:
    down: str                 # the direction (in design axes) that points down on the bed: direction_name
    rotation: np.ndarray      # (3, 3): print = rotation @ design + translation
    translation: np.ndarray   # (3,)
    support_area: float       # mm^2, projected
    bed_area: float           # mm^2
    direction: np.ndarray = None     # (3,) the unit vector of down

    def apply(self, points: np.ndarray) -> np.ndarray:
        return points @ self.rotation.T + self.translation

    def to_dict(self) -> dict:
        return {"down": self.down, "direction": [float(v) for v in self.direction],
                "rotation": self.rotation.round(12).tolist(),
                "translation": [float(v) for v in self.translation],
                "support_area": float(self.support_area), "bed_area": float(self.bed_area),
                "needs_support": bool(self.support_area > 0.0)}


def _unit(direction) -> np.ndarray:
    d = axis_vector(direction) if isinstance(direction, str) else np.asarray(direction, float)
    return d / np.linalg.norm(d)


def turn_putting_down(direction) -> tuple[np.ndarray, float]:
    """(unit axis, angle in rad) of the turn taking ``direction`` (a design axis name such as "+z", or a
    vector) to -z: about their common normal, a half turn about x when it points straight up."""
    d = _unit(direction)
    target = np.array([0.0, 0.0, -1.0])
    if np.allclose(d, target, atol=1e-12):
        return np.array([1.0, 0.0, 0.0]), 0.0
    if np.allclose(d, -target, atol=1e-12):          # upside down: a half turn about x
        return np.array([1.0, 0.0, 0.0]), np.pi
    k = np.cross(d, target)
    return k / np.linalg.norm(k), float(np.arccos(np.clip(d @ target, -1.0, 1.0)))


def rotation_putting_down(direction) -> np.ndarray:
    """The proper rotation of turn_putting_down (Rodrigues); exact in its zeros and ones for an axis."""
    k, angle = turn_putting_down(direction)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    c, s = np.cos(angle), np.sin(angle)
    if direction_name(_unit(direction)) in DIRECTIONS:
        c, s = np.rint(c), np.rint(s)
    return np.eye(3) + s * K + (1 - c) * K @ K


def _faces(points: np.ndarray, tris: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(area (m,), unit outward normal (m, 3)) of every triangle (counter-clockwise seen from outside)."""
    a, b, c = points[tris[:, 0]], points[tris[:, 1]], points[tris[:, 2]]
    n = np.cross(b - a, c - a)
    area = 0.5 * np.linalg.norm(n, axis=1)
    return area, n / np.maximum(2.0 * area, 1e-300)[:, None]


def _tolerance(points: np.ndarray) -> float:
    """How far off a plane a vertex of a face on it may be: 1e-6 of the part's size."""
    return 1e-6 * max(float(np.ptp(points, axis=0).max()), 1.0)


def planar_faces(points: np.ndarray, tris: np.ndarray, count: int = FACE_CANDIDATES,
                 faces: tuple | None = None) -> list[tuple[np.ndarray, float]]:
    """The part's largest planar faces a bed can touch, largest first: (outward unit normal, area).

    Triangles are grouped by their normal (rounded to SAME_NORMAL); a group's
    face is its triangles whose corners lie on the part's outermost plane
    along the group's (area-weighted) normal: a face inside a recess cannot
    touch the bed. Only the ``4 count`` largest groups are looked at (a curved
    surface makes a group per triangle, each small). ``faces``: _faces(points,
    tris) if the caller has them."""
    area, n = faces if faces is not None else _faces(points, tris)
    keep = np.flatnonzero(area > 0)
    if not len(keep):
        return []
    q = np.round(n[keep] / SAME_NORMAL).astype(np.int64) + int(round(1 / SAME_NORMAL)) + 1
    span = 2 * int(round(1 / SAME_NORMAL)) + 3
    _, group = np.unique((q[:, 0] * span + q[:, 1]) * span + q[:, 2], return_inverse=True)
    group = group.reshape(-1)
    sums = np.bincount(group, weights=area[keep])
    largest = np.argsort(-sums, kind="stable")[:4 * count]       # a group may lie partly in a recess
    tol = _tolerance(points)
    out = []
    for g in largest:
        mine = keep[group == g]
        d = (area[mine] @ n[mine]) / np.linalg.norm(area[mine] @ n[mine])
        height = points[tris[mine]] @ d                            # (k, 3): each corner along d
        on = np.all(height >= float((points @ d).max()) - tol, axis=1)
        if on.any():
            out.append((d, float(area[mine][on].sum())))
    out.sort(key=lambda item: -item[1])
    return out[:count]


def pose(points: np.ndarray, tris: np.ndarray, direction, faces: tuple | None = None) -> PrintPose:
    """The part lying on ``direction`` (a design axis name or an outward unit vector): its support and bed
    areas. ``faces``: _faces(points, tris) if the caller has them (a rotation keeps areas and turns normals)."""
    d = _unit(direction)
    R = rotation_putting_down(direction)
    area, n = faces if faces is not None else _faces(points, tris)
    z = points @ R[2]                                      # heights above the bed, less z0
    nz = n @ R[2]
    z0 = float(z.min())
    on_bed = np.all(np.abs(z[tris] - z0) <= _tolerance(points), axis=1)
    overhang = (nz < -np.sin(np.radians(OVERHANG))) & ~on_bed
    support = float((area[overhang] * -nz[overhang]).sum())
    bed = float(area[on_bed & (nz < -FLAT)].sum())
    return PrintPose(direction_name(d), R, np.array([0.0, 0.0, -z0]), support, bed, d)


def best_pose(points: np.ndarray, tris: np.ndarray) -> PrintPose:
    """The orientation that needs the least support (see the module doc)."""
    faces = _faces(points, tris)
    axes = [axis_vector(name) for name in DIRECTIONS]
    tilted = [d for d, _ in planar_faces(points, tris, faces=faces)
              if not any(np.abs(d - a).max() <= SAME_NORMAL for a in axes)]      # an axis is tried as such
    poses = [pose(points, tris, d, faces) for d in (*DIRECTIONS, *tilted)]
    tie = 0.01 * max(float(faces[0].max(initial=0.0)), 1e-12)
    flat = [p for p in poses if p.bed_area > tie]
    poses = flat or poses                                 # standing on a rim only when nothing lies flat
    least = min(p.support_area for p in poses)
    close = [p for p in poses if p.support_area <= least + tie]
    widest = max(p.bed_area for p in close)
    return next(p for p in close if p.bed_area >= widest - tie)      # the candidates' order breaks a tie


def move_into_pose(occ, dimtags: list, pose_: PrintPose) -> None:
    """Turn and shift OCC entities into the pose: a rotation and a translation (rigid, so OCC keeps
    the exact surfaces; a general affine map would turn them into splines)."""
    k, angle = turn_putting_down(pose_.direction)
    if angle:
        occ.rotate(dimtags, 0.0, 0.0, 0.0, *k, angle)
    occ.translate(dimtags, *pose_.translation)
