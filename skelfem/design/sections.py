"""One reader per design section besides the body and bones: cables, pins, loads, tractions, gravity, grounds,
markers, contact, solver, dynamics, fabrication.
"""
from __future__ import annotations

import math

import numpy as np

from . import polygons
from .objects import ObjectSpec, primitives_box
from .shapes import check_inside, named_entries
from .spec import (Body, CableSpec, ContactSpec, DesignError, DynamicsSpec, ENERGY_LINE_SEARCHES, FabricationSpec,
                   GroundSpec, INTEGRATORS, LINE_SEARCHES, LINEAR_SOLVERS, LoadSpec, MAX_COORDINATE, MAX_STEPS,
                   MAX_TIME_STEPS, PinSpec, SolverSpec, TractionSpec)
from .table import Table, entry_name, is_finite, is_number, positive, show_value


MAX_CABLE_FRICTION = 10.0     # mu; any bend with mu tan(theta / 2) >= 1 locks long before


def read_cables(top: Table, dim: int, region, tol, materials: tuple = ()) -> tuple:
    cables = []
    for t in named_entries(top, "cables"):
        name = t.where.split(".", 1)[1]
        kind = t.take("kind", "str")
        if kind not in ("tendon", "ligament"):
            t.fail("kind", f"must be \"tendon\" or \"ligament\", got {kind!r}")
        path = t.take("path", "points", dim=dim)
        if len(path) < 2:
            t.fail("path", "a cable path needs at least 2 points")
        seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
        if np.any(seg <= tol):
            t.fail("path", "repeated consecutive points (zero-length segment)")
        if region is not None and not region.contains_path(path):
            t.fail("path", "the cable leaves the body (it must run inside it or on its boundary)")
        k = positive(t, "stiffness", t.take("stiffness", "number"))
        contraction = pretension = 0.0
        if kind == "tendon":
            contraction = positive(t, "contraction", t.take("contraction", "number", 0.0), strict=False)
            if t.has("pretension"):
                t.fail("pretension", "only ligaments take a pretension (a tendon is shortened by contraction)")
        else:
            pretension = positive(t, "pretension", t.take("pretension", "number", 0.0), strict=False)
            if t.has("contraction"):
                t.fail("contraction", "ligaments are passive and never contracted (use pretension)")
        anchor = None
        if t.has("anchor_radius"):
            anchor = positive(t, "anchor_radius", t.take("anchor_radius", "number"), strict=False)
            if anchor >= seg.sum():
                t.fail("anchor_radius", f"must be smaller than the cable ({seg.sum():g} mm)")
        if max(contraction, pretension) >= seg.sum():
            t.fail("contraction" if kind == "tendon" else "pretension",
                   f"must be shorter than the cable ({seg.sum():g} mm)")
        schedule = None
        if t.has("schedule"):
            if kind != "tendon":
                t.fail("schedule", "ligaments are passive and never actuated (only tendons take a schedule)")
            schedule = _schedule(t, t.take("schedule", "list"), float(seg.sum()))
        friction, by_material = _cable_friction(t, materials)
        t.done()
        cables.append(CableSpec(name, kind, path, k, contraction, pretension, anchor, schedule, friction,
                                by_material))
    return tuple(cables)


def _cable_friction(t: Table, materials: tuple) -> tuple[float, tuple]:
    """friction = mu, or a table {material = mu} of the materials it runs through (body, bones; one not
    named: 0). Returns (mu, ()) or (0, ((material, mu), ...))."""
    def coefficient(key: str, value) -> float:
        if not is_number(value) or not is_finite(value):
            t.fail(key, f"must be a finite number, got {show_value(value)}")
        if not 0.0 <= value <= MAX_CABLE_FRICTION:
            t.fail(key, f"must lie in [0, {MAX_CABLE_FRICTION:g}] (a friction coefficient), got {value:g}")
        return float(value)
    if isinstance(t.data.get("friction"), dict):
        table = t.take("friction", "table")
        pairs = []
        for material, value in table.items():
            if material not in materials:
                t.fail(f"friction.{material}", f"is no material the cable can run through (the body's and the "
                                               f"bones': {', '.join(materials)})")
            pairs.append((material, coefficient(f"friction.{material}", value)))
        return 0.0, tuple(pairs)
    if not t.has("friction"):
        return 0.0, ()
    return coefficient("friction", t.data.pop("friction")), ()


