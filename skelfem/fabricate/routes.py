"""Cable routes held while the silicone is cast: guide posts at bends in silicone, and the route check.

A taut line runs straight between the points that hold it. In the mould
those are the bones' channels (the line follows a channel: its ends at the
bone's faces, and every sketch point inside a bone, are held) and the cable's
own ends. Where a sketch bends in silicone nothing holds it, and the cast
line cuts the corner: on finger.toml the flexor's bend before the distal bone.

So each bend in silicone gets a **guide post**: a cylinder of
``post_diameter`` (down to 0.3 of it, at least MIN_POST, where the full one finds no room or
holds a sharp bend too far from its sketch)
standing on the mould's wall along the mould's normal n (so
that it pulls out with its half) and reaching past the cable, placed on the
inner side of the bend. A line of radius r_c pulled round a post of radius
r_p follows both straight sketch segments up to their tangent points and an
arc of radius rho = r_p + r_c between them; the post's axis lies on the
bend's inner bisector at rho / sin(theta/2) from the bend point B (theta the
angle between the two segments at B). The cast line then misses B by

    rho (1 / sin(theta/2) - 1)

and follows the sketch elsewhere. The line's radius is taken as its
channel's (the thickest line that runs in it: the conservative choice).

The check: the route as cast (straight between holds, round each post) is
sampled, and its largest distance from the sketch, and the sketch's from it
(both ways: a Hausdorff distance), must be at most ``route_tolerance``
(0.3 mm by default). Posts are placed only for a cable whose line, held by
the bones alone, strays further. A route that cannot be held so is refused,
naming the cable and the point, with the reason of the bend nearest it: a
bend turning toward n (a post along n cannot hold it), a post that would
meet a bone, another cable or a peg, or a bend too sharp for the
tolerance. The posts leave holes in the silicone, filled after
demoulding like the pegs'.
"""
from __future__ import annotations

import math

import numpy as np
from .parts import Frame, Tool, cable_points, cable_radius, where_text
from .surfaces import FabricationError, Surface, inside, point_triangle_distance, ray_hits

MAX_TILT = math.radians(20)       # a bend's inner bisector at most this far out of the plane normal to n
ARC_STEP = math.radians(2)        # the arc round a post, sampled (chords: rho (1 - cos 1 deg) inside it)
POST_SCALES = (1.0, 0.75, 0.5, 0.4, 0.3)    # of post_diameter: a post that finds no room is tried thinner
MIN_POST = 0.6                    # mm: no thinner post (a printed pin this thin breaks off)


