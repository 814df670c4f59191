"""The probe pass: every problem found on triangulations (numpy) before any output folder is touched.

Fabrication export: printable bones and a two-part mould from the design that is simulated.

The paper's second pipeline (section III): PLA bones with channels for the
cables, rubber-band ligaments, and a printed two-part mould into which
silicone is cast; section VI.A asks for moulds that fixture the skeleton.
``skelfem fabricate DESIGN`` turns a design into

- ``bone_<name>.stl`` / ``.step``: each bone (2D: its outline extruded over
  ``bone_depth``, centred in the slab) minus a channel of ``channel_diameter``
  along every piece of a tendon's sketch inside it, an anchor hole of
  ``anchor_diameter`` through it (along the mould's normal) where a ligament
  ends in it, and the sockets of the mould's pegs;
- ``mould_bottom.stl`` / ``mould_top.stl`` (and ``.step``): a block around the
  body split by the parting plane (2D: the slab's mid-plane z = thickness/2;
  3D: ``[fabrication] split``), each half minus the body, so that the closed
  cavity is the body; registration pins on the bottom half and holes with
  ``clearance`` in the top, a pour hole and vents through the top, exits for
  the tendons through the wall, and pegs that reach from each half through
  the silicone into sockets in the bones and so hold each bone where the
  design puts it (the fixturing of section VI.A).

Geometry in two passes. A *probe* pass builds the body and the bones with
Gmsh's OpenCASCADE kernel, triangulates their surfaces and plans everything
with numpy on the triangles (rays for the cable crossings, inside tests,
peg and pour sites; exact point-triangle distances for the walls around
channels). Every problem is found there, before any output folder is
touched, and raised as :class:`FabricationError` (key, message). A *build*
pass then makes each part in its own OCC model (boolean cuts and fuses),
measures its volume exactly (``getMass``), triangulates its surface, writes
binary STL and STEP, and checks the STL it wrote (every edge shared by
exactly two triangles, every shared edge used in opposite directions,
positive volume by the divergence theorem).
"""
from __future__ import annotations

import math

import numpy as np
from .meshing import generate_surface_mesh, triangle_surface
from .parts import Frame, Plan, Tool, cable_points, where_text
from . import casting
from .routes import RouteHolder, check_apart
from .sheaths import sheath
from .surfaces import (FabricationError, GRAZING, PROBE_CURVATURE, Surface, face_distances, inside,
                       point_triangle_distance, ray_hits)