def _schedule(t: Table, value: list, length: float) -> np.ndarray:
    """[[t0, u0], [t1, u1], ...]: times (s) >= 0 strictly increasing, contractions (mm) in [0, length)."""
    if not value:
        t.fail("schedule", "must be a non-empty list of [time, contraction] pairs")
    for i, row in enumerate(value):
        if not (isinstance(row, list) and len(row) == 2 and all(is_number(x) for x in row)):
            t.fail("schedule", f"entry {i} must be a [time, contraction] pair of numbers, got {show_value(row)}")
        if not all(is_finite(x) for x in row):
            t.fail("schedule", f"entry {i} must be finite, got {show_value(row)}")
    a = np.asarray(value, dtype=float)
    if a[0, 0] < 0:
        t.fail("schedule", f"times must be >= 0, got {a[0, 0]:g}")
    bad = np.flatnonzero(np.diff(a[:, 0]) <= 0)
    if len(bad):
        i = int(bad[0]) + 1
        t.fail("schedule", f"times must increase strictly: entry {i} (t = {a[i, 0]:g}) "
                           f"does not come after entry {i - 1} (t = {a[i - 1, 0]:g})")
    if np.any(a[:, 1] < 0):
        t.fail("schedule", f"contractions must be >= 0, got {a[:, 1].min():g}")
    if np.any(a[:, 1] >= length):
        t.fail("schedule", f"contractions must be shorter than the cable ({length:g} mm), got {a[:, 1].max():g}")
    return a


MIN_DT = 1e-15              # s: a femtosecond, below which no continuum model holds (and 1 / dt^2 overflows)
MIN_DT_WAVE = 1e-6          # dt is at least this share of the time an elastic wave crosses one element


def wave_time(materials: dict, used: list, h: float) -> float:
    """s: the shortest time an elastic (bar) wave takes to cross one element of size h (mm) in the used
    materials, h sqrt(rho / E) (rho converted from kg/m^3 to t/mm^3, E in MPa); inf if none has a density."""
    times = [h * math.sqrt(materials[m].density * 1e-12 / materials[m].E) for m in used
             if materials[m].density is not None]
    return min(times, default=math.inf)


def read_dynamics(top: Table, materials: dict, used: list, h: float = 0.0) -> DynamicsSpec | None:
    """[dynamics]: dt in [max(MIN_DT, MIN_DT_WAVE x wave_time), duration], at most MAX_TIME_STEPS steps.

    Below MIN_DT_WAVE of the wave time, the inertia term M / dt^2 outweighs
    the stiffness by more than 1e12: Newton's relative tolerance no longer sees
    the elastic forces and a step moves nothing (dt = 1e-300 s exited 3 in
    1 / dt^2)."""
    if not top.has("dynamics"):
        return None
    t = Table(top.take("dynamics", "table"), "dynamics", top.source)
    dt = positive(t, "dt", t.take("dt", "number"))
    duration = positive(t, "duration", t.take("duration", "number"))
    wave = wave_time(materials, used, h)
    floor = max(MIN_DT, MIN_DT_WAVE * wave) if math.isfinite(wave) else MIN_DT
    if dt < floor:
        why = (f"{MIN_DT_WAVE:g} x the {wave:.3g} s an elastic wave takes to cross one element"
               if floor > MIN_DT else "a femtosecond")
        t.fail("dt", f"must be at least {floor:.3g} s ({why}), got {dt:g}")
    if duration < dt:
        t.fail("duration", f"must be at least one time step (dt = {dt:g} s), got {duration:g}")
    if duration / dt > MAX_TIME_STEPS:
        t.fail("dt", f"duration / dt must be at most {MAX_TIME_STEPS:g} time steps, got {duration / dt:.3g}")
    integrator = t.take("integrator", "str", "bdf2")
    if integrator not in INTEGRATORS:
        t.fail("integrator", f"must be one of {', '.join(INTEGRATORS)}; got {integrator!r}")
    d = Table(t.take("damping", "table", {}), "dynamics.damping", top.source)
    mass = positive(d, "mass", d.take("mass", "number", 0.0), strict=False)
    stiffness = positive(d, "stiffness", d.take("stiffness", "number", 0.0), strict=False)
    d.done()
    t.done()
    for name in used:
        if materials[name].density is None:
            raise DesignError(f"{top.source}: materials.{name}.density: missing (required with [dynamics])")
    return DynamicsSpec(dt, duration, integrator, mass, stiffness)


