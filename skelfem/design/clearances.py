"""Fabrication clearances of a 2D design as smooth inequalities with exact gradients (an optimize-design task's
``[constraints]``).

=====================  ==========================================================================
``min_wall``           silicone between every bone and the body's outline and holes (mm)
``min_gap``            between any two bones: the joint gap (mm)
``min_cable_wall``     silicone between every cable sketch vertex that lies in the silicone (not on
                       the outline, not in a bone) and the body's outline, holes and bones (mm): a
                       channel's way into a bone neither grazes it nor runs along under its side
``min_cable_gap``      between the sketches of any two cables (mm), which must not cross: where both
                       run in a bone, ``skelfem fabricate`` needs their holes' radii +
                       ``fabrication.min_wall`` (``cable_gap_floor``), and a smaller value is refused
``min_entry_angle``    a tendon's channel into a bone (its last segment) crosses the bone's edge
                       at this angle or more (degrees; fabricate sheathes a channel below 30) and
                       keeps its radius + ``fabrication.min_wall`` from the bone's corners
(always, with any)     every cable end in a bone keeps its hole's radius (a ligament's
                       ``fabrication.anchor_diameter / 2``, a tendon's ``channel_diameter / 2``) +
                       ``fabrication.min_wall`` from the bone's outline: the wall ``skelfem
                       fabricate`` demands round an anchor hole or a channel's end; and, without
                       ``min_cable_gap``, any two cables' sketches do not cross and keep their radii
                       + ``fabrication.min_wall`` apart (``cable_apart``: ``skelfem fabricate``'s rule
                       for two cables, in a bone or in the silicone)
=====================  ==========================================================================

Each is a set of distances d(x, [a, b]) − need ≥ 0 between a point and a segment: for two
polygons, every vertex of one against every edge of the other, both ways (the least of these is
the distance between two boundaries that do not cross). A point's distance to a segment is its
distance to a convex set, continuously differentiable wherever it is not zero: with c = a + t (b − a)
the nearest point and n = (x − c) / d, dd/dx = n, dd/da = −(1 − t) n, dd/db = −t n. So every
constraint is C¹ in the points, and through the design handles' exact velocities in the design
variables (skelfem.analysis.design_optimize).

Two cables' sketches that cross would pass those distances (the vertices may all lie far from the
other sketch). Where a segment of one crosses a segment of the other, the least of the four
end-to-segment distances of the pair counts as negative, −d: the depth by which the nearest end
would have to move to undo the crossing, a signed distance that is continuous where the crossing
ends (d = 0 there) and whose gradient is −n. Continuous moves that keep d − need ≥ 0 can never
make two sketches cross (an end would have to pass through the other segment); the sign catches a
start design or an optimiser's trial step that jumped across.

The points are those of ``points_of``: the body's loops and the bones' outlines (the order of
``Design.body_loops`` then ``Design.bones``), then every cable's sketch. Numpy only: the task is
checked at its start before anything is meshed.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import polygons as poly_tools

KEYS = ("min_wall", "min_gap", "min_cable_wall", "min_cable_gap", "min_entry_angle")
ANGLES = ("min_entry_angle",)  # degrees; the other keys are lengths (mm)
ANCHOR = "end_wall"            # the wall skelfem fabricate demands round a cable end's hole in a bone
APART = "cable_apart"          # skelfem fabricate's rule for two cables: no crossing, radii + min_wall apart
CORNERS = "entry_corners"      # min_entry_angle's channel kept off the corners of the bone it enters
GRAZING_ANGLE = 30.0           # degrees: below it skelfem fabricate sheathes a channel (its GRAZING = sin 30)


@dataclass(frozen=True)
class Group:
    key: str            # one of KEYS, "end_wall" or "entry_corners"
    what: str           # "bone 'distal' and the body's outline"
    need: float         # mm; for min_entry_angle the sine of the least angle

    def shortfall(self, least: float) -> str:
        """Why the start design fails this group, its least value being ``least``."""
        if self.key in ANGLES:
            angle, need = (math.degrees(math.asin(min(max(v, -1.0), 1.0))) for v in (least, self.need))
            return f"{self.what} at {angle:.3g} degrees in the start design, less than the {need:.3g} needed"
        if least < 0.0:
            return f"{self.what} cross in the start design"
        return f"{self.what} are {least:.3g} mm apart in the start design, less than the {self.need:g} mm needed"

    @property
    def asked_by(self) -> str:
        """The [constraints] key that asks for this group (fabrication: any key asks for the end walls)."""
        return {ANCHOR: "fabrication", APART: "fabrication", CORNERS: "min_entry_angle"}.get(self.key, self.key)


def points_of(polys, paths) -> np.ndarray:
    """One (n, 2) array of the design's loops and bones (``polys``) and cable sketches (``paths``, in order)."""
    return np.vstack([np.asarray(p, dtype=float) for p in list(polys) + list(paths)]) if polys else np.zeros((0, 2))