def path_samples(points: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Points every <= step along a polyline (its corners included) and their arclengths."""
    seg = np.diff(points, axis=0)
    lengths = np.linalg.norm(seg, axis=1)
    out, arc = [points[:1]], [np.zeros(1)]
    s0 = 0.0
    for a, d, L in zip(points[:-1], seg, lengths):
        k = max(1, int(math.ceil(L / step)))
        f = np.arange(1, k + 1) / k
        out.append(a + f[:, None] * d), arc.append(s0 + f * L)
        s0 += L
    return np.concatenate(out), np.concatenate(arc)


class _Planner:
    """Builds the plan from the probe surfaces; every check raises FabricationError."""

    def __init__(self, design, body: Surface, bones: dict, scale: float):
        self.design, self.spec = design, design.fabrication
        self.body, self.bones, self.scale = body, bones, scale
        self.tol = 1e-7 * scale
        self.dim = design.dim
        spec = self.spec
        middle = 0.5 * (body.points.min(axis=0) + body.points.max(axis=0))
        self.frame = Frame.from_normal(middle if spec.split_point is None else spec.split_point, spec.split_normal)
        self.r_channel, self.r_anchor = spec.channel_diameter / 2, spec.anchor_diameter / 2
        self.r_peg = spec.peg_diameter / 2
        self.r_socket = self.r_peg + spec.clearance
        self.wall = spec.min_wall

    # cables in 3D coordinates
    def cable_points(self, cable) -> np.ndarray:
        return cable_points(self.design, cable)

    def cable_key(self, cable) -> str:
        return f"cables.{cable.name}.path"

    # -- where a cable runs inside a bone
    def pieces(self, points: np.ndarray, surface: Surface) -> list[dict]:
        """The stretches of a polyline inside a closed surface, each with how it starts and ends.

        A start or end is either the polyline's own end ("end") or a crossing
        of the surface, with the crossed CAD face and sin of the angle between
        the polyline and the face (|d . n| with n the triangle's normal).
        """
        seg = np.diff(points, axis=0)
        L = np.linalg.norm(seg, axis=1)
        d = seg / L[:, None]
        arc0 = np.r_[0.0, np.cumsum(L)]
        r, t, k = ray_hits(points[:-1], d, surface.corners, self.tol)
        ok = (t > self.tol) & (t <= L[r] + self.tol)     # a crossing at a corner: at the end of one segment
        r, t, k = r[ok], t[ok], k[ok]
        s = arc0[r] + t
        order = np.argsort(s)
        r, s, k = r[order], s[order], k[order]
        keep = np.r_[True, np.diff(s) > self.tol] if len(s) else np.zeros(0, bool)
        r, s, k = r[keep], s[keep], k[keep]
        sin = np.abs(np.einsum("ij,ij->i", d[r], surface.normals[k]))
        state = bool(inside(points[:1], surface, self.tol)[0])
        out, start = [], ({"at": "end", "s": 0.0} if state else None)
        for seg_i, si, ki, sn in zip(r, s, k, sin):
            cross = {"at": "face", "s": float(si), "face": int(surface.faces[ki]), "sin": float(sn),
                     "point": points[seg_i] + (si - arc0[seg_i]) * d[seg_i]}
            if state:
                out.append((start, cross))
            else:
                start = cross
            state = not state
        if state:
            out.append((start, {"at": "end", "s": float(arc0[-1])}))
        pieces = []
        for a, b in out:
            inner = points[(arc0 > a["s"] + self.tol) & (arc0 < b["s"] - self.tol)]
            pa = points[0] if a["at"] == "end" else a["point"]
            pb = points[-1] if b["at"] == "end" else b["point"]
            pieces.append({"points": np.vstack([pa, inner, pb]), "start": a, "end": b})
        return pieces

    def check_wall(self, tool: Tool, start: dict, end: dict, key_path: str, key_size: str, what: str,
                   sheathable: bool = False) -> bool:
        """Every point of the tool's axis at least radius + min_wall from the bone's surface.

        Near a crossing the axis is close to the crossed face by construction:
        a point at distance s from the crossing lies s sin(theta) from that
        face, so the face is ignored there while s < (r + min_wall)/sin(theta).
        A channel that enters at a grazing angle or would open the bone's side
        returns True when sheathable (it gets a printed sheath: sheaths.py),
        and is refused otherwise.
        """
        surface = self.bones[tool.bone]
        need = tool.radius + self.wall
        for end_ in (start, end):
            if end_["at"] == "face" and end_["sin"] < GRAZING:
                if sheathable:
                    return True
                angle = math.degrees(math.asin(min(1.0, end_["sin"])))
                raise FabricationError(key_path, f"{what} meets the surface of bone {tool.bone!r} at "
                                                 f"{where_text(end_['point'])} at a grazing {angle:.0f} degrees "
                                                 f"(at least 30 are needed, or the channel opens the bone's side)")
        pts, arc = path_samples(tool.points, min(0.25, tool.radius / 2))
        dist, faces = face_distances(pts, surface)
        total = arc[-1]
        for end_, s_from in ((start, arc), (end, total - arc)):
            if end_["at"] == "face":
                near = s_from < need / max(end_["sin"], 1e-9) + self.tol
                dist[np.ix_(near, faces == end_["face"])] = np.inf
        worst = dist.min(axis=1)
        bad = worst < need - 1e-6 * self.scale
        if not bad.any():
            return False
        if need > self.inradius(tool.bone):
            raise FabricationError(key_size, f"{2 * tool.radius:g} mm with min_wall {self.wall:g} mm on each "
                                             f"side does not fit in bone {tool.bone!r} (at most "
                                             f"{2 * max(self.inradius(tool.bone) - self.wall, 0):.3g} mm there)")
        if sheathable:
            return True
        i = int(np.argmin(worst))
        raise FabricationError(key_path, f"{what} would open the side of bone {tool.bone!r}: near "
                                         f"{where_text(pts[i])} its axis passes {worst[i]:.2f} mm from the bone's "
                                         f"surface, and radius + min_wall = {need:g} mm are needed")

    def inradius(self, bone: str) -> float:
        """Radius of the largest ball inside a bone (a grid of inside points, their distance to the surface)."""
        cache = self.__dict__.setdefault("_inradius", {})
        if bone not in cache:
            surface = self.bones[bone]
            lo, hi = surface.points.min(axis=0), surface.points.max(axis=0)
            h = max(float(np.prod(np.maximum(hi - lo, 1e-9))) / 6000.0, 1e-12) ** (1 / 3)
            axes = [np.arange(a + h / 2, b, h) for a, b in zip(lo, hi)]
            grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
            grid = grid[inside(grid, surface, self.tol)]
            cache[bone] = float(point_triangle_distance(grid, surface.corners).min(axis=1).max()) if len(grid) else 0.0
        return cache[bone]

    # -- channels and anchors
    def route(self) -> dict:
        """Channels and anchor holes per bone, every wall checked; records each tendon's way out (spool)."""
        design = self.design
        tools = {b.name: [] for b in design.bones}
        spool = {}
        for cable in design.cables:
            pts = self.cable_points(cable)
            in_bone = {}
            for bone in design.bones:
                for piece in self.pieces(pts, self.bones[bone.name]):
                    a, b = piece["start"], piece["end"]
                    if a["at"] == "end":
                        in_bone[0] = bone.name
                    if b["at"] == "end":
                        in_bone[len(pts) - 1] = bone.name
                    if cable.kind == "tendon" or (a["at"] == "face" and b["at"] == "face"):
                        r = self.r_channel if cable.kind == "tendon" else self.r_anchor
                        ext = tuple(0.0 if e["at"] == "end" else
                                    r * math.sqrt(max(1 - e["sin"] ** 2, 0)) / max(e["sin"], 1e-9) + 0.5
                                    for e in (a, b))
                        tool = Tool("channel", piece["points"], r, bone.name, cable.name, ext)
                        tools[bone.name].append((tool, a, b))
                    for e, end_point in ((a, pts[0]), (b, pts[-1])):
                        if cable.kind == "ligament" and e["at"] == "end":
                            tools[bone.name].append(self.anchor(bone.name, cable.name, end_point))
            if cable.kind == "tendon":
                spool[cable.name] = self.spool_end(cable, pts, in_bone)
        self.check_depth(tools)
        sheathed = {}
        for bone, items in tools.items():
            for j, (tool, a, b) in enumerate(items):
                cable = self.design.cable(tool.cable)
                if tool.kind == "channel":
                    if self.check_wall(tool, a, b, self.cable_key(cable),
                                       "fabrication.channel_diameter" if cable.kind == "tendon"
                                       else "fabrication.anchor_diameter", f"the channel of {cable.name!r}",
                                       sheathable=True):
                        sheathed.setdefault(bone, []).append((j, *sheath(self, tool, a, b)))
                else:
                    self.check_wall(tool, a, b, self.cable_key(cable), "fabrication.anchor_diameter",
                                    f"the anchor hole of {cable.name!r}")
            self.check_apart(bone, [t for t, _, _ in items])
        out = {bone: [t for t, _, _ in items] for bone, items in tools.items()}
        for bone, swaps in sheathed.items():
            for j, cover, channel in swaps:
                out[bone][j] = channel
            out[bone] += [cover for _, cover, _ in swaps]
        self.spool = spool
        return out

    def anchor(self, bone: str, cable: str, point: np.ndarray):
        """A hole through the bone along the mould's normal, through the ligament's end point."""
        surface, n = self.bones[bone], self.frame.n
        ends = []
        for sign in (1.0, -1.0):
            r, t, k = ray_hits(point, sign * n, surface.corners, self.tol)
            t, k = t[t > self.tol], k[t > self.tol]
            if not len(t):
                raise FabricationError(f"cables.{cable}.path", f"its end in bone {bone!r} is not inside it")
            ends.append({"at": "face", "point": point + sign * t[0] * n, "face": int(surface.faces[k[0]]),
                         "sin": float(abs(surface.normals[k[0]] @ n))})
        a, b = ends[1], ends[0]
        tool = Tool("anchor", np.vstack([a["point"], point, b["point"]]), self.r_anchor, bone, cable,
                    extend=(self.r_anchor + 0.5, self.r_anchor + 0.5))
        return tool, a, b

    def spool_end(self, cable, pts: np.ndarray, in_bone: dict) -> dict:
        """The tendon's end toward the spool (its first point unless that lies in a bone) and its way out."""
        key = self.cable_key(cable)
        if 0 in in_bone and len(pts) - 1 in in_bone:
            raise FabricationError(key, f"both ends lie in bones ({in_bone[0]!r}, {in_bone[len(pts) - 1]!r}); "
                                        "a tendon needs one end that leaves the body for its spool")
        i, j = (0, 1) if 0 not in in_bone else (len(pts) - 1, len(pts) - 2)
        p, d = pts[i], (pts[i] - pts[j]) / np.linalg.norm(pts[i] - pts[j])
        back = min(self.r_channel, 0.5 * float(np.linalg.norm(pts[i] - pts[j])))
        origin = p - back * d
        _, t, _ = ray_hits(origin, d, self.body.corners, self.tol)
        t = t[t > self.tol]
        if not len(t):
            raise FabricationError(key, f"its end at {where_text(p)} does not lead out of the body")
        leave = float(t[0])
        for bone, surface in self.bones.items():
            _, tb, _ = ray_hits(origin, d, surface.corners, self.tol)
            if np.any((tb > self.tol) & (tb < leave)):
                raise FabricationError(key, f"its end at {where_text(p)} runs into bone {bone!r} on its way out of the "
                                            "body (a tendon leaves the body straight on from its spool end)")
        if len(t) > 1:
            raise FabricationError(key, f"straight on from its end at {where_text(p)} the tendon would re-enter the "
                                        "body; route its spool end to the surface")
        return {"point": p, "direction": d, "origin": origin, "leave": origin + leave * d}

    def check_depth(self, tools: dict) -> None:
        """2D: a bone must be deep enough for a channel in its mid-plane."""
        if self.dim != 2 or not any(t.kind == "channel" for items in tools.values() for t, _, _ in items):
            return
        r = max(t.radius for items in tools.values() for t, _, _ in items if t.kind == "channel")
        need = 2 * (r + self.wall)
        if self.spec.bone_depth < need - 1e-9:
            raise FabricationError("fabrication.bone_depth", f"{self.spec.bone_depth:g} mm is too thin for the "
                                                             f"bones' channels: a {2 * r:g} mm channel with min_wall "
                                                             f"{self.wall:g} mm needs {need:g} mm")

    def check_apart(self, bone: str, tools: list) -> None:
        """Channels and holes of different cables in one bone must not meet."""
        from scipy.spatial import cKDTree
        for i, a in enumerate(tools):
            pa, _ = path_samples(a.points, 0.1)
            tree = cKDTree(pa)
            for b in tools[:i]:
                if b.cable == a.cable:
                    continue
                pb, _ = path_samples(b.points, 0.1)
                gap = float(tree.query(pb)[0].min())      # sampled every 0.1 mm: within 0.05 mm
                need = a.radius + b.radius + self.wall
                if gap < need - 0.05:
                    raise FabricationError(f"cables.{a.cable}.path", f"its {a.kind} in bone {bone!r} comes within "
                                                                     f"{gap:.2f} mm of the {b.kind} of {b.cable!r} "
                                                                     f"(axes {need:g} mm apart are needed)")

    # -- the mould's block
    def block(self) -> None:
        f = self.frame
        y = f.local(self.body.points)
        lo, hi = y.min(axis=0), y.max(axis=0)
        if not (lo[2] + self.tol < f.c < hi[2] - self.tol):
            raise FabricationError("fabrication.split.point", f"the parting plane n.x = {f.c:g} does not cut the body "
                                                             f"(it spans {lo[2]:.3g} to {hi[2]:.3g} along the normal)")
        w = self.spec.wall
        f.lo, f.hi = lo - w, hi + w
        if self.spec.split_point is None:
            f.c = casting.least_undercut(self)

    def column(self, uv: np.ndarray, surfaces: list[Surface]) -> list:
        """For lines along n through the points uv (q, 2) of the plane: the n-coordinates where each
        line crosses each surface (a list per surface of q sorted arrays)."""
        f = self.frame
        origins = f.world(np.column_stack([uv, np.full(len(uv), f.lo[2] - 1.0)]))
        out = []
        for s in surfaces:
            r, t, _ = ray_hits(origins, f.n, s.corners, self.tol)
            split = np.searchsorted(r, np.arange(len(uv) + 1))
            out.append([f.lo[2] - 1.0 + t[split[i]:split[i + 1]] for i in range(len(uv))])
        return out

    @staticmethod
    def ring(center: np.ndarray, radius: float, count: int = 8) -> np.ndarray:
        """count points around center whose polygon contains the circle of the given radius."""
        a = 2 * np.pi * np.arange(count) / count
        return center + radius / math.cos(math.pi / count) * np.column_stack([np.cos(a), np.sin(a)])

    def grid(self, uv_points: np.ndarray, target: int, margin: float = 0.0) -> np.ndarray:
        return self.lattice(uv_points, target, margin)[0]

    @staticmethod
    def lattice(uv_points: np.ndarray, target: int, margin: float = 0.0) -> tuple[np.ndarray, tuple, float]:
        """About target points on a square grid over the points' box (less margin): (points (q, 2) in
        row-major order, the grid's shape, its spacing)."""
        lo, hi = uv_points.min(axis=0) + margin, uv_points.max(axis=0) - margin
        if np.any(hi <= lo):
            return np.zeros((0, 2)), (0, 0), 0.0
        h = math.sqrt(float(np.prod(hi - lo)) / target)
        axes = [np.arange(a + 0.5 * ((b - a) % h), b + 1e-12, h) if b - a > h else np.array([(a + b) / 2])
                for a, b in zip(lo, hi)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 2), (len(axes[0]), len(axes[1])), h

    # -- pegs and sockets
    def pegs(self, bone_tools: dict) -> list:
        """Up to two pegs per bone from each half, along the mould's normal (so that they pull out).

        A site (u, v) on side s (+1: top half, -1: bottom) is taken where the
        line along n leaves the bone at E (its last crossing toward s) and:
        the bone is flat enough there for a socket (a ring of radius socket +
        min_wall crosses it within socket_depth/2 of E, with 2 socket_depth +
        min_wall of bone beneath, room for a socket from the other side too);
        nothing of the bone, of another bone, or of the body after it leaves
        it, lies in the peg's column beyond E (a ring of radius peg +
        clearance); the body is left on the peg's own side of the parting
        plane; the column keeps clear of every cable, and the socket of every
        channel and anchor hole. The peg's tip stops clearance short of the
        socket's bottom, and clearance separates it from the socket's wall.
        """
        from scipy.spatial import cKDTree
        spec, f = self.spec, self.frame
        self.shallow = []
        cable_pts = [path_samples(self.cable_points(c), 0.2)[0] for c in self.design.cables]
        cable_tree = cKDTree(np.concatenate(cable_pts)) if cable_pts else None
        pegs = []
        for bone in self.design.bones:
            surface = self.bones[bone.name]
            others = [s for name, s in self.bones.items() if name != bone.name]
            holes = [t for t in bone_tools[bone.name]]
            hole_pts = [path_samples(t.points, 0.2)[0] for t in holes]
            hole_r = np.concatenate([np.full(len(p), t.radius) for p, t in zip(hole_pts, holes)]) if holes else None
            hole_tree = cKDTree(np.concatenate(hole_pts)) if holes else None
            sites = self.grid(f.local(surface.points)[:, :2], 150, margin=self.r_socket + self.wall)
            if not len(sites):
                continue
            ring_s = np.stack([self.ring(p, self.r_socket + self.wall) for p in sites])
            ring_p = np.stack([self.ring(p, self.r_peg + spec.clearance) for p in sites])
            lines = np.concatenate([sites, ring_s.reshape(-1, 2), ring_p.reshape(-1, 2)])
            hits = self.column(lines, [surface, self.body] + others)
            q = len(sites)
            for h in (spec.socket_depth, spec.socket_depth / 2):     # half as deep where the full depth finds none
                found = []
                for side in (-1, 1):
                    ok = []
                    for i in range(q):
                        site = self._peg_site(i, q, side, hits, h)
                        if site is None:
                            continue
                        e, leave = site
                        tip = e - side * (h - spec.clearance)
                        axis = f.world([[*sites[i], tip], [*sites[i], leave]])
                        sock = f.world([[*sites[i], e], [*sites[i], e - side * h]])
                        if cable_tree is not None:
                            near = cable_tree.query(path_samples(axis, 0.2)[0])[0].min()
                            if near < self.r_peg + self.r_channel + self.wall:
                                continue
                        if hole_tree is not None:
                            d, j = hole_tree.query(path_samples(sock, 0.2)[0])
                            if np.any(d < self.r_socket + hole_r[j] + self.wall):
                                continue
                        ok.append((sites[i], e, tip, leave))
                    found += [(side, *x) for x in self._spread(ok, 2)]
                if found:
                    break
            if found and h < spec.socket_depth:
                self.shallow.append(bone.name)
            for side, site, e, tip, leave in found:
                far = leave + side * spec.wall / 2          # into the half's material beyond the body
                peg = Tool("peg", f.world([[*site, tip], [*site, far]]), self.r_peg, bone.name,
                           side="top" if side > 0 else "bottom")
                sock = Tool("socket", f.world([[*site, e + side * h], [*site, e - side * h]]), self.r_socket,
                            bone.name)
                pegs.append(peg)
                bone_tools[bone.name].append(sock)
        return pegs

    def _peg_site(self, i, q, side, hits, h):
        """(E, n where the peg leaves the body) for site i on side, or None; see pegs()."""
        mine, body, others = hits[0], hits[1], hits[2:]
        rs = range(q + 8 * i, q + 8 * i + 8)
        rp = range(9 * q + 8 * i, 9 * q + 8 * i + 8)
        ax = mine[i]
        if len(ax) < 2:
            return None
        e = ax[-1] if side > 0 else ax[0]
        beneath = (ax[-1] - ax[-2]) if side > 0 else (ax[1] - ax[0])
        if beneath < 2 * h + self.wall:                 # room for a socket from the other side too
            return None
        for j in rs:
            if not len(mine[j]):
                return None
            ej = mine[j][-1] if side > 0 else mine[j][0]
            if side * (ej - e) < -h / 2 or side * (ej - e) > h:
                return None
        leave = None
        for j in [i, *rp]:
            # bone beyond E within the peg's radius (a face not normal to n) is cut away by the socket,
            # which starts socket_depth beyond E: up to half that is accepted
            if len(mine[j]) and side * ((mine[j][-1] if side > 0 else mine[j][0]) - e) > h / 2:
                return None
            beyond = body[j][side * (body[j] - e) > self.tol]
            if len(beyond) != 1:
                return None                  # leaves the body more than once, or never
            if side * (beyond[0] - self.frame.c) < 0:
                return None                  # leaves the body in the other half
            if any(np.any(side * (o[j] - e) > -h - self.tol) for o in others):
                return None
            if j == i:
                leave = float(beyond[0])
        return e, leave

    @staticmethod
    def _spread(items: list, count: int) -> list:
        """Up to count items far apart: the one farthest from their centre, then the farthest from it."""
        if len(items) <= 1:
            return items
        uv = np.array([it[0] for it in items])
        first = int(np.argmax(np.linalg.norm(uv - uv.mean(axis=0), axis=1)))
        second = int(np.argmax(np.linalg.norm(uv - uv[first], axis=1)))
        return [items[first], items[second]][:count]

    # -- pour hole, vents, pins, exits
    def pins(self) -> list:
        """Four registration pins at the block's corners (radius wall/4, height wall/2) and their holes."""
        f, w, c = self.frame, self.spec.wall, self.spec.clearance
        r, h = w / 4, w / 2
        tools = []
        for a in (f.lo[0] + w / 2, f.hi[0] - w / 2):
            for b in (f.lo[1] + w / 2, f.hi[1] - w / 2):
                tools.append(Tool("pin", f.world([[a, b, f.c - 1.0], [a, b, f.c + h]]), r))
                tools.append(Tool("pin_hole", f.world([[a, b, f.c - 1.0], [a, b, f.c + h + c]]), r + c))
        return tools

    def pry_slots(self, exits: list) -> list:
        """A pry slot on each of the block's two longer sides: a round hole across the parting plane, half
        in each half, wall/2 deep into the wall (a flat blade in it levers the halves apart); at the side's
        middle, or a quarter along where a tendon exit is in the way."""
        f, w = self.frame, self.spec.wall
        r = min(w / 4, 2.0)
        depth = w / 2
        k = int(np.argmax(f.hi[:2] - f.lo[:2]))          # along the longer in-plane axis
        other = 1 - k
        away = [f.local(t.points[-1]) for t in exits]
        tools = []
        for face, inward in ((f.lo[other], 1.0), (f.hi[other], -1.0)):
            for frac in (0.5, 0.25, 0.75):
                along = f.lo[k] + frac * (f.hi[k] - f.lo[k])
                a, b = np.zeros(3), np.zeros(3)
                a[k] = b[k] = along
                a[other], b[other] = face - inward * 1.0, face + inward * depth
                a[2] = b[2] = f.c
                if all(np.linalg.norm((y - a)[[k, 2]]) > r + self.r_channel + self.wall for y in away):
                    tools.append(Tool("pry", f.world([a, b]), r))
                    break
        return tools

    def exits(self) -> list:
        """A channel through the mould wall where each tendon leaves the body toward its spool."""
        tools = []
        for name, s in self.spool.items():
            d = s["direction"]
            end = s["origin"] + (self.frame.reach(s["origin"], d) + 1.0) * d
            tools.append(Tool("exit", np.vstack([s["origin"], end]),
                              self.r_channel, cable=name))
        return tools


def plan(design) -> Plan:
    """Check a design for fabrication and plan every part; raises FabricationError (key, message)."""
    from ..design.sections import MAX_PRINT, MIN_PRINT, fabrication_bounds, fabrication_extent
    from ..runtime.interrupts import interruptible

    spec = design.fabrication
    if len(design.bodies) > 1:
        raise FabricationError("bodies", f"fabrication casts one body; this design has {len(design.bodies)} "
                                         "(fabricate each from a design of its own)")
    extent = fabrication_extent(design)          # every bound before Gmsh, which ignores signals
    if not MIN_PRINT <= float(extent.max()) <= MAX_PRINT:
        raise FabricationError("body", f"the body's largest extent ({float(extent.max()):.3g} mm) must lie in "
                                       f"[{MIN_PRINT:g}, {MAX_PRINT:g}] mm to print its mould")
    for key, message in fabrication_bounds(spec, extent):
        raise FabricationError(f"fabrication.{key}", message + " (the default for this body; set it)")
    scale, body_volume, bone_volumes, body, bones = interruptible(_probe, design, spec)   # Gmsh ignores signals
    planner = _Planner(design, body, bones, scale)
    planner.block()
    bone_tools = planner.route()
    pegs = planner.pegs(bone_tools)
    holder = RouteHolder(design, spec, planner.frame, body, bones, scale)
    posts, routes = holder.hold(pegs)
    check_apart(holder)
    openings, flow, notes = casting.openings(planner, pegs + posts)
    flow["air_under_bones"], more = casting.ceilings(planner)
    flow["undercut"], most = casting.undercuts(planner)
    exits = planner.exits()
    rod_holes = [Tool("rod_hole", t.points, t.radius + spec.clearance, cable=t.cable) for t in posts if t.kind == "rod"]
    mould = openings + planner.pins() + exits + planner.pry_slots(exits) + rod_holes
    bolts, more_notes = casting.clamps(planner, [t for t in mould if t.kind in ("pin_hole", "exit", "pry", "rod_hole")])
    mould += bolts
    notes += more_notes
    p = Plan(design, spec, planner.frame, scale, bone_tools, pegs, mould, body_volume, bone_volumes,
             notes + more + most, body_surface=body, bone_surfaces=bones, posts=posts, routes=routes, flow=flow)
    if planner.shallow:
        p.notes.append(f"the pegs enter bone(s) {', '.join(planner.shallow)} only {spec.socket_depth / 2:g} mm "
                       f"(half of fabrication.socket_depth: no room for {spec.socket_depth:g} mm)")
    for t in posts:
        if 2 * t.radius < spec.post_diameter - 1e-9:
            what = "guide post" if t.kind == "post" else "removable rod"
            p.notes.append(f"the {what} of cable {t.cable!r} at {where_text(t.points[0])} is only "
                           f"{2 * t.radius:.2g} mm thick (fabrication.post_diameter finds no room, or holds the bend "
                           f"further than route_tolerance from its sketch): print the mould finely, or soften the "
                           "cable's bend")
    for bone, items in bone_tools.items():
        for t in items:
            if t.kind == "sheath":
                p.notes.append(f"bone {bone!r} carries a printed sheath round the channel of {t.cable!r} from "
                               f"{where_text(t.points[0])} to {where_text(t.points[-1])}: the channel would open "
                               "the bone's side; the simulation does not model the sheath")
    unheld = [b.name for b in design.bones if not any(t.bone == b.name for t in pegs)]
    if unheld:
        p.notes.append(f"no peg can reach bone(s) {', '.join(unheld)} along the mould's normal; "
                       "they are not fixtured")
    return p


def _probe(design, spec):
    """The design's solids in OCC, meshed coarsely: (scale, body volume, bone volumes, body surface,
    bone surfaces)."""
    from ..runtime.interrupts import import_gmsh
    gmsh = import_gmsh()

    from ..design.occ import gmsh_model
    from ..mesh.geometry import add_design_solids
    with gmsh_model("skelfem-fabricate-probe"):
        occ = gmsh.model.occ
        body_tags, bone_tags = add_design_solids(occ, design, spec.bone_depth or None)
        occ.synchronize()
        box = np.array([occ.getBoundingBox(3, t) for t in body_tags]).reshape(-1, 2, 3)
        scale = float((box[:, 1].max(axis=0) - box[:, 0].min(axis=0)).max())
        body_volume = float(sum(occ.getMass(3, t) for t in body_tags))
        bone_volumes = {name: float(sum(occ.getMass(3, t) for t in tags)) for name, tags in bone_tags.items()}
        generate_surface_mesh(gmsh, scale / 8, PROBE_CURVATURE)
        body = triangle_surface(gmsh, body_tags)
        bones = {name: triangle_surface(gmsh, tags) for name, tags in bone_tags.items()}
    return scale, body_volume, bone_volumes, body, bones