def read_pins(top: Table, dim: int) -> tuple:
    pins = []
    for t in named_entries(top, "pins", required=True):
        name = t.where.split(".", 1)[1]
        region = _box(t, dim)
        kind = t.take("kind", "str", "fixed")
        if kind not in ("fixed", "spring"):
            t.fail("kind", f"must be \"fixed\" or \"spring\", got {kind!r}")
        if kind == "spring" or t.has("stiffness"):
            k = positive(t, "stiffness", t.take("stiffness", "number"))
        else:
            k = 0.0
        move = t.take("move", "point", np.zeros(dim), dim=dim)     # mm: under the coordinate rule
        angle, centre, axis = _rotation(t, dim)
        t.done()
        pins.append(PinSpec(name, region, kind, k, move, angle, centre, axis))
    return tuple(pins)


MAX_PIN_ANGLE = 360.0     # degrees: a pin turns by at most one revolution


def _rotation(pin: Table, dim: int) -> tuple:
    """A pin's ``rotate = {angle, centre, axis}``: (degrees, centre point, unit axis in 3D) or (0, None, None).
    The pinned boundary turns about the centre (after the move: x = c + move + R (X - c))."""
    if not pin.has("rotate"):
        return 0.0, None, None
    t = Table(pin.take("rotate", "table"), pin.key("rotate"), pin.source)
    angle = t.take("angle", "number")
    if abs(angle) > MAX_PIN_ANGLE:
        t.fail("angle", f"must lie within +-{MAX_PIN_ANGLE:g} degrees, got {angle:g}")
    if not t.has("centre"):
        t.fail("centre", "missing: a rotation turns about a centre (a point)")
    centre = t.take("centre", "point", dim=dim)
    axis = None
    if dim == 3:
        axis = t.take("axis", "vector", dim=3)
        if not np.linalg.norm(axis) > 0:
            t.fail("axis", "must not be zero")
        axis = axis / np.linalg.norm(axis)
    t.done()
    return float(angle), centre, axis


def read_loads(top: Table, dim: int, region) -> tuple:
    loads = []
    for t in named_entries(top, "loads"):
        at = t.take("at", "point", dim=dim)
        check_inside(t, "at", at, region, "the load point")
        force = t.take("force", "vector", dim=dim)
        t.done()
        loads.append(LoadSpec(t.where.split(".", 1)[1], at, force))
    return tuple(loads)


def _box(t: Table, dim: int) -> np.ndarray:
    region = t.take("region", "points", dim=dim)
    if region.shape != (2, dim) or np.any(region[1] < region[0]):
        t.fail("region", "must be [min, max] corners of a box with min <= max")
    return region


def read_tractions(top: Table, dim: int) -> tuple:
    out = []
    for t in named_entries(top, "tractions"):
        region = _box(t, dim)
        traction = t.take("traction", "vector", dim=dim)
        t.done()
        out.append(TractionSpec(t.where.split(".", 1)[1], region, traction))
    return tuple(out)


MAX_GRAVITY = 1e5      # m/s^2: about 10,000 g


def read_gravity(top: Table, dim: int, materials: dict, used: list) -> np.ndarray | None:
    """[gravity]: an acceleration of at most MAX_GRAVITY (1e300 m/s^2 overflowed into a numpy warning
    on stderr and a diverged solve)."""
    t = Table(top.take("gravity", "table", {}), "gravity", top.source)
    if not t.data:
        return None
    g = t.take("acceleration", "vector", dim=dim)
    if float(np.linalg.norm(g)) > MAX_GRAVITY:
        t.fail("acceleration", f"must be at most {MAX_GRAVITY:g} m/s^2 (about 10,000 g; check the units: m/s^2), "
                               f"got {float(np.linalg.norm(g)):g}")
    t.done()
    for name in used:
        if materials[name].density is None:
            raise DesignError(f"{top.source}: materials.{name}.density: missing (required with [gravity])")
    return g


