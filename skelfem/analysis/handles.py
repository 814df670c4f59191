"""Design handles: a few numbers p that move a 2D design's points, and the exact velocities dPoints/dp.

A handle is named by a design key (skelfem.design.variables: a vertex of a body, a hole or a bone, a
bone's offset or angle, a cable's sketch vertex, a material's E); its value is a change from the start
design (p = 0).

A bone's pose carries with it the cable sketch vertices and the markers that lie strictly inside
the bone at the start (a tendon's end anchored in the bone moves with it). The design is
points(p) = pose_b(start + additive moves), pose_b(P) = c_b + R(angle_b) (P - c_b) + offset_b for
the points of bone b; ``velocities`` is its exact Jacobian at any p.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np

from ..design import polygons as poly_tools
from ..design.variables import parse_variable
from ..mesh.morph import polygons


@dataclass(frozen=True)
class Handle:
    key: str
    kind: str                   # "point" (one coordinate of a point), "offset", "angle", "modulus", "stiffness"
    #                             or "pretension"
    point: int = -1             # "point": the point's index
    axis: int = 0               # "point", "offset": 0 x, 1 y
    bone: int = -1              # "offset", "angle": the bone's index
    material: str = ""          # "modulus"
    cable: str = ""             # "stiffness", "pretension"


class DesignHandles:
    """The points a set of handles moves, at the start design, and how they move."""

    def __init__(self, design, keys):
        if design.dim != 2:
            raise ValueError("design handles are 2D")
        self.start = design
        self.polys0 = polygons(design)
        self.paths0 = {c.name: np.asarray(c.path, dtype=float) for c in design.cables}
        self.markers0 = {n: np.asarray(v, dtype=float) for n, v in design.markers.items()}
        # every movable point in one array: polygon vertices, sketch vertices, markers
        self.names: list[tuple] = []
        for k, p in enumerate(self.polys0):
            self.names += [("poly", k, i) for i in range(len(p))]
        for c, path in self.paths0.items():
            self.names += [("path", c, i) for i in range(len(path))]
        self.names += [("marker", m, 0) for m in self.markers0]
        self.P0 = np.vstack(self.polys0 + list(self.paths0.values())
                            + [m[None, :] for m in self.markers0.values()])
        self.index = {n: j for j, n in enumerate(self.names)}
        n_loops = len(design.body_loops)
        self.bone_poly = {b.name: n_loops + j for j, b in enumerate(design.bones)}
        self.loop_of = self._body_loops(design)
        self.handles = [self._handle(key) for key in keys]
        twice = sorted({k for k in keys if list(keys).count(k) > 1})
        if twice:
            raise ValueError(f"{twice[0]}: named twice")
        self.anchor_radii: dict = {}     # {cable: radius} written into every moved design (DesignGradient)
        self.keys = [h.key for h in self.handles]
        posed = sorted({h.bone for h in self.handles if h.kind in ("offset", "angle")})
        self.group = np.full(len(self.P0), -1)           # the posed bone each point follows, or -1
        self.centre = {}
        for b in posed:
            bone = design.bones[b]
            outline = np.asarray(bone.outline, dtype=float)
            tol = 1e-9 * (1.0 + float(np.abs(outline).max()))
            k = self.bone_poly[bone.name]
            members = [self.index[("poly", k, i)] for i in range(len(outline))]
            others = [j for j, n in enumerate(self.names) if n[0] != "poly"]
            inside = poly_tools.strictly_inside(outline, self.P0[others], tol) if others else []
            members += [j for j, flag in zip(others, inside) if flag]
            self.group[members] = b
            self.centre[b] = _centroid(outline)

    @staticmethod
    def _body_loops(design) -> dict:
        """{(body name, "outline" or hole k): polygon index} of the body loops, in ``polygons`` order."""
        out, k = {}, 0
        for body in design.bodies:
            out[(body.name or "", "outline")] = k
            k += 1
            for h in range(len(body.holes)):
                out[(body.name or "", h)] = k
                k += 1
        return out

    def _handle(self, key: str) -> Handle:
        v = parse_variable(self.start, key)
        if v.kind == "modulus":
            return Handle(key, "modulus", material=v.owner)
        if v.kind in ("stiffness", "pretension"):
            return Handle(key, v.kind, cable=v.owner)
        if v.kind in ("offset", "angle"):
            bone = [b.name for b in self.start.bones].index(v.owner)
            return Handle(key, v.kind, bone=bone, axis=v.axis)
        if v.kind == "path":
            name = ("path", v.owner, v.index)
        elif v.kind == "bone_vertex":
            name = ("poly", self.bone_poly[v.owner], v.index)
        else:
            name = ("poly", self.loop_of[(v.owner, "outline" if v.kind == "body" else v.hole)], v.index)
        return Handle(key, "point", point=self.index[name], axis=v.axis)

    # -- the design at p, and its velocities --------------------------------------------------------------
    def _poses(self, p) -> dict:
        """{bone: (rotation matrix, angle in rad, offset)} at p."""
        out = {b: [0.0, np.zeros(2)] for b in self.centre}
        for h, v in zip(self.handles, p):
            if h.kind == "angle":
                out[h.bone][0] += math.radians(float(v))
            elif h.kind == "offset":
                out[h.bone][1] = out[h.bone][1] + float(v) * np.eye(2)[h.axis]
        return {b: (_rotation(a), a, o) for b, (a, o) in out.items()}

    def points(self, p) -> np.ndarray:
        """Every movable point at p, (n, 2)."""
        P = self.P0.copy()
        for h, v in zip(self.handles, p):
            if h.kind == "point":
                P[h.point, h.axis] += float(v)
        for b, (R, _, o) in self._poses(p).items():
            idx = self.group == b
            P[idx] = self.centre[b] + (P[idx] - self.centre[b]) @ R.T + o
        return P

    def velocities(self, p) -> np.ndarray:
        """dPoints/dp, (n, 2, handles): exact at p."""
        P = self.P0.copy()
        for h, v in zip(self.handles, p):
            if h.kind == "point":
                P[h.point, h.axis] += float(v)
        poses = self._poses(p)
        out = np.zeros((len(P), 2, len(self.handles)))
        for j, h in enumerate(self.handles):
            if h.kind == "point":
                b = self.group[h.point]
                out[h.point, :, j] = poses[b][0][:, h.axis] if b >= 0 else np.eye(2)[h.axis]
            elif h.kind == "offset":
                out[self.group == h.bone, h.axis, j] = 1.0
            elif h.kind == "angle":
                idx = self.group == h.bone
                R = poses[h.bone][0]
                r = (P[idx] - self.centre[h.bone]) @ R.T
                out[idx, :, j] = math.radians(1.0) * np.column_stack([-r[:, 1], r[:, 0]])
        return out

    def moduli(self, p) -> dict:
        """{material: E} at p, of the materials with a handle."""
        out = {}
        for h, v in zip(self.handles, p):
            if h.kind == "modulus":
                out[h.material] = out.get(h.material, float(self.start.materials[h.material].E)) + float(v)
        return out

    def raw(self, p) -> dict:
        """The start design's TOML data with the handles at p (a fresh dict for parse_design)."""
        raw = copy.deepcopy(self.start.raw)
        P = self.points(p)
        several = "bodies" in raw
        for (owner, which), loop in self.loop_of.items():
            pts = P[[self.index[("poly", loop, i)] for i in range(len(self.polys0[loop]))]]
            table = next(b for b in raw["bodies"] if b.get("name") == owner) if several else raw["body"]
            if which == "outline":
                table["outline"] = pts.tolist()
            else:
                table["holes"][which] = pts.tolist()
        for bone in raw.get("bones", []):
            loop = self.bone_poly[bone["name"]]
            bone["outline"] = P[[self.index[("poly", loop, i)] for i in range(len(self.polys0[loop]))]].tolist()
        for cable in raw.get("cables", []):
            name = cable["name"]
            cable["path"] = P[[self.index[("path", name, i)] for i in range(len(self.paths0[name]))]].tolist()
        for name in self.markers0:
            raw["markers"][name] = P[self.index[("marker", name, 0)]].tolist()
        for material, E in self.moduli(p).items():
            raw["materials"][material]["E"] = E
        for h, v in zip(self.handles, p):
            if h.kind in ("stiffness", "pretension"):
                cable = next(c for c in raw["cables"] if c["name"] == h.cable)
                cable[h.kind] = float(getattr(self.start.cable(h.cable), h.kind)) + float(v)
        for cable in raw.get("cables", []):
            if cable["name"] in self.anchor_radii:
                cable["anchor_radius"] = self.anchor_radii[cable["name"]]
        return raw

    def split(self, P: np.ndarray) -> tuple[list, dict, dict]:
        """(polygons, {cable: path}, {marker: point}) of a points array (or of its derivatives)."""
        polys = [P[[self.index[("poly", k, i)] for i in range(len(p))]] for k, p in enumerate(self.polys0)]
        paths = {c: P[[self.index[("path", c, i)] for i in range(len(p))]] for c, p in self.paths0.items()}
        markers = {m: P[self.index[("marker", m, 0)]] for m in self.markers0}
        return polys, paths, markers

    def join(self, polys, paths: dict, markers: dict) -> np.ndarray:
        """The inverse of split (missing cables or markers: zero)."""
        out = np.zeros_like(self.P0)
        for k, g in enumerate(polys):
            out[[self.index[("poly", k, i)] for i in range(len(g))]] = g
        for c, g in paths.items():
            out[[self.index[("path", c, i)] for i in range(len(g))]] = g
        for m, g in markers.items():
            out[self.index[("marker", m, 0)]] = g
        return out