def _ranges(sizes) -> list[np.ndarray]:
    out, k = [], 0
    for n in sizes:
        out.append(np.arange(k, k + n))
        k += n
    return out


class Clearances:
    """The constraints of a ``[constraints]`` table on a 2D design: ``values(X)`` and ``jacobian(X)``."""

    def __init__(self, design, constraints: dict):
        loops = [np.asarray(p, dtype=float) for p in design.body_loops]
        bones = [np.asarray(b.outline, dtype=float) for b in design.bones]
        paths = [np.asarray(c.path, dtype=float) for c in design.cables]
        idx = _ranges([len(p) for p in loops + bones + paths])
        loop_idx, bone_idx, path_idx = idx[:len(loops)], idx[len(loops):len(loops) + len(bones)], \
            idx[len(loops) + len(bones):]
        tol = 1e-9 * (1.0 + max(float(np.abs(p).max()) for p in loops))
        loop_names = ["the body's outline" if k == 0 or len(loops) == 1 else f"hole {k - 1} of the body"
                      for k in range(len(loops))]
        if len(design.bodies) > 1:
            loop_names = [f"loop {k} of the bodies" for k in range(len(loops))]
        self.groups: list[Group] = []
        rows: list[tuple] = []              # (point, a, b, group): d(point, [a, b]) >= need
        entries: list[tuple] = []           # (a, b, c, d, sign, group): sign sin(b - a, d - c) >= need
        crossings: list[tuple] = []         # two cables' segments (p, q, a, b) and their four rows

        def polygon_pair(i_a, i_b, group):
            for P, Q in ((i_a, i_b), (i_b, i_a)):
                for x in P:
                    for a, b in zip(Q, np.roll(Q, -1)):
                        rows.append((x, a, b, group))

        def polyline_pair(i_a, i_b, group):
            first = len(rows)
            for P, Q in ((i_a, i_b), (i_b, i_a)):
                for x in P:
                    for a, b in zip(Q[:-1], Q[1:]):
                        rows.append((x, a, b, group))
            na, nb = len(i_a), len(i_b)           # row of (vertex v of A, segment j of B), then (B's v, A's j)
            for i in range(na - 1):
                for j in range(nb - 1):
                    crossings.append((i_a[i], i_a[i + 1], i_b[j], i_b[j + 1],
                                      first + i * (nb - 1) + j, first + (i + 1) * (nb - 1) + j,
                                      first + na * (nb - 1) + j * (na - 1) + i,
                                      first + na * (nb - 1) + (j + 1) * (na - 1) + i))

        def add(key, what, need, pairs_of):
            self.groups.append(Group(key, what, float(need)))
            pairs_of(len(self.groups) - 1)

        if "min_wall" in constraints:
            for j, bone in enumerate(design.bones):
                for k, name in enumerate(loop_names):
                    add("min_wall", f"bone {bone.name!r} and {name}", constraints["min_wall"],
                        lambda g, j=j, k=k: polygon_pair(bone_idx[j], loop_idx[k], g))
        if "min_gap" in constraints:
            for j in range(len(bones)):
                for i in range(j):
                    add("min_gap", f"bones {design.bones[i].name!r} and {design.bones[j].name!r}",
                        constraints["min_gap"], lambda g, i=i, j=j: polygon_pair(bone_idx[i], bone_idx[j], g))
        if "min_cable_wall" in constraints:
            walls = [(name, loop_idx[k]) for k, name in enumerate(loop_names)] + \
                [(f"bone {b.name!r}", bone_idx[j]) for j, b in enumerate(design.bones)]
            for c, cable in enumerate(design.cables):
                for v, x in enumerate(paths[c]):
                    if not self._in_silicone(design, loops, bones, x, tol):
                        continue
                    for name, ring in walls:
                        add("min_cable_wall", f"cables.{cable.name}.path[{v}] and {name}",
                            constraints["min_cable_wall"],
                            lambda g, x=path_idx[c][v], ring=ring: rows.extend(
                                (x, a, b, g) for a, b in zip(ring, np.roll(ring, -1))))
        if "min_cable_gap" in constraints:
            for j in range(len(paths)):
                for i in range(j):
                    add("min_cable_gap", f"cables {design.cables[i].name!r} and {design.cables[j].name!r}",
                        constraints["min_cable_gap"],
                        lambda g, i=i, j=j: polyline_pair(path_idx[i], path_idx[j], g))
        elif constraints:
            for j, b in enumerate(design.cables):
                for i, a in enumerate(design.cables[:j]):
                    add(APART, f"cables {a.name!r} and {b.name!r} (their holes' radii + fabrication.min_wall)",
                        _radius(design, a) + _radius(design, b) + design.fabrication.min_wall,
                        lambda g, i=i, j=j: polyline_pair(path_idx[i], path_idx[j], g))
        if constraints:
            self._end_walls(design, constraints, (paths, bones, path_idx, bone_idx), tol, add, rows, entries)
        table = np.array(rows, dtype=int).reshape(-1, 4)
        self.point, self.a, self.b, group = table.T
        self.entries = np.array(entries, dtype=int).reshape(-1, 6)
        self.crossings = np.array(crossings, dtype=int).reshape(-1, 8)
        self.group = np.concatenate([group, self.entries[:, 5]])
        self.need = np.array([self.groups[g].need for g in self.group])

    @staticmethod
    def _end_walls(design, constraints, where, tol, add, rows, entries) -> None:
        """skelfem fabricate's wall round a cable end's hole in a bone: the end keeps its hole's radius +
        fabrication.min_wall from the bone's outline. With min_entry_angle, a tendon's last segment, the
        channel into the bone, crosses the bone's edge at that angle or more and keeps the hole's radius +
        min_wall from the bone's corners: kept off them, it goes on entering through the edge it crossed at
        the start, whose angle is the constraint (below fabricate's 30 degrees its channel would open the
        bone's side where it enters, and fabricate would print a sheath the simulation does not have)."""
        paths, bones, path_idx, bone_idx = where
        spec = design.fabrication
        for c, cable in enumerate(design.cables):
            hole = spec.anchor_diameter if cable.kind == "ligament" else spec.channel_diameter
            size = "anchor_diameter" if cable.kind == "ligament" else "channel_diameter"
            for v, w in ((0, 1), (len(paths[c]) - 1, len(paths[c]) - 2)):
                for j, bone in enumerate(design.bones):
                    if not poly_tools.strictly_inside(bones[j], paths[c][v:v + 1], tol)[0]:
                        continue
                    x, ring = path_idx[c][v], bone_idx[j]
                    need = hole / 2 + spec.min_wall
                    add(ANCHOR, f"the end cables.{cable.name}.path[{v}] and the outline of bone {bone.name!r} "
                        f"(fabrication.{size} / 2 + fabrication.min_wall)", need,
                        lambda g, x=x, ring=ring: rows.extend((x, a, b, g) for a, b in zip(ring, np.roll(ring, -1))))
                    entry = _entry_edge(bones[j], paths[c][w], paths[c][v], tol)
                    if cable.kind != "tendon" or "min_entry_angle" not in constraints or entry is None:
                        continue
                    k, sign = entry
                    y = path_idx[c][w]
                    edge = (ring[k], ring[(k + 1) % len(ring)], y, x, sign)
                    add(CORNERS, f"the channel of cables.{cable.name} and the corners of bone {bone.name!r} "
                        "(fabrication.channel_diameter / 2 + fabrication.min_wall)", need,
                        lambda g, x=x, y=y, ring=ring: rows.extend((corner, y, x, g) for corner in ring))
                    add("min_entry_angle", f"the channel of cables.{cable.name} enters bone {bone.name!r}",
                        math.sin(math.radians(constraints["min_entry_angle"])),
                        lambda g, edge=edge: entries.append((*edge, g)))

    @staticmethod
    def _in_silicone(design, loops, bones, x, tol) -> bool:
        inside = poly_tools.region_contains(loops, x[None, :], tol)[0] \
            and not poly_tools.near_boundary(x[None, :], loops, tol)[0]
        return bool(inside and not any(poly_tools.contains(b, x[None, :], tol)[0] for b in bones))

    def __len__(self) -> int:
        return len(self.group)

    def _nearest(self, X):
        """(t, r, signed d) of every point-segment row: d < 0 on the row that measures how deep two crossing
        cable segments cross (the least of their four)."""
        x, a, b = X[self.point], X[self.a], X[self.b]
        e = b - a
        ee = np.einsum("ij,ij->i", e, e)
        t = np.clip(np.einsum("ij,ij->i", x - a, e) / np.where(ee > 0, ee, 1.0), 0.0, 1.0)
        r = x - (a + t[:, None] * e)
        d = np.linalg.norm(r, axis=1)
        if len(self.crossings):
            p, q, c, f = (X[self.crossings[:, k]] for k in range(4))
            crossed = _proper_crossing(p, q, c, f)
            four = self.crossings[crossed, 4:]
            deepest = four[np.arange(len(four)), np.argmin(d[four], axis=1)]
            d[deepest] = -d[deepest]
        return t, r, d

    def _sines(self, X):
        a, b, c, d, sign = (self.entries[:, i] for i in range(5))
        u, v = X[b] - X[a], X[d] - X[c]
        lu, lv = np.linalg.norm(u, axis=1), np.linalg.norm(v, axis=1)
        cross = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
        return sign * cross / (lu * lv), u, v, lu, lv, cross, sign

    def _raw(self, X) -> np.ndarray:
        """Every constraint's distance (mm) or sine, before its need is taken off."""
        X = np.asarray(X, dtype=float)
        return np.concatenate([self._nearest(X)[2], self._sines(X)[0]])

    def values(self, X: np.ndarray) -> np.ndarray:
        """d − need for every point-segment pair (mm), sin − sin(min_entry_angle) for every channel's entry: ≥ 0
        where the design keeps its clearances."""
        return self._raw(X) - self.need

    def jacobian(self, X: np.ndarray) -> np.ndarray:
        """d(values)/dX, (constraints, points, 2)."""
        X = np.asarray(X, dtype=float)
        t, r, d = self._nearest(X)
        n = np.where(d < 0, -1.0, 1.0)[:, None] * r / np.maximum(np.abs(d), 1e-300)[:, None]
        J = np.zeros((len(self), len(X), 2))
        rows = np.arange(len(self.point))
        np.add.at(J, (rows, self.point), n)
        np.add.at(J, (rows, self.a), -(1.0 - t)[:, None] * n)
        np.add.at(J, (rows, self.b), -t[:, None] * n)
        _, u, v, lu, lv, cross, sign = self._sines(X)
        k = len(self.point) + np.arange(len(self.entries))
        du = sign[:, None] * (np.column_stack([v[:, 1], -v[:, 0]]) / (lu * lv)[:, None]
                              - (cross / (lu ** 3 * lv))[:, None] * u)
        dv = sign[:, None] * (np.column_stack([-u[:, 1], u[:, 0]]) / (lu * lv)[:, None]
                              - (cross / (lu * lv ** 3))[:, None] * v)
        for col, grad in ((0, -du), (1, du), (2, -dv), (3, dv)):
            np.add.at(J, (k, self.entries[:, col]), grad)
        return J

    def worst(self, X: np.ndarray) -> list[tuple[Group, float]]:
        """[(group, its least distance)] of the groups whose least distance falls short of their need, worst
        first."""
        d = self._raw(X)
        out = []
        for g, group in enumerate(self.groups):
            least = float(d[self.group == g].min())
            if least < group.need:
                out.append((group, least))
        return sorted(out, key=lambda item: item[1] - item[0].need)

    def least(self, X: np.ndarray) -> dict:
        """{key: the least (distance − need) over its pairs} (mm; min_entry_angle: sin − its need), for reports."""
        v = self.values(X)
        return {key: float(min(v[self.group == g].min() for g, grp in enumerate(self.groups) if grp.key == key))
                for key in dict.fromkeys(grp.key for grp in self.groups)}


