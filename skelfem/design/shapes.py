"""Materials, the body (2D outline or 3D solids) and the bones, and the 2D layout checks between them.
"""
from __future__ import annotations

import math

import numpy as np

from . import polygons
from .spec import Body, Bone, DesignError, MAX_COORDINATE, MAX_NAME, Material, PRIMITIVES
from .pose import MAX_ANGLE as POSE_MAX_ANGLE
from .table import MATERIAL_PAIR, Table, convert_value, entry_name, memoised, positive


def _polygon(t: Table, name: str, pts: np.ndarray, tol: float) -> np.ndarray:
    if len(pts) < 3:
        t.fail(name, "a polygon needs at least 3 points")
    memoised("polygon", [pts], tol, lambda: _polygon_shape(t, name, pts, tol))
    return pts


def _polygon_shape(t: Table, name: str, pts: np.ndarray, tol: float) -> bool:
    if np.any(np.linalg.norm(pts - np.roll(pts, -1, axis=0), axis=1) <= tol):
        t.fail(name, "repeated consecutive points (degenerate polygon)")
    if np.ptp(pts, axis=0).min() <= tol:
        t.fail(name, "polygon has zero area (degenerate)")
    if not polygons.is_simple(pts, tol):
        t.fail(name, "polygon is not simple (edges cross or touch)")
    if abs(polygons.signed_area(pts)) <= tol * np.ptp(pts, axis=0).max():
        t.fail(name, "polygon has zero area (degenerate)")
    return True


class _Region2D:
    """The body's closed region: inside the outline and outside every hole (loops: several bodies' loops,
    apart from each other, for the region of them all)."""

    def __init__(self, outline, holes, tol, loops=None):
        self.outline, self.holes, self.tol = outline, holes, tol
        self.loops = [outline, *holes] if loops is None else list(loops)

    def contains(self, points: np.ndarray) -> np.ndarray:
        # holes lie strictly inside the outline and apart: the even-odd rule over all loops
        return polygons.region_contains(self.loops, np.atleast_2d(points), self.tol)

    def contains_path(self, path: np.ndarray) -> bool:
        return memoised("path", [*self.loops, path], self.tol, lambda: bool(
            np.all(self.contains(polygons.polyline_samples(path, self.loops, self.tol)))))


def _layout_2d(body_t: "Table", region: _Region2D, bone_tables: list, bone_outlines: list) -> None:
    loops = [region.outline, *region.holes, *bone_outlines]
    memoised(f"layout{len(region.holes)}", loops, region.tol,
          lambda: _check_layout_2d(body_t, region, bone_tables, bone_outlines))


def _check_layout_2d(body_t: "Table", region: _Region2D, bone_tables: list, bone_outlines: list) -> bool:
    """Holes strictly inside the outline and apart; bones strictly inside the body, apart.

    All boundaries are intersected at once (polygons.meeting_loops); loops
    that do not meet are nested or apart, which one vertex decides.
    """
    outline, holes, tol = region.outline, region.holes, region.tol
    loops = [outline, *holes, *bone_outlines]
    nh = len(holes)
    meets = polygons.meeting_loops(loops, tol)
    firsts = np.array([loop[0] for loop in loops])
    in_outline = polygons.parity(firsts, [outline])

    boxes = np.array([np.r_[loop.min(axis=0) - tol, loop.max(axis=0) + tol] for loop in loops])
    nested: set = set()                             # (i, j): loop i's first vertex lies inside loop j
    candidates: dict = {}
    for I, J in polygons.candidate_pairs(boxes[1:]):
        for i, j in zip((I + 1).tolist(), (J + 1).tolist()):
            candidates.setdefault(j, []).append(i)
            candidates.setdefault(i, []).append(j)
    for j, inner in candidates.items():
        inner = sorted(set(inner))
        hit = polygons.parity(firsts[inner], [loops[j]])
        nested.update((i, j) for i, h in zip(inner, hit) if h)

    def overlapping(i, j):
        a, b = min(i, j), max(i, j)
        return (a, b) in meets or (i, j) in nested or (j, i) in nested

    for k in range(nh):
        i = 1 + k
        if (0, i) in meets or not in_outline[i]:
            body_t.fail(f"holes[{k}]", "a hole must lie strictly inside the outline")
        for m in range(k):
            if overlapping(i, 1 + m):
                body_t.fail(f"holes[{k}]", f"overlaps holes[{m}]")
    for k, t in enumerate(bone_tables):
        i = 1 + nh + k
        if (0, i) in meets or not in_outline[i]:
            t.fail("outline", "a bone must lie strictly inside the body outline")
        for m in range(nh):
            if overlapping(i, 1 + m):
                t.fail("outline", f"overlaps body.holes[{m}]")
        for m in range(k):
            if overlapping(i, 1 + nh + m):
                other = bone_tables[m].where.split(".", 1)[1]
                t.fail("outline", f"overlaps or touches bone {other!r}")
    return True