def _rotation(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s], [s, c]])


def _centroid(outline: np.ndarray) -> np.ndarray:
    """The area centroid of a simple polygon."""
    x, y = outline[:, 0], outline[:, 1]
    x1, y1 = np.roll(x, -1), np.roll(y, -1)
    cross = x * y1 - x1 * y
    area = 0.5 * cross.sum()
    return np.array([((x + x1) * cross).sum(), ((y + y1) * cross).sum()]) / (6.0 * area)


# -- 3D: the bones' poses ------------------------------------------------------------------------------------
KINDS_3D = "bones.B.offset.x|y|z (mm), bones.B.angle.x|y|z (degrees), materials.M.E"


class PoseHandles3D:
    """Handles on a 3D design's bone poses: ``bones.B.offset.x|y|z`` (a translation, mm) and
    ``bones.B.angle.x|y|z`` (a turn about that axis through the bone's centre, degrees; one axis per
    bone), and ``materials.M.E``; each a change from the start design (p = 0), whose bones carry no pose.

    The points they move are the posed bones' mesh nodes (which skelfem.mesh.morph3d moves rigidly), the
    cable sketch vertices and markers inside those bones (carried by the pose, as in 2D), at
    points(p) = c + R(angle) (P0 - c) + offset; ``velocities`` is its exact Jacobian. ``join`` takes the
    nodes' gradient as Morph3D.pull_back gives it.
    """

    def __init__(self, design, keys, tagged_mesh):
        if design.dim != 3:
            raise ValueError("PoseHandles3D: a 3D design")
        self.start = design
        names = [b.name for b in design.bones]
        self.handles = []
        for key in keys:
            parts = key.split(".") if isinstance(key, str) else []
            if len(parts) == 3 and parts[0] == "materials" and parts[2] == "E":
                if parts[1] not in design.materials:
                    raise ValueError(f"{key}: no material {parts[1]!r}")
                self.handles.append(Handle(key, "modulus", material=parts[1]))
            elif len(parts) == 4 and parts[0] == "bones" and parts[2] in ("offset", "angle") \
                    and parts[3] in ("x", "y", "z"):
                if parts[1] not in names:
                    raise ValueError(f"{key}: no bone {parts[1]!r} (have: {', '.join(names)})")
                self.handles.append(Handle(key, parts[2], bone=names.index(parts[1]), axis="xyz".index(parts[3])))
            else:
                raise ValueError(f"{key!r}: not a 3D design variable ({KINDS_3D})")
        twice = sorted({k for k in keys if list(keys).count(k) > 1})
        if twice:
            raise ValueError(f"{twice[0]}: named twice")
        self.keys = [h.key for h in self.handles]
        self.anchor_radii: dict = {}
        posed = sorted({h.bone for h in self.handles if h.kind in ("offset", "angle")})
        self.axis = {}
        for h in self.handles:
            if h.kind == "angle":
                if self.axis.setdefault(h.bone, h.axis) != h.axis:
                    raise ValueError(f"{h.key}: one turning axis per bone")
        for b in posed:
            if design.bones[b].pose is not None:
                raise ValueError(f"bones.{design.bones[b].name}: 3D design gradients start from a bone without a "
                                 "pose (move, rotate) of its own")
        self._points(design, tagged_mesh, posed)

    def _points(self, design, tm, posed) -> None:
        """The points each posed bone carries: its mesh nodes, the sketch vertices and markers inside it."""
        from ..mesh.points import locate_cells
        mesh = tm.mesh
        cells = mesh.geometry.dofmap.array.reshape(-1, 4)
        tag_of = np.zeros(len(cells), dtype=int)
        tag_of[np.asarray(tm.cell_tags.indices)] = np.asarray(tm.cell_tags.values)
        X = mesh.geometry.x[:, :3]
        self.paths0 = {c.name: np.asarray(c.path, dtype=float) for c in design.cables}
        self.markers0 = {n: np.asarray(v, dtype=float) for n, v in design.markers.items()}
        sketch = [("path", c, i) for c, p in self.paths0.items() for i in range(len(p))] + \
            [("marker", m, 0) for m in self.markers0]
        S = np.vstack([self.paths0[n[1]][n[2]] if n[0] == "path" else self.markers0[n[1]] for n in sketch]) \
            if sketch else np.zeros((0, 3))
        where = tag_of[locate_cells(mesh, S)] if len(S) else np.zeros(0, int)
        self.names, P, group = [], [], []
        self.centre = {}
        for b in posed:
            tag = tm.tags[f"bone:{design.bones[b].name}"]
            nodes = np.unique(cells[tag_of == tag])
            self.centre[b] = 0.5 * (X[nodes].min(axis=0) + X[nodes].max(axis=0))
            self.names += [("node", int(k), 0) for k in nodes]
            P.append(X[nodes])
            group += [b] * len(nodes)
            inside = [j for j in range(len(sketch)) if where[j] == tag]
            self.names += [sketch[j] for j in inside]
            P.append(S[inside])
            group += [b] * len(inside)
        self.P0 = np.vstack(P) if P else np.zeros((0, 3))
        self.group = np.array(group, dtype=int)
        self.index = {n: j for j, n in enumerate(self.names)}

    def _poses(self, p) -> dict:
        """{bone: (R, offset)} at p."""
        from ..design.pose import rotation
        angle = {b: 0.0 for b in self.centre}
        offset = {b: np.zeros(3) for b in self.centre}
        for h, v in zip(self.handles, p):
            if h.kind == "angle":
                angle[h.bone] += float(v)
            elif h.kind == "offset":
                offset[h.bone] = offset[h.bone] + float(v) * np.eye(3)[h.axis]
        return {b: (rotation(np.eye(3)[self.axis.get(b, 2)], angle[b]), offset[b], angle[b]) for b in self.centre}

    def points(self, p) -> np.ndarray:
        P = self.P0.copy()
        for b, (R, o, _) in self._poses(p).items():
            idx = self.group == b
            P[idx] = self.centre[b] + (P[idx] - self.centre[b]) @ R.T + o
        return P

    def velocities(self, p) -> np.ndarray:
        """dPoints/dp, (n, 3, handles): exact at p."""
        poses = self._poses(p)
        out = np.zeros((len(self.P0), 3, len(self.handles)))
        for j, h in enumerate(self.handles):
            idx = self.group == h.bone
            if h.kind == "offset":
                out[idx, h.axis, j] = 1.0
            elif h.kind == "angle":
                r = (self.P0[idx] - self.centre[h.bone]) @ poses[h.bone][0].T
                out[idx, :, j] = math.radians(1.0) * np.cross(np.eye(3)[self.axis[h.bone]], r)
        return out

    def raw(self, p) -> dict:
        """The start design's TOML data with the handles at p."""
        raw = copy.deepcopy(self.start.raw)
        P = self.points(p)
        for b, (_, o, a) in self._poses(p).items():
            bone = raw["bones"][b]
            bone["move"] = [float(v) for v in o]
            bone["rotate"] = {"angle": float(a), "axis": [float(v) for v in np.eye(3)[self.axis.get(b, 2)]],
                              "centre": [float(v) for v in self.centre[b]]}
        for cable in raw.get("cables", []):
            path = [list(map(float, q)) for q in self.paths0[cable["name"]]]
            for i in range(len(path)):
                j = self.index.get(("path", cable["name"], i))
                if j is not None:
                    path[i] = P[j].tolist()
            cable["path"] = path
            if cable["name"] in self.anchor_radii:
                cable["anchor_radius"] = self.anchor_radii[cable["name"]]
        for name in self.markers0:
            j = self.index.get(("marker", name, 0))
            if j is not None:
                raw["markers"][name] = P[j].tolist()
        for h, v in zip(self.handles, p):
            if h.kind == "modulus":
                raw["materials"][h.material]["E"] = float(raw["materials"][h.material]["E"]) + float(v)
        return raw

    def join(self, g_nodes: np.ndarray, paths: dict, markers: dict) -> np.ndarray:
        """The gradient at every point: the nodes' from g_nodes (n_nodes, 3), the sketch's and markers'."""
        out = np.zeros_like(self.P0)
        for j, n in enumerate(self.names):
            if n[0] == "node":
                out[j] = g_nodes[n[1]]
            elif n[0] == "path" and n[1] in paths:
                out[j] = paths[n[1]][n[2]]
            elif n[0] == "marker" and n[1] in markers:
                out[j] = markers[n[1]]
        return out