def read_grounds(top: Table, dim: int, bodies: tuple, tol: float, objects: tuple = ()) -> tuple:
    """[[grounds]]: rigid half-spaces that no body and no object crosses at rest (touching is fine)."""
    grounds = []
    for t in named_entries(top, "grounds"):
        point = t.take("point", "point", dim=dim)
        normal = t.take("normal", "vector", dim=dim)
        norm = float(np.linalg.norm(normal / np.abs(normal).max())) * np.abs(normal).max() \
            if np.any(normal) else 0.0
        if not norm > 0 or not math.isfinite(norm):
            t.fail("normal", "must be a non-zero vector")
        normal = normal / norm
        k = positive(t, "stiffness", t.take("stiffness", "number"))
        t.done()
        for piece in (*bodies, *objects):
            depth = -_lowest(piece, dim, point, normal)
            if depth > max(tol, 1e-9):
                what = f"object {piece.name!r}" if piece in objects else "the body"
                t.fail("point", f"the plane cuts {what} at rest ({depth:.3g} mm of it lies beyond the plane); "
                                f"a ground must start on the normal's side of {what} (touching is fine)")
        grounds.append(GroundSpec(t.where.split(".", 1)[1], point, normal, k))
    return tuple(grounds)


def _lowest(body, dim: int, point: np.ndarray, normal: np.ndarray) -> float:
    """The smallest signed distance (x - point) . normal over a body or an object at rest."""
    if dim == 2:
        return float(((body.outline - point) @ normal).min())
    lows = []
    for prim in body.solids:
        (kind, p), = prim.items()
        if kind == "box":
            corners = np.array([[x, y, z] for x in (p["min"][0], p["max"][0]) for y in (p["min"][1], p["max"][1])
                                for z in (p["min"][2], p["max"][2])])
            lows.append(((corners - point) @ normal).min())
        elif kind == "sphere":
            lows.append(float((p["center"] - point) @ normal) - p["radius"])
        elif kind == "cylinder":
            axis = (p["to"] - p["from"]) / np.linalg.norm(p["to"] - p["from"])
            spread = p["radius"] * math.sqrt(max(0.0, 1.0 - float(axis @ normal) ** 2))
            lows.append(min(float((c - point) @ normal) for c in (p["from"], p["to"])) - spread)
        else:
            pts = np.array([[x, y, z] for x, y in p["outline"] for z in p["z"]])
            lows.append(((pts - point) @ normal).min())
    return float(min(lows))


def _body_box(body, dim: int, thickness: float) -> tuple[np.ndarray, np.ndarray]:
    """An axis-aligned box around the body, or around several (3D: around its primitives, conservative
    for round ones)."""
    if isinstance(body, ObjectSpec):
        return tuple(body.box)
    if not isinstance(body, Body):
        boxes = [_body_box(b, dim, thickness) for b in body]
        return np.min([lo for lo, _ in boxes], axis=0), np.max([hi for _, hi in boxes], axis=0)
    if dim == 2:
        assert body.outline is not None                     # a 2D body has one
        lo, hi = body.outline.min(axis=0), body.outline.max(axis=0)
        return np.r_[lo, 0.0], np.r_[hi, thickness]
    return primitives_box(body.solids)