# -- sections -------------------------------------------------------------------------------------------
def named_entries(top: Table, section: str, required: bool = False) -> list[Table]:
    entries = top.take(section, "tables", default=None)
    if entries is None:
        if required:
            top.fail(section, "missing: at least one entry is required")
        return []
    if required and not entries:
        top.fail(section, "at least one entry is required")
    tables, seen = [], set()
    for i, e in enumerate(entries):
        name = e.get("name")
        label = name if isinstance(name, str) and 0 < len(name) <= MAX_NAME else str(i)   # a key of one line
        t = Table(e, f"{section}.{label}", top.source)
        name = entry_name(t, "name", t.take("name", "str"))
        if name in seen:
            t.fail("name", f"duplicate name {name!r} in {section}")
        seen.add(name)
        tables.append(t)
    return tables


MIN_E, MAX_E = 1e-6, 1e7      # MPa: Young's moduli from 1 Pa (softer than any gel) to 10 TPa (beyond diamond)


def read_materials(top: Table) -> dict:
    """[materials]: E within [MIN_E, MAX_E] MPa (E = 1e-300 beside a 20 N/mm tendon made Newton steps of
    1e300 mm, and the contact's collision detection on such a step did not answer SIGINT for minutes),
    nu in (-1, 0.5), density > 0."""
    mt = Table(top.take("materials", "table"), "materials", top.source)
    if not mt.data:
        mt.fail("", "at least one material is required")
    out = {}
    for name in list(mt.data):
        entry_name(mt, name, name, "a material name", also=MATERIAL_PAIR)
        t = Table(mt.take(name, "table"), f"materials.{name}", top.source)
        E = positive(t, "E", t.take("E", "number"))
        if not MIN_E <= E <= MAX_E:
            t.fail("E", f"must lie in [{MIN_E:g}, {MAX_E:g}] MPa (1 Pa to 10 TPa; check the units: MPa = N/mm^2), "
                        f"got {E:g}")
        nu = t.take("nu", "number")
        if not -1.0 < nu < 0.5:
            t.fail("nu", f"must lie in (-1, 0.5), got {nu:g}")
        density = t.take("density", "number", None)
        if density is not None:
            positive(t, "density", density)
        t.done()
        out[name] = Material(name, E, nu, density)
    return out


def _material_ref(t: Table, materials: dict) -> str:
    name = t.take("material", "str")
    if name not in materials:
        t.fail("material", f"unknown material {name!r} (defined: {', '.join(materials)})")
    return name


def _solid(t: Table, i: int, prim, dim: int, tol: float) -> dict:
    where = f"{t.where}.solids[{i}]"
    if not isinstance(prim, dict) or len(prim) != 1 or next(iter(prim)) not in PRIMITIVES:
        raise DesignError(f"{t.source}: {where}: must be one of "
                          + ", ".join(f"{{ {p} = {{...}} }}" for p in PRIMITIVES))
    (kind, params), = prim.items()
    p = Table(params, f"{where}.{kind}", t.source)
    if kind == "box":
        lo, hi = p.take("min", "point", dim=3), p.take("max", "point", dim=3)
        if np.any(hi - lo <= tol):
            p.fail("max", "must exceed min in every coordinate")
        out = {"min": lo, "max": hi}
    elif kind == "cylinder":
        a, b = p.take("from", "point", dim=3), p.take("to", "point", dim=3)
        if np.linalg.norm(b - a) <= tol:
            p.fail("to", "must differ from 'from'")
        out = {"from": a, "to": b, "radius": _small(p, "radius", p.take("radius", "number"), tol)}
    elif kind == "sphere":
        out = {"center": p.take("center", "point", dim=3),
               "radius": _small(p, "radius", p.take("radius", "number"), tol)}
    else:
        outline = _polygon(p, "outline", p.take("outline", "points", dim=2), tol)
        z = p.take("z", "point", dim=2)
        if z[1] - z[0] <= tol:
            p.fail("z", "must be [z0, z1] with z1 > z0")
        out = {"outline": outline, "z": z}
    p.done()
    return {kind: out}