def _entry_edge(bone: np.ndarray, outside: np.ndarray, end: np.ndarray, tol: float):
    """(k, sign) of the one edge bone[k] -> bone[k + 1] that the segment outside -> end crosses, and the sign of
    sin(edge, segment); None if the segment starts in the bone too, or crosses at a corner or more than once."""
    if poly_tools.contains(bone, outside[None, :], tol)[0]:
        return None
    a, b = bone, np.roll(bone, -1, axis=0)
    hit = poly_tools.segments_intersect(outside[None, :], end[None, :], a, b, tol)
    if hit.sum() != 1:
        return None
    k = int(np.argmax(hit))
    u, v = b[k] - a[k], end - outside
    return k, (1 if u[0] * v[1] - u[1] * v[0] > 0 else -1)


def _proper_crossing(p, q, a, b) -> np.ndarray:
    """Whether segments p->q and a->b (rows of (n, 2) arrays) cross, each's ends strictly on either side of
    the other's line (touching is d = 0 on a row already)."""
    def side(o, u, w):
        return (u[:, 0] - o[:, 0]) * (w[:, 1] - o[:, 1]) - (u[:, 1] - o[:, 1]) * (w[:, 0] - o[:, 0])
    return (side(p, q, a) * side(p, q, b) < 0.0) & (side(a, b, p) * side(a, b, q) < 0.0)


def _radius(design, cable) -> float:
    """The radius of a cable's hole in a bone (skelfem fabricate's): a ligament's anchor hole, a tendon's channel."""
    spec = design.fabrication
    return (spec.anchor_diameter if cable.kind == "ligament" else spec.channel_diameter) / 2


def cable_gap_floor(design) -> float:
    """The least min_cable_gap that keeps ``skelfem fabricate``'s rule for two cables' holes in one bone:
    the two largest holes' radii + fabrication.min_wall."""
    spec = design.fabrication
    radii = sorted(_radius(design, c) for c in design.cables)
    return sum(radii[-2:]) + spec.min_wall if len(radii) > 1 else 0.0


def start_points(design) -> np.ndarray:
    """The design's points in ``Clearances`` order."""
    return points_of(list(design.body_loops) + [b.outline for b in design.bones], [c.path for c in design.cables])