def read_fabrication(top: Table, dim: int, thickness: float, body) -> FabricationSpec:
    """[fabrication]: every key optional; defaults follow the body's size (docs/guide/fabrication.md).

    bone_depth defaults to 0.8 x thickness (2D), the mould wall to 5 % of the
    body's largest extent (to 0.5 mm, at least 3 mm), the pour hole to 30 % of its
    smallest extent (at most 6 mm); the 3D parting plane to the mid-plane of
    the body's bounding box across its smallest extent. Geometric feasibility
    (channels inside bones, room for pegs and the pour hole) is checked by
    skelfem.fabricate before anything is written.
    """
    t = Table(top.take("fabrication", "table", {}), "fabrication", top.source)
    d = FabricationSpec()
    lo, hi = _body_box(body, dim, thickness)
    extent = hi - lo
    if dim == 2:
        extent = np.r_[extent[:2], thickness]

    def length(name, default, strict=True):
        value = positive(t, name, t.take(name, "number", default), strict)
        if value > MAX_COORDINATE:
            t.fail(name, f"must be at most {MAX_COORDINATE:g} mm, got {value:g}")
        return value

    given = {k for k in FABRICATION_LIMITS if t.has(k)}
    channel = length("channel_diameter", d.channel_diameter)
    anchor = length("anchor_diameter", d.anchor_diameter)
    if dim == 2:
        depth = length("bone_depth", 0.8 * thickness)
        if depth >= thickness:
            t.fail("bone_depth", f"must be less than thickness ({thickness:g} mm): the bones are cast inside the slab")
    else:
        if t.has("bone_depth"):
            t.fail("bone_depth", "is for dim = 2 only (3D bones are their solids)")
        depth = 0.0
    min_wall = length("min_wall", d.min_wall, strict=False)
    wall = length("wall", max(3.0, round(0.1 * float(extent.max())) / 2))
    clearance = length("clearance", d.clearance, strict=False)
    pour = length("pour_diameter", min(d.pour_diameter, 0.3 * float(extent.min())))
    vent = length("vent_diameter", d.vent_diameter)
    vents = t.take("vents", "int", d.vents)
    if not 0 <= vents <= 16:
        t.fail("vents", f"must be between 0 and 16, got {vents}")
    peg = length("peg_diameter", d.peg_diameter)
    socket = length("socket_depth", d.socket_depth)
    post = length("post_diameter", d.post_diameter)
    route = length("route_tolerance", d.route_tolerance)
    if dim == 2:
        if t.has("split"):
            t.fail("split", "is for dim = 3 only (a 2D mould parts at the slab's mid-plane)")
        point, normal = np.array([0.0, 0.0, thickness / 2]), np.array([0.0, 0.0, 1.0])
    else:
        axis = 2 - int(np.argmin(extent[::-1]))      # the smallest extent; ties prefer z, then y
        s = Table(t.take("split", "table", {}), "fabrication.split", top.source)
        point = s.take("point", "point", None, dim=3)        # None: skelfem fabricate chooses it
        normal = s.take("normal", "vector", np.eye(3)[axis], dim=3)
        scale = float(np.abs(normal).max())
        if not scale > 0:
            s.fail("normal", "must be a non-zero vector")
        normal = normal / scale
        normal = normal / float(np.linalg.norm(normal))
        s.done()
    t.done()
    spec = FabricationSpec(channel, anchor, depth, min_wall, wall, clearance, pour, vent, vents, peg, socket,
                           post, route, point, normal)
    for key, message in fabrication_bounds(spec, extent):
        if key in given:               # a default out of range is refused by skelfem fabricate only
            t.fail(key, message)
    return spec


PRINTER_RESOLUTION = 0.1     # mm: the smallest step a desktop FDM / resin printer reproduces
FEATURE_RATIO = 1e-3         # ... and no feature smaller than this fraction of the body's largest extent
MIN_MOULD_WALL = 1.0         # mm: a thinner mould wall does not hold the pour (and gives broken STL normals)
MAX_MOULD_WALL_RATIO = 2.0   # the mould wall is at most this many times the body's largest extent
MIN_PRINT, MAX_PRINT = 1.0, 2000.0   # mm: the body's largest extent that a printed mould can cast
# [fabrication] keys: their kinds: hole (diameters, depths), depth, gap (clearance, min_wall), tolerance, wall
FABRICATION_LIMITS = {"channel_diameter": "hole", "anchor_diameter": "hole", "pour_diameter": "hole",
                      "vent_diameter": "hole", "peg_diameter": "hole", "socket_depth": "hole",
                      "post_diameter": "hole", "route_tolerance": "tolerance",
                      "bone_depth": "depth", "min_wall": "gap", "clearance": "gap", "wall": "wall"}


def fabrication_bounds(spec: FabricationSpec, extent) -> list[tuple[str, str]]:
    """[(key, message)] of every [fabrication] length out of its bounds for a body of this extent (mm).

    Features are at least the printer's resolution (2 x PRINTER_RESOLUTION for
    holes and pegs, which Gmsh must resolve) and FEATURE_RATIO of the body's
    largest extent, and at most the body's smallest extent; gaps (clearance,
    min_wall) are 0 or at least PRINTER_RESOLUTION / 2, at most a quarter of the smallest extent; the
    route tolerance lies between the gaps' floor and the largest extent;
    the mould wall lies in [MIN_MOULD_WALL, MAX_MOULD_WALL_RATIO x largest extent].
    Gmsh hung (ignoring signals) on a 0.01 mm channel and on a 1e5 mm wall.
    """
    extent = np.asarray(extent, dtype=float)
    big, small = float(extent.max()), float(extent.min())
    floor = max(2 * PRINTER_RESOLUTION, FEATURE_RATIO * big)
    out = []
    for key, kind in FABRICATION_LIMITS.items():
        value = float(getattr(spec, key))
        if kind == "hole":
            lo, hi = floor, small
        elif kind == "depth":
            if value == 0.0:
                continue
            lo, hi = floor, small
        elif kind == "gap":
            if value == 0.0:
                continue
            lo, hi = max(PRINTER_RESOLUTION / 2, FEATURE_RATIO * big), max(small / 4, PRINTER_RESOLUTION)
        elif kind == "tolerance":
            lo, hi = max(PRINTER_RESOLUTION / 2, FEATURE_RATIO * big), big
        else:
            lo, hi = MIN_MOULD_WALL, max(MAX_MOULD_WALL_RATIO * big, 2 * MIN_MOULD_WALL)
        if not lo <= value <= hi:
            out.append((key, f"must lie in [{lo:.3g}, {hi:.3g}] mm for this body (largest extent {big:.3g} mm, "
                             f"printer resolution {PRINTER_RESOLUTION:g} mm), got {value:g}"))
    return out