def _small(t: Table, name: str, r: float, tol: float) -> float:
    positive(t, name, r)
    if r <= tol or r > MAX_COORDINATE:
        t.fail(name, f"must lie in ({tol:g}, {MAX_COORDINATE:g}] mm, got {r:g}")
    return r


def read_solids(t: Table, dim: int, tol: float) -> tuple:
    prims = t.take("solids", "list")
    if not prims:
        t.fail("solids", "at least one primitive is required")
    return tuple(_solid(t, i, p, dim, tol) for i, p in enumerate(prims))


def read_body(top: Table, dim: int, materials: dict):
    """[body], or [[bodies]] (2D): (bodies, the soft region, tol, [(body table, its region)])."""
    if top.has("bodies"):
        if top.has("body"):
            top.fail("bodies", "give either one [body] or [[bodies]], not both")
        return _read_bodies(top, dim, materials)
    t = Table(top.take("body", "table"), "body", top.source)
    material = _material_ref(t, materials)
    if dim == 3:
        tol = 1e-9 * max(_extent(top.data), 1.0)
        body = Body(material, solids=read_solids(t, dim, tol))
        t.done()
        return (body,), None, tol, [(t, None)]
    outline = t.take("outline", "points", dim=2)
    tol = 1e-9 * max(float(np.ptp(outline, axis=0).max()) if len(outline) >= 1 else 1.0, 1.0)
    body, region = _outline_body(t, "body", material, outline, tol)
    return (body,), region, tol, [(t, region)]


def _outline_body(t: Table, name: str, material: str, outline, tol: float):
    outline = _polygon(t, "outline", outline, tol)
    holes = []
    for i, h in enumerate(t.take("holes", "list", default=[])):
        hname = f"holes[{i}]"
        holes.append(_polygon(t, hname, convert_value(h, "points", 2, lambda m: t.fail(hname, m)), tol))
    t.done()
    return Body(material, outline=outline, holes=tuple(holes), name=name), _Region2D(outline, holes, tol)


def _read_bodies(top: Table, dim: int, materials: dict):
    """[[bodies]]: several soft bodies, apart at rest (2D outlines, 3D solids)."""
    tables = named_entries(top, "bodies", required=True)
    if dim == 3:
        return _read_bodies_3d(tables, materials)
    outlines = [t.take("outline", "points", dim=2) for t in tables]
    sizes = [float(np.ptp(o, axis=0).max()) for o in outlines if len(o) >= 1]
    tol = 1e-9 * max(max(sizes, default=1.0), 1.0)
    bodies: list = []
    out: list = []
    for t, outline in zip(tables, outlines):
        material = _material_ref(t, materials)
        body, region = _outline_body(t, t.where.split(".", 1)[1], material, outline, tol)
        for other in bodies:
            if polygons.overlap(body.outline, other.outline, tol):
                t.fail("outline", f"overlaps or touches body {other.name!r} (bodies must start apart)")
        bodies.append(body)
        out.append((t, region))
    return tuple(bodies), _Region2D(None, (), tol, loops=polygons.loops_of(bodies)), tol, out