def segment_distance(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Distance of each point (k, 3) to a polyline (m, 3)."""
    a, b = poly[:-1], poly[1:]
    d = b - a
    L2 = np.maximum(np.einsum("ij,ij->i", d, d), 1e-300)
    t = np.clip(np.einsum("kij,ij->ki", points[:, None, :] - a[None], d) / L2, 0.0, 1.0)
    foot = a[None] + t[..., None] * d[None]
    return np.linalg.norm(points[:, None, :] - foot, axis=2).min(axis=1)


def dense(poly: np.ndarray, step: float) -> np.ndarray:
    out = [poly[:1]]
    for a, b in zip(poly[:-1], poly[1:]):
        k = max(1, int(math.ceil(np.linalg.norm(b - a) / step)))
        out.append(a + (np.arange(1, k + 1) / k)[:, None] * (b - a))
    return np.concatenate(out)


def hausdorff(sketch: np.ndarray, cast: np.ndarray, step: float) -> tuple[float, np.ndarray]:
    """(largest distance between the two polylines, both ways; the sketch or cast point where it is)."""
    s, c = dense(sketch, step), dense(cast, step)
    ds, dc = segment_distance(s, cast), segment_distance(c, sketch)
    i, j = int(np.argmax(ds)), int(np.argmax(dc))
    return (float(ds[i]), s[i]) if ds[i] >= dc[j] else (float(dc[j]), c[j])


def bend(p: np.ndarray, i: int) -> tuple[float, np.ndarray]:
    """(theta: the angle at sketch point i between its two segments, pi for straight on; the unit inner
    bisector)."""
    d1 = (p[i - 1] - p[i]) / np.linalg.norm(p[i - 1] - p[i])
    d2 = (p[i + 1] - p[i]) / np.linalg.norm(p[i + 1] - p[i])
    theta = math.acos(float(np.clip(d1 @ d2, -1.0, 1.0)))
    b = d1 + d2
    return theta, b / max(float(np.linalg.norm(b)), 1e-300)


def wrap(p: np.ndarray, i: int, rho: float) -> np.ndarray:
    """The line round a post at bend i: tangent point, arc samples, tangent point."""
    theta, b = bend(p, i)
    centre = p[i] + b * rho / math.sin(theta / 2)
    t1 = p[i] + (p[i - 1] - p[i]) / np.linalg.norm(p[i - 1] - p[i]) * rho / math.tan(theta / 2)
    t2 = p[i] + (p[i + 1] - p[i]) / np.linalg.norm(p[i + 1] - p[i]) * rho / math.tan(theta / 2)
    u, v = t1 - centre, t2 - centre
    sweep = math.pi - theta
    k = max(2, int(math.ceil(sweep / ARC_STEP)))
    w = v - (v @ u) / (u @ u) * u                       # in the arc's plane, normal to u
    w = w / max(float(np.linalg.norm(w)), 1e-300) * rho
    a = np.linspace(0.0, sweep, k + 1)
    return centre + np.cos(a)[:, None] * u + np.sin(a)[:, None] * w


def cast_route(p: np.ndarray, held: np.ndarray, posts: dict) -> np.ndarray:
    """The line as cast: straight between held points (held: a mask over the sketch points, in bones or
    ends) and crossings (already sketch points), round the posts (sketch index -> rho, the post's radius
    plus the line's)."""
    out = []
    for i in range(len(p)):
        if held[i]:
            out.append(p[i:i + 1])
        elif i in posts:
            out.append(wrap(p, i, posts[i]))
    return np.concatenate(out)


class RouteHolder:
    """Posts for one design's cables and the route report; see the module doc."""

    def __init__(self, design, spec, frame: Frame, body: Surface, bones: dict, scale: float):
        self.design, self.spec, self.frame = design, spec, frame
        self.body, self.bones, self.scale = body, bones, scale
        self.tol = 1e-7 * scale
        self.r_post = spec.post_diameter / 2

    def points(self, cable) -> np.ndarray:
        """The sketch in 3D, with a point added wherever it crosses a bone's surface (held there)."""
        p = cable_points(self.design, cable)
        out = [p[:1]]
        for a, b in zip(p[:-1], p[1:]):
            L = float(np.linalg.norm(b - a))
            d = (b - a) / L
            ts = []
            for s in self.bones.values():
                _, t, _ = ray_hits(a, d, s.corners, self.tol)
                ts += [float(x) for x in t if self.tol < x < L - self.tol]
            for t in sorted(ts):
                out.append((a + t * d)[None])
            out.append(b[None])
        return np.concatenate(out)

    def in_bone(self, x: np.ndarray) -> np.ndarray:
        if not self.bones:
            return np.zeros(len(x), bool)
        return np.any([inside(x, s, self.tol) for s in self.bones.values()], axis=0)

    def hold(self, pegs: list) -> tuple[list[Tool], dict]:
        """(posts as Tools of kind "post", {cable: route report}); raises FabricationError for a route
        that cannot be held within route_tolerance."""
        spec = self.spec
        posts, report = [], {}
        for cable in self.design.cables:
            r_c = cable_radius(spec, cable)
            p = self.points(cable)
            mids = 0.5 * (p[:-1] + p[1:])
            inner = self.in_bone(mids)                  # which pieces run in bones
            held = np.zeros(len(p), bool)
            held[[0, -1]] = True
            held[:-1] |= inner
            held[1:] |= inner
            free = [i for i in range(1, len(p) - 1) if not held[i] and bend(p, i)[0] < math.pi - 1e-9]
            dev0, where0 = hausdorff(p, cast_route(p, held, {}), min(0.1, self.r_post / 4))
            posted, failed = {}, {}
            if dev0 > spec.route_tolerance:            # held by the bones alone it strays: posts at the bends
                for i in free:
                    try:
                        posted[i] = self.post(cable, p, i, r_c, pegs)
                    except FabricationError as exc:
                        failed[i] = exc.message
            dev, where = hausdorff(p, cast_route(p, held, {i: t.radius + r_c for i, t in posted.items()}),
                                   min(0.1, self.r_post / 4))
            if dev > spec.route_tolerance:
                near = min(failed, key=lambda i: float(np.linalg.norm(p[i] - where)), default=None)
                why = (failed[near] if near is not None else "even round a guide post; soften the bend or raise "
                       "fabrication.route_tolerance")
                raise FabricationError(f"cables.{cable.name}.path",
                                       f"cast, its line would lie {dev:.2g} mm off its sketch near {where_text(where)} "
                                       f"(fabrication.route_tolerance {spec.route_tolerance:g} mm): {why}")
            report[cable.name] = {"deviation": dev, "unheld_deviation": dev0, "where_unheld": _plain(where0),
                                  "posts": [{"at": _plain(p[i]), "tip": _plain(t.points[0]), "diameter": 2 * t.radius,
                                             "angle_deg": math.degrees(bend(p, i)[0]), "half": t.side,
                                             "kind": t.kind} for i, t in posted.items()]}
            posts += posted.values()
        return posts, report

    def post(self, cable, p: np.ndarray, i: int, r_c: float, pegs: list) -> Tool:
        """The guide post holding bend i: from the mould's wall along n past the line, on the inner side;
        post_diameter, else (no room) thinner ones (POST_SCALES, not below MIN_POST)."""
        f = self.frame
        key = f"cables.{cable.name}.path"
        theta, b = bend(p, i)
        along = abs(float(b @ f.n)) <= math.sin(MAX_TILT)
        if along:
            b = b - (b @ f.n) * f.n
            b /= np.linalg.norm(b)
        sizes = [k * self.r_post for k in POST_SCALES if 2 * k * self.r_post >= MIN_POST]
        close = [r for r in sizes if (r + r_c) * (1 / math.sin(theta / 2) - 1) <= self.spec.route_tolerance]
        for r_p in close or sizes:                  # a post thin enough for the tolerance round a sharp bend
            axis = p[i] + b * (r_p + r_c) / math.sin(theta / 2)
            tool = (self.place(cable, axis, r_p, r_c, pegs) if along else None) or self.rod(cable, p, i, axis, r_p,
                                                                                         r_c, pegs)
            if tool is not None:
                return tool
        raise FabricationError(key, f"no guide post can hold its bend at {where_text(p[i])}: neither along the "
                                    "mould's normal nor as a removable rod across the bend is a column clear of "
                                    f"bones, pegs and other cables, even {MIN_POST:g} mm thin "
                                    f"(fabrication.post_diameter {self.spec.post_diameter:g} mm); move the bend, or "
                                    "put it inside a bone")

    def rod(self, cable, p: np.ndarray, i: int, axis: np.ndarray, r_p: float, r_c: float, pegs: list) -> Tool | None:
        """A removable rod of radius r_p square across the bend's plane through axis, pushed in through a hole
        in the mould's wall before the pour and pulled out before demoulding (so it may cross the parting
        plane): from whichever side its column leaves the body once and meets no bone, peg or other cable;
        None where neither does. Its points run from its tip (past the line) to the block's outside."""
        f, spec = self.frame, self.spec
        d1, d2 = p[i - 1] - p[i], p[i + 1] - p[i]
        across = np.cross(d1, d2)
        across /= np.linalg.norm(across)
        reach = r_p + r_c
        for d in (across, -across):
            tip, leave = self.clear_column(cable, axis, d, r_p, reach, pegs)
            if tip is None:
                continue
            return Tool("rod", np.array([tip, axis + (f.reach(axis, d) + spec.wall) * d]), r_p, cable=cable.name)
        return None

    def place(self, cable, axis: np.ndarray, r_p: float, r_c: float, pegs: list) -> Tool | None:
        """A post of radius r_p through axis (at the line's height), from the bottom half or else the top
        one; None where neither column is clear."""
        spec, f = self.spec, self.frame
        reach = r_p + r_c                             # past the line's axis: the line cannot slip off
        for side in (-1.0, 1.0):                      # the bottom half first
            d = side * f.n
            tip, leave = self.clear_column(cable, axis, d, r_p, reach, pegs)
            if tip is not None:
                return Tool("post", np.array([tip, leave + spec.wall / 2 * d]), r_p, cable=cable.name,
                            side="top" if side > 0 else "bottom")
        return None

    def clear_column(self, cable, axis: np.ndarray, d: np.ndarray, r_p: float, reach: float, pegs: list):
        """(tip, where it leaves the body) of a cylinder of radius r_p from reach before axis along d out of
        the body, or (None, None) where it leaves the body more than once or never, its tip is not in the
        body (the other side), or it comes near a bone, another cable or a peg."""
        _, t, _ = ray_hits(axis, d, self.body.corners, self.tol)
        t = t[t > self.tol]
        tip = axis - reach * d
        if len(t) != 1 or not inside(tip, self.body, self.tol)[0]:
            return None, None
        leave = axis + float(t[0]) * d
        column = dense(np.array([tip, leave]), 0.2)
        if self.in_bone(column).any() or (self.bones and min(
                float(point_triangle_distance(column, s.corners).min()) for s in self.bones.values())
                < r_p + self.spec.clearance):
            return None, None
        if self.too_near_cables(column, cable.name, r_p) or self.too_near_pegs(column, pegs, r_p):
            return None, None
        return tip, leave

    def too_near_cables(self, column: np.ndarray, name: str, r_p: float) -> bool:
        for other in self.design.cables:
            if other.name == name:
                continue
            r, q = cable_radius(self.spec, other), cable_points(self.design, other)
            if segment_distance(column, q).min() < r_p + r + self.spec.min_wall:
                return True
        return False

    def too_near_pegs(self, column: np.ndarray, pegs: list, r_p: float) -> bool:
        return any(segment_distance(column, t.points).min() < r_p + t.radius + self.spec.clearance
                   for t in pegs)


def segment_pair_distance(p0, p1, q0, q1) -> tuple[np.ndarray, np.ndarray]:
    """(distance, the point midway between the nearest points) of segments p0-p1 and q0-q1, rows of (n, 3)
    arrays: exact (the nearest points by Ericson's clamped solve; segments of positive length)."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a, e = np.einsum("ij,ij->i", d1, d1), np.einsum("ij,ij->i", d2, d2)
    b, c, f = np.einsum("ij,ij->i", d1, d2), np.einsum("ij,ij->i", d1, r), np.einsum("ij,ij->i", d2, r)
    den = a * e - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(den > 1e-12 * a * e, np.clip((b * f - c * e) / den, 0.0, 1.0), 0.0)
        t = (b * s + f) / e
        s = np.where(t < 0.0, np.clip(-c / a, 0.0, 1.0), np.where(t > 1.0, np.clip((b - c) / a, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    x, y = p0 + s[:, None] * d1, q0 + t[:, None] * d2
    return np.linalg.norm(x - y, axis=1), 0.5 * (x + y)


def check_apart(holder: RouteHolder) -> None:
    """Two cables' lines in the silicone neither cross nor come closer than their radii + fabrication.min_wall
    (the rule for their channels and holes in one bone, and for a guide post beside a cable); FabricationError
    naming the cable and where. Pieces in bones are left to the bones' own check (a ligament's sketch in its
    bone is no channel: only its anchor hole is)."""
    spec = holder.spec
    lines = []
    for cable in holder.design.cables:
        p = holder.points(cable)
        free = ~holder.in_bone(0.5 * (p[:-1] + p[1:]))
        lines.append((cable, p[:-1][free], p[1:][free]))
    for j, (b, b0, b1) in enumerate(lines):
        for a, a0, a1 in lines[:j]:
            if not len(a0) or not len(b0):
                continue
            i, k = (m.ravel() for m in np.meshgrid(np.arange(len(b0)), np.arange(len(a0)), indexing="ij"))
            d, at = segment_pair_distance(b0[i], b1[i], a0[k], a1[k])
            need = cable_radius(spec, a) + cable_radius(spec, b) + spec.min_wall
            worst = int(np.argmin(d))
            if d[worst] < need - holder.tol:
                how = "crosses" if d[worst] <= holder.tol else f"comes within {d[worst]:.2f} mm of"
                raise FabricationError(f"cables.{b.name}.path",
                                       f"its line in the silicone {how} the line of {a.name!r} near "
                                       f"{where_text(at[worst])} (their radii + fabrication.min_wall: axes {need:g} "
                                       "mm apart are needed)")


def _plain(x) -> list:
    return [round(float(v), 6) for v in np.ravel(x)]