MIN_BODY, MAX_BODY = 1e-3, 1e6     # mm: the body's largest extent, 1 um to 1 km


def check_body_scale(source: str, body, dim: int, thickness: float) -> None:
    """The body's largest extent must lie in [MIN_BODY, MAX_BODY] mm, before any meshing.

    Below, Gmsh's absolute tolerances break (a 6 nm strip aborted the process
    from inside Gmsh); above, DOLFINx's point location fails (GJK) on a body
    1e7 mm long. Between, answers do not depend on the unit scale (tolerances
    are relative to the design's force and length scales).
    """
    lo, hi = _body_box(body, dim, thickness)
    big = float(np.max(hi - lo))
    if not MIN_BODY <= big <= MAX_BODY:
        raise DesignError(f"{source}: body: its largest extent ({big:.3g} mm) must lie in [{MIN_BODY:g}, "
                          f"{MAX_BODY:g}] mm (1 um to 1 km); check the units (mm)")


def body_extent(design) -> np.ndarray:
    """The extents (x, y, z; mm) of the box around a design's body (2D: the slab)."""
    lo, hi = _body_box(design.bodies, design.dim, design.thickness)
    return hi - lo


def check_bodies_held(source: str, bodies: tuple, pins: tuple, tol: float) -> None:
    """[[bodies]]: every body must meet a pin's region (else nothing holds it: a singular solve); in 3D,
    a region box that shares volume with the body's solids (OpenCASCADE)."""
    if len(bodies) < 2:
        return
    for body in bodies:
        if body.outline is None:
            from .solids import common_volume
            grow = 1e3 * tol                   # 1e-6 of the design's size: a flat region still meets its face
            held = any(common_volume([{"box": {"min": [float(v) - grow for v in p.region[0]],
                                               "max": [float(v) + grow for v in p.region[1]]}}], body.solids) > 0
                       for p in pins)
        else:
            held = any(polygons.overlap(body.outline, _box_polygon(p.region), tol) for p in pins)
        if not held:
            raise DesignError(f"{source}: bodies.{body.name}: nothing holds this body: no pin's region meets "
                              "it (add a [[pins]] entry whose region overlaps it)")


def _box_polygon(region: np.ndarray) -> np.ndarray:
    (x0, y0), (x1, y1) = region[0][:2], region[1][:2]
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], float)


fabrication_extent = body_extent


def read_markers(top: Table, dim: int, region, objects=()) -> dict:
    """[markers]: points inside the body, or inside a free object's outline (they follow the object)."""
    from .objects import inside
    t = Table(top.take("markers", "table", {}), "markers", top.source)
    out = {}
    for name in list(t.data):
        entry_name(t, name, name, "a marker name")
        X = t.take(name, "point", dim=dim)
        if not any(inside(o, X) for o in objects):
            check_inside(t, name, X, region, "the marker")
        out[name] = X
    return out


MIN_DHAT_MESH = 1e-3    # contact.dhat: at least this share of mesh.size ...
MAX_DHAT_PIECE = 0.1    # ... and at most this share of the smallest extent of a piece that touches