def _read_bodies_3d(tables: list, materials: dict):
    """[[bodies]] in 3D: each its solids; no two may overlap or touch (checked with OpenCASCADE)."""
    from .solids import touching
    tol = 1e-9 * max(max((_extent({"body": t.data}) for t in tables), default=1.0), 1.0)
    bodies: list = []
    out: list = []
    for t in tables:
        name = t.where.split(".", 1)[1]
        material = _material_ref(t, materials)
        body = Body(material, solids=read_solids(t, 3, tol), name=name)
        t.done()
        for other in bodies:
            how = touching(body.solids, other.solids, tol)
            if how:
                t.fail("solids", f"{how} body {other.name!r} (bodies must start apart)")
        bodies.append(body)
        out.append((t, None))
    return tuple(bodies), None, tol, out


def _extent(data: dict) -> float:
    """Size of the 3D body's primitives (for tolerances), from the raw table; 1 if unreadable."""
    try:
        pts = []
        for prim in data["body"]["solids"]:
            (kind, p), = prim.items()
            if kind == "box":
                pts += [p["min"], p["max"]]
            elif kind == "cylinder":
                pts += [p["from"], p["to"]]
            elif kind == "sphere":
                pts += [p["center"]]
            else:
                pts += [[x, y, z] for x, y in p["outline"] for z in p["z"]]
        a = np.asarray(pts, float)
        ext = float(np.ptp(a, axis=0).max())
        return ext if math.isfinite(ext) else 1.0
    except Exception:
        return 1.0


def read_pose(t: Table) -> dict | None:
    """A 3D bone's ``move`` and ``rotate`` as a pose dict, or None when it has neither."""
    move = t.take("move", "vector", None, dim=3) if t.has("move") else None
    angle, centre, axis = 0.0, None, None
    if t.has("rotate"):
        r = Table(t.take("rotate", "table"), t.key("rotate"), t.source)
        angle = float(r.take("angle", "number"))
        if abs(angle) > POSE_MAX_ANGLE:
            r.fail("angle", f"must lie within +-{POSE_MAX_ANGLE:g} degrees, got {angle:g}")
        if not r.has("centre"):
            r.fail("centre", "missing: a bone turns about a centre (a point)")
        centre = r.take("centre", "point", dim=3)
        axis = r.take("axis", "vector", dim=3)
        if not np.linalg.norm(axis) > 0:
            r.fail("axis", "must not be zero")
        axis = axis / np.linalg.norm(axis)
        r.done()
    if move is None and centre is None:
        return None
    return {"angle": angle, "axis": axis if axis is not None else np.array([0.0, 0.0, 1.0]),
            "centre": centre if centre is not None else np.zeros(3),
            "move": move if move is not None else np.zeros(3)}


def read_bones(top: Table, dim: int, materials: dict, tol, body_tables: list) -> tuple:
    """[[bones]]; in 2D each lies strictly inside one body (body_tables: [(table, region)] per body)."""
    bones, tables = [], []
    for t in named_entries(top, "bones"):
        name = t.where.split(".", 1)[1]
        material = _material_ref(t, materials)
        rigid = t.take("rigid", "bool", False)
        if dim == 3:
            from .pose import placed
            pose = read_pose(t)
            bones.append(Bone(name, material, solids=placed(read_solids(t, dim, tol), pose), rigid=rigid, pose=pose))
            t.done()
            continue
        outline = _polygon(t, "outline", t.take("outline", "points", dim=2), tol)
        t.done()
        bones.append(Bone(name, material, outline=outline, rigid=rigid))
        tables.append(t)
    if dim == 2:
        home = np.zeros(len(bones), int)           # the body around each bone's first vertex
        if len(body_tables) > 1:
            for k, b in enumerate(bones):
                assert b.outline is not None                # a 2D bone has one
                inside = [polygons.contains(r.outline, b.outline[:1], tol)[0] for _, r in body_tables]
                if not any(inside):
                    tables[k].fail("outline", "a bone must lie strictly inside one body's outline")
                home[k] = inside.index(True)
        for j, (body_t, region) in enumerate(body_tables):
            mine = np.flatnonzero(home == j)
            _layout_2d(body_t, region, [tables[k] for k in mine], [bones[k].outline for k in mine])
    return tuple(bones)


def check_inside(t: Table, key: str, points: np.ndarray, region, what: str) -> None:
    if region is not None and not np.all(region.contains(np.atleast_2d(points))):
        t.fail(key, f"{what} lies outside the body")