def read_contact(top: Table, dim: int, h: float = 1.0, pieces: tuple = ()) -> ContactSpec:
    """[contact]; where contact acts (self-contact, or several pieces: bodies and objects) or dhat is
    written, dhat lies in [MIN_DHAT_MESH x mesh.size, MAX_DHAT_PIECE x the smallest piece's smallest
    extent]. Below, the barrier's collision detection (bracketed to 1e-3 dhat) crawls: on a 274-DOF
    strip against a wall 4 s at dhat = 1e-4 h, minutes at 2.5e-7 h, endless at 1e-300 mm. Above,
    the barrier pushes pieces apart across a good part of their own size."""
    t = Table(top.take("contact", "table", {}), "contact", top.source)
    written = t.has("dhat")
    spec = ContactSpec(t.take("self", "bool", False), positive(t, "dhat", t.take("dhat", "number", 0.3)))
    t.done()
    if written or spec.self_contact or len(pieces) > 1:
        low = MIN_DHAT_MESH * h
        small, name = min(((float(np.min(hi - lo)), p.name) for p, (lo, hi) in
                           ((p, _body_box(p, dim, np.inf)) for p in pieces)), default=(math.inf, ""))
        high = MAX_DHAT_PIECE * small
        if low > high:                  # no dhat fits: the mesh is too coarse for the piece, not dhat wrong
            raise DesignError(f"{top.source}: mesh.size: {h:g} mm is more than {MAX_DHAT_PIECE / MIN_DHAT_MESH:g} x "
                              f"the smallest extent of a piece that touches ({small:.3g} mm, {name!r}), so no "
                              f"contact.dhat fits ({MIN_DHAT_MESH:g} x mesh.size to {MAX_DHAT_PIECE:g} x that "
                              f"extent); use a mesh.size of at most {small * MAX_DHAT_PIECE / MIN_DHAT_MESH:.3g} "
                              "mm, or a larger piece")
        if not low <= spec.dhat <= high:
            t.fail("dhat", f"must lie in [{low:.3g}, {high:.3g}] mm for this design ({MIN_DHAT_MESH:g} x mesh.size, "
                           f"{MAX_DHAT_PIECE:g} x the smallest extent of a piece that touches), got {spec.dhat:g}")
    return spec


def read_solver(top: Table) -> SolverSpec:
    t = Table(top.take("solver", "table", {}), "solver", top.source)
    d = SolverSpec()
    steps = t.take("steps", "int", d.steps)
    if not 1 <= steps <= MAX_STEPS:
        t.fail("steps", f"must be >= 1 and <= {MAX_STEPS}" if steps >= 1 else "must be >= 1")
    its = t.take("max_iterations", "int", d.max_iterations)
    if not 1 <= its <= MAX_STEPS:
        t.fail("max_iterations", f"must be >= 1 and <= {MAX_STEPS}" if its >= 1 else "must be >= 1")
    ls = t.take("line_search", "str", d.line_search)
    if ls not in LINE_SEARCHES:
        t.fail("line_search", f"must be one of {', '.join(LINE_SEARCHES)}; got {ls!r}")
    rtol = positive(t, "rtol", t.take("rtol", "number", d.rtol))
    atol = positive(t, "atol", t.take("atol", "number")) if t.has("atol") else None
    linear = t.take("linear", "str", d.linear)
    if linear not in LINEAR_SOLVERS:
        t.fail("linear", f"must be one of {', '.join(LINEAR_SOLVERS)}; got {linear!r}")
    t.done()
    return SolverSpec(steps, its, ls, rtol, atol, linear)


def check_energy_line_search(top: Table, solver: SolverSpec, bones: tuple, contact: ContactSpec,
                             pieces: int = 1) -> None:
    """Rigid bones move along their exact rigid motion, and contact's steps (self-contact, between bodies
    and objects: pieces > 1) are bounded to collision-free ones, only in the energy line searches
    (skelfem.fem.newton and skelfem.terms.contact refuse the others); "auto" resolves to one of them
    ("energy" with bones, else "curved")."""
    rigid = [b.name for b in bones if b.rigid]
    touching = contact.self_contact or pieces > 1
    if solver.line_search in ("auto", *ENERGY_LINE_SEARCHES) or not (rigid or touching):
        return
    reasons = []
    if rigid:
        reasons.append(f"keep rigid bones rigid (rigid: {', '.join(rigid)})")
    if contact.self_contact:
        reasons.append("bound steps to collision-free ones for self-contact (contact.self = true)")
    elif touching:
        reasons.append("bound steps to collision-free ones for contact between bodies and objects")
    top.fail("solver.line_search", f"{solver.line_search!r} cannot {' nor '.join(reasons)}; "
                                   "use \"energy\" or \"curved\"")


