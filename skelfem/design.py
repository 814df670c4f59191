"""Design files: load a TOML design, apply ``--set`` overrides, validate.

The contract is ``shared/design-format.md`` (summarised in the README). Every
problem is raised as a :class:`DesignError` whose message names the file and
the offending key, e.g. ``finger.toml: cables.flexor.stiffness: must be > 0``;
the CLI prints it as one ``error:`` line. Nothing here imports DOLFINx, so a
bad design is rejected before any heavy import or meshing.
"""
from __future__ import annotations

import copy
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import objects_design, polygons

FORMAT = 1
MAX_COORDINATE = 1e7      # mm: geometry beyond +-10 km is a typo, and overflows the predicates
MAX_STEPS = 10_000        # load steps and Newton iterations: a cap against runaway runs
MAX_NAME = 100            # bytes in a design, entry or marker name
LINE_SEARCHES = ("auto", "energy", "curved", "residual", "none", "trust_region")
ENERGY_LINE_SEARCHES = ("energy", "curved")   # line searches on Pi: the only ones rigid bones and self-contact allow
INTEGRATORS = ("euler", "bdf2")
MAX_TIME_STEPS = 1_000_000   # duration / dt: a cap against runaway runs
SECTIONS_BY_NAME = ("bones", "cables", "pins", "loads", "grounds", "tractions")
PRIMITIVES = ("box", "cylinder", "sphere", "extrude")


class DesignError(ValueError):
    """A design that cannot be simulated; the message is one line for the user."""


# -- the validated design --------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Material:
    name: str
    E: float          # Young's modulus, MPa
    nu: float         # Poisson's ratio
    density: float | None = None   # kg/m^3 (gravity, dynamics); None: not given


@dataclass(frozen=True, eq=False)
class MeshSpec:
    size: float = 2.0     # target edge length, mm
    degree: int = 1       # Lagrange degree of u


@dataclass(frozen=True, eq=False)
class Body:
    material: str
    outline: np.ndarray | None = None        # 2D: (n, 2)
    holes: tuple = ()                        # 2D: tuple of (m, 2)
    solids: tuple = ()                       # 3D: tuple of primitive dicts


@dataclass(frozen=True, eq=False)
class Bone:
    name: str
    material: str
    outline: np.ndarray | None = None
    solids: tuple = ()
    rigid: bool = False   # a rigid body: its nodes follow 3 (2D) / 6 (3D) rigid DOFs, its cells carry no energy


@dataclass(frozen=True, eq=False)
class CableSpec:
    name: str
    kind: str             # "tendon" or "ligament"
    path: np.ndarray      # (n, dim) sketch polyline
    stiffness: float      # k, N/mm
    contraction: float = 0.0   # tendon: u, mm
    pretension: float = 0.0    # ligament: rest-length shortening, mm
    anchor_radius: float | None = None   # mm; an end in silicone pulls on a disk/ball this wide (None: default)
    schedule: np.ndarray | None = None   # tendons, dynamics: (n, 2) rows [t (s), contraction (mm)], t increasing

    def contraction_at(self, t: float) -> float:
        """The contraction at time t: the schedule, piecewise linear and held beyond its ends, or the
        constant contraction if there is no schedule."""
        if self.schedule is None:
            return self.contraction
        return float(np.interp(t, self.schedule[:, 0], self.schedule[:, 1]))


@dataclass(frozen=True, eq=False)
class PinSpec:
    name: str
    region: np.ndarray    # (2, dim): [min, max]
    kind: str = "fixed"   # "fixed" (Dirichlet) or "spring" (penalty)
    stiffness: float = 0.0
    move: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class LoadSpec:
    name: str
    at: np.ndarray
    force: np.ndarray


@dataclass(frozen=True, eq=False)
class TractionSpec:
    name: str
    region: np.ndarray    # (2, dim): [min, max]; the boundary inside it is loaded
    traction: np.ndarray  # MPa: a dead load per area of reference boundary


@dataclass(frozen=True, eq=False)
class GroundSpec:
    name: str
    point: np.ndarray
    normal: np.ndarray    # unit normal, pointing to the side the body stays on
    stiffness: float


@dataclass(frozen=True, eq=False)
class ContactSpec:
    self_contact: bool = False
    dhat: float = 0.3


@dataclass(frozen=True, eq=False)
class SolverSpec:
    steps: int = 1
    max_iterations: int = 50
    line_search: str = "auto"
    rtol: float = 1e-9
    atol: float = 1e-10


@dataclass(frozen=True, eq=False)
class DynamicsSpec:
    """The [dynamics] section: its presence makes a run dynamic."""
    dt: float                         # time step, s
    duration: float                   # s
    integrator: str = "bdf2"          # "euler" or "bdf2"
    damping_mass: float = 0.0         # Rayleigh a, 1/s: damping force a M v
    damping_stiffness: float = 0.0    # Rayleigh b, s: damping force b K v (K: elastic tangent at the last step)

    @property
    def steps(self) -> int:
        """Number of time steps of size dt (the last one may be shorter)."""
        return int(math.ceil(self.duration / self.dt * (1.0 - 1e-12)))


@dataclass(frozen=True, eq=False)
class FabricationSpec:
    """The [fabrication] section (skelfem fabricate), every default resolved; lengths in mm."""
    channel_diameter: float = 1.2     # tendon channels through the bones
    anchor_diameter: float = 1.5      # ligament anchor holes (the rubber band loops through)
    bone_depth: float = 0.0           # 2D: extrusion depth of the bones, centred in the slab
    min_wall: float = 0.4             # least printed material left around a channel, hole or socket
    wall: float = 5.0                 # mould wall beyond the body
    clearance: float = 0.2            # fit of registration pins and bone pegs in their holes
    pour_diameter: float = 6.0
    vent_diameter: float = 2.0
    vents: int = 2
    peg_diameter: float = 2.0         # pegs that hold the bones in the mould
    socket_depth: float = 1.0         # sockets in the bones that the pegs enter
    split_point: np.ndarray | None = None    # the mould's parting plane (2D: the slab's mid-plane)
    split_normal: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class Design:
    source: str
    name: str
    dim: int
    thickness: float
    mesh: MeshSpec
    materials: dict
    body: Body
    bones: tuple
    cables: tuple
    pins: tuple
    loads: tuple = ()
    grounds: tuple = ()
    contact: ContactSpec = field(default_factory=ContactSpec)
    markers: dict = field(default_factory=dict)
    solver: SolverSpec = field(default_factory=SolverSpec)
    gravity: np.ndarray | None = None    # m/s^2 as written; None: no gravity
    tractions: tuple = ()
    fabrication: FabricationSpec = field(default_factory=FabricationSpec)
    dynamics: DynamicsSpec | None = None   # None: a static run
    friction: objects_design.FrictionSpec = field(default_factory=objects_design.FrictionSpec)   # Coulomb coefficients
    objects: tuple = ()                    # objects_design.ObjectSpec: free rigid bodies
    format: int = FORMAT
    raw: dict = field(default_factory=dict)   # the TOML data after overrides
    measure: float = 0.0      # body area (2D, mm^2) or volume (3D, mm^3), bones included
    vertices: int = 0         # polygon vertices of all outlines (2D) / primitives (3D)

    @property
    def tendons(self) -> tuple:
        return tuple(c for c in self.cables if c.kind == "tendon")

    def cable(self, name: str) -> CableSpec:
        return next(c for c in self.cables if c.name == name)


# -- reading typed values -------------------------------------------------------------------------
_REQUIRED = object()


class _Table:
    """Keys of one TOML table, taken one at a time; leftovers are unknown keys."""

    def __init__(self, data, where: str, source: str):
        self.source, self.where = source, where
        if not isinstance(data, dict):
            self.fail("", "must be a table")
        self.data = dict(data)

    def key(self, name: str) -> str:
        return f"{self.where}.{name}" if self.where else name

    def fail(self, name: str, message: str):
        where = self.key(name) if name else self.where
        text = f"{self.source}: {where}: {message}" if where else f"{self.source}: {message}"
        raise DesignError(re.sub(r"[\x00-\x1f\x7f]", lambda m: repr(m.group())[1:-1], text))

    def has(self, name: str) -> bool:
        return name in self.data

    def take(self, name: str, kind: str, default=_REQUIRED, dim: int | None = None):
        if name not in self.data:
            if default is _REQUIRED:
                self.fail(name, "missing (required)")
            return default
        value = self.data.pop(name)
        return _convert(value, kind, dim, lambda msg: self.fail(name, msg))

    def done(self) -> None:
        if self.data:
            self.fail(sorted(self.data)[0], "unknown key")


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _show(value, width: int = 60) -> str:
    """repr of a value for a one-line message, shortened."""
    try:
        text = repr(value)
    except Exception:           # e.g. an integer too long to print
        text = f"<{type(value).__name__}>"
    return text if len(text) <= width else text[:width - 3] + "..."


def _finite(value) -> bool:
    try:
        return math.isfinite(value)
    except OverflowError:       # an integer beyond float range
        return False


def _convert(value, kind: str, dim, fail):
    if kind == "number":
        if not _is_number(value):
            fail(f"must be a number, got {_show(value)}")
        if not _finite(value):
            fail(f"must be a finite number, got {_show(value)}")
        return float(value)
    if kind == "int":
        if not isinstance(value, int) or isinstance(value, bool):
            fail(f"must be an integer, got {_show(value)}")
        return int(value)
    if kind == "str":
        if not isinstance(value, str):
            fail(f"must be a string, got {_show(value)}")
        return value
    if kind == "bool":
        if not isinstance(value, bool):
            fail(f"must be true or false, got {_show(value)}")
        return value
    if kind in ("vector", "points"):
        shape = (dim,) if kind == "vector" else (None, dim)
        ok = isinstance(value, list) and (kind == "vector" or all(isinstance(v, list) for v in value))
        if ok:
            flat = value if kind == "vector" else [x for v in value for x in v]
            ok = all(_is_number(x) for x in flat)
        if ok:
            if not all(_finite(x) for x in flat):
                fail("must be finite")
            try:
                a = np.asarray(value, dtype=float)
            except (ValueError, TypeError, OverflowError):
                ok = False
        if not ok or a.ndim != len(shape) or a.shape[-1] != dim:
            what = f"{dim} numbers" if kind == "vector" else f"a list of points with {dim} coordinates each"
            fail(f"must be {what}")
        return a
    if kind == "table":
        if not isinstance(value, dict):
            fail("must be a table")
        return value
    if kind == "tables":
        if not isinstance(value, list) or not all(isinstance(x, dict) for x in value):
            fail("must be an array of tables ([[...]])")
        return value
    if kind == "list":
        if not isinstance(value, list):
            fail("must be a list")
        return value
    raise AssertionError(kind)


def _positive(t: _Table, name: str, value: float, strict: bool = True) -> float:
    if value < 0 or (strict and value == 0):
        t.fail(name, f"must be {'>' if strict else '>='} 0, got {value:g}")
    return value


def _bounded(t: _Table, name: str, a: np.ndarray) -> np.ndarray:
    """Geometry must stay within +-MAX_COORDINATE mm."""
    if a.size and np.abs(a).max() > MAX_COORDINATE:
        t.fail(name, f"coordinates must lie within +-{MAX_COORDINATE:g} mm (got {np.abs(a).max():g})")
    return a


def _plain_name(t: _Table, name: str, value: str, what: str) -> str:
    """A name that also names folders or columns: no separators, control characters or hidden names."""
    from .outdir import check_name
    problem = check_name(value, what, MAX_NAME)
    if problem:
        t.fail(name, f"{problem}; got {_show(value)}")
    return value


# -- overrides ------------------------------------------------------------------------------------------
def _parse_value(text: str):
    try:
        return tomllib.loads("v = " + text)["v"]
    except (tomllib.TOMLDecodeError, RecursionError, KeyError):
        return text.strip()


def apply_override(data: dict, assignment: str, source: str) -> None:
    """Apply ``KEY=VALUE`` (KEY dotted; named entries addressed by name) to data in place."""
    def fail(msg):
        raise DesignError(f"{source}: --set {assignment}: {msg}")
    if "=" not in assignment:
        fail("expected KEY=VALUE")
    key, text = assignment.split("=", 1)
    parts = [p.strip() for p in key.strip().split(".")]
    if not all(parts):
        fail("empty key")
    node, walked = data, []
    for part in parts[:-1]:
        walked.append(part)
        if isinstance(node, list):
            match = [e for e in node if isinstance(e, dict) and e.get("name") == part]
            if not match:
                names = ", ".join(str(e.get("name")) for e in node if isinstance(e, dict))
                fail(f"no entry named {part!r} in {'.'.join(walked[:-1])} (have: {names or 'none'})")
            node = match[0]
        elif isinstance(node, dict):
            if part not in node:
                if parts[0] in SECTIONS_BY_NAME and len(walked) == 1:
                    fail(f"the design has no {part!r} section")
                node[part] = {}
            node = node[part]
        else:
            fail(f"{'.'.join(walked[:-1])} is a value, not a table")
    if isinstance(node, list):
        fail(f"address an entry of {'.'.join(parts[:-1])} by name")
    if not isinstance(node, dict):
        fail(f"{'.'.join(parts[:-1])} is a value, not a table")
    node[parts[-1]] = _parse_value(text)


# -- geometry checks (2D) --------------------------------------------------------------------------------
_MEMO: dict = {}     # results of pure geometry checks by their inputs: a re-parse after a live change repeats none


def _memo(kind: str, arrays, tol: float, check):
    """check() once per (kind, arrays, tol); a check that raises is not remembered."""
    key = (kind, tol, *((a.shape, a.tobytes()) for a in arrays))
    if key not in _MEMO:
        if len(_MEMO) > 4096:
            _MEMO.clear()
        _MEMO[key] = check()
    return _MEMO[key]


def _polygon(t: _Table, name: str, pts: np.ndarray, tol: float) -> np.ndarray:
    if len(pts) < 3:
        t.fail(name, "a polygon needs at least 3 points")
    _bounded(t, name, pts)
    _memo("polygon", [pts], tol, lambda: _polygon_shape(t, name, pts, tol))
    return pts


def _polygon_shape(t: _Table, name: str, pts: np.ndarray, tol: float) -> bool:
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
    """The body's closed region: inside the outline and outside every hole."""

    def __init__(self, outline, holes, tol):
        self.outline, self.holes, self.tol = outline, holes, tol
        self.loops = [outline, *holes]

    def contains(self, points: np.ndarray) -> np.ndarray:
        # holes lie strictly inside the outline and apart: the even-odd rule over all loops
        return polygons.region_contains(self.loops, np.atleast_2d(points), self.tol)

    def contains_path(self, path: np.ndarray) -> bool:
        return _memo("path", [*self.loops, path], self.tol, lambda: bool(
            np.all(self.contains(polygons.polyline_samples(path, self.loops, self.tol)))))


def _layout_2d(body_t: "_Table", region: _Region2D, bone_tables: list, bone_outlines: list) -> None:
    loops = [region.outline, *region.holes, *bone_outlines]
    _memo(f"layout{len(region.holes)}", loops, region.tol,
          lambda: _check_layout_2d(body_t, region, bone_tables, bone_outlines))


def _check_layout_2d(body_t: "_Table", region: _Region2D, bone_tables: list, bone_outlines: list) -> bool:
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
    nested = set()                                  # (i, j): loop i's first vertex lies inside loop j
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
def _named_entries(top: _Table, section: str, required: bool = False) -> list[_Table]:
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
        label = name if isinstance(name, str) and name else str(i)
        t = _Table(e, f"{section}.{label}", top.source)
        name = t.take("name", "str")
        if not name or "." in name or "=" in name:
            t.fail("name", "must be a non-empty name without '.' or '='")
        _plain_name(t, "name", name, "a name")
        if name in seen:
            t.fail("name", f"duplicate name {name!r} in {section}")
        seen.add(name)
        tables.append(t)
    return tables


def _materials(top: _Table) -> dict:
    mt = _Table(top.take("materials", "table"), "materials", top.source)
    if not mt.data:
        mt.fail("", "at least one material is required")
    out = {}
    for name in list(mt.data):
        t = _Table(mt.take(name, "table"), f"materials.{name}", top.source)
        E = _positive(t, "E", t.take("E", "number"))
        nu = t.take("nu", "number")
        if not -1.0 < nu < 0.5:
            t.fail("nu", f"must lie in (-1, 0.5), got {nu:g}")
        density = t.take("density", "number", None)
        if density is not None:
            _positive(t, "density", density)
        t.done()
        out[name] = Material(name, E, nu, density)
    return out


def _material_ref(t: _Table, materials: dict) -> str:
    name = t.take("material", "str")
    if name not in materials:
        t.fail("material", f"unknown material {name!r} (defined: {', '.join(materials)})")
    return name


def _solid(t: _Table, i: int, prim, dim: int, tol: float) -> dict:
    where = f"{t.where}.solids[{i}]"
    if not isinstance(prim, dict) or len(prim) != 1 or next(iter(prim)) not in PRIMITIVES:
        raise DesignError(f"{t.source}: {where}: must be one of "
                          + ", ".join(f"{{ {p} = {{...}} }}" for p in PRIMITIVES))
    (kind, params), = prim.items()
    p = _Table(params, f"{where}.{kind}", t.source)
    if kind == "box":
        lo, hi = _bounded(p, "min", p.take("min", "vector", dim=3)), _bounded(p, "max", p.take("max", "vector", dim=3))
        if np.any(hi - lo <= tol):
            p.fail("max", "must exceed min in every coordinate")
        out = {"min": lo, "max": hi}
    elif kind == "cylinder":
        a, b = _bounded(p, "from", p.take("from", "vector", dim=3)), _bounded(p, "to", p.take("to", "vector", dim=3))
        if np.linalg.norm(b - a) <= tol:
            p.fail("to", "must differ from 'from'")
        out = {"from": a, "to": b, "radius": _small(p, "radius", p.take("radius", "number"), tol)}
    elif kind == "sphere":
        out = {"center": _bounded(p, "center", p.take("center", "vector", dim=3)),
               "radius": _small(p, "radius", p.take("radius", "number"), tol)}
    else:
        outline = _polygon(p, "outline", p.take("outline", "points", dim=2), tol)
        z = _bounded(p, "z", p.take("z", "vector", dim=2))
        if z[1] - z[0] <= tol:
            p.fail("z", "must be [z0, z1] with z1 > z0")
        out = {"outline": outline, "z": z}
    p.done()
    return {kind: out}


def _small(t: _Table, name: str, r: float, tol: float) -> float:
    _positive(t, name, r)
    if r <= tol or r > MAX_COORDINATE:
        t.fail(name, f"must lie in ({tol:g}, {MAX_COORDINATE:g}] mm, got {r:g}")
    return r


def _solids(t: _Table, dim: int, tol: float) -> tuple:
    prims = t.take("solids", "list")
    if not prims:
        t.fail("solids", "at least one primitive is required")
    return tuple(_solid(t, i, p, dim, tol) for i, p in enumerate(prims))


def _body(top: _Table, dim: int, materials: dict):
    t = _Table(top.take("body", "table"), "body", top.source)
    material = _material_ref(t, materials)
    if dim == 3:
        tol = 1e-9 * max(_extent(top.data), 1.0)
        body = Body(material, solids=_solids(t, dim, tol))
        t.done()
        return body, None, tol, t
    outline = t.take("outline", "points", dim=2)
    tol = 1e-9 * max(float(np.ptp(outline, axis=0).max()) if len(outline) >= 1 else 1.0, 1.0)
    outline = _polygon(t, "outline", outline, tol)
    holes = []
    for i, h in enumerate(t.take("holes", "list", default=[])):
        hname = f"holes[{i}]"
        holes.append(_polygon(t, hname, _convert(h, "points", 2, lambda m: t.fail(hname, m)), tol))
    t.done()
    return Body(material, outline=outline, holes=tuple(holes)), _Region2D(outline, holes, tol), tol, t


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


def _bones(top: _Table, dim: int, materials: dict, region, tol, body_t) -> tuple:
    bones, tables = [], []
    for t in _named_entries(top, "bones"):
        name = t.where.split(".", 1)[1]
        material = _material_ref(t, materials)
        rigid = t.take("rigid", "bool", False)
        if dim == 3:
            bones.append(Bone(name, material, solids=_solids(t, dim, tol), rigid=rigid))
            t.done()
            continue
        outline = _polygon(t, "outline", t.take("outline", "points", dim=2), tol)
        t.done()
        bones.append(Bone(name, material, outline=outline, rigid=rigid))
        tables.append(t)
    if dim == 2:
        _layout_2d(body_t, region, tables, [b.outline for b in bones])
    return tuple(bones)


def _inside(t: _Table, key: str, points: np.ndarray, region, what: str) -> None:
    if region is not None and not np.all(region.contains(np.atleast_2d(points))):
        t.fail(key, f"{what} lies outside the body")


def _cables(top: _Table, dim: int, region, tol) -> tuple:
    cables = []
    for t in _named_entries(top, "cables"):
        name = t.where.split(".", 1)[1]
        kind = t.take("kind", "str")
        if kind not in ("tendon", "ligament"):
            t.fail("kind", f"must be \"tendon\" or \"ligament\", got {kind!r}")
        path = _bounded(t, "path", t.take("path", "points", dim=dim))
        if len(path) < 2:
            t.fail("path", "a cable path needs at least 2 points")
        seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
        if np.any(seg <= tol):
            t.fail("path", "repeated consecutive points (zero-length segment)")
        if region is not None and not region.contains_path(path):
            t.fail("path", "the cable leaves the body (it must run inside it or on its boundary)")
        k = _positive(t, "stiffness", t.take("stiffness", "number"))
        contraction = pretension = 0.0
        if kind == "tendon":
            contraction = _positive(t, "contraction", t.take("contraction", "number", 0.0), strict=False)
            if t.has("pretension"):
                t.fail("pretension", "only ligaments take a pretension (a tendon is shortened by contraction)")
        else:
            pretension = _positive(t, "pretension", t.take("pretension", "number", 0.0), strict=False)
            if t.has("contraction"):
                t.fail("contraction", "ligaments are passive and never contracted (use pretension)")
        anchor = None
        if t.has("anchor_radius"):
            anchor = _positive(t, "anchor_radius", t.take("anchor_radius", "number"), strict=False)
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
        t.done()
        cables.append(CableSpec(name, kind, path, k, contraction, pretension, anchor, schedule))
    return tuple(cables)


def _schedule(t: _Table, value: list, length: float) -> np.ndarray:
    """[[t0, u0], [t1, u1], ...]: times (s) >= 0 strictly increasing, contractions (mm) in [0, length)."""
    if not value:
        t.fail("schedule", "must be a non-empty list of [time, contraction] pairs")
    for i, row in enumerate(value):
        if not (isinstance(row, list) and len(row) == 2 and all(_is_number(x) for x in row)):
            t.fail("schedule", f"entry {i} must be a [time, contraction] pair of numbers, got {_show(row)}")
        if not all(_finite(x) for x in row):
            t.fail("schedule", f"entry {i} must be finite, got {_show(row)}")
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


def _dynamics(top: _Table, materials: dict, used: list) -> DynamicsSpec | None:
    if not top.has("dynamics"):
        return None
    t = _Table(top.take("dynamics", "table"), "dynamics", top.source)
    dt = _positive(t, "dt", t.take("dt", "number"))
    duration = _positive(t, "duration", t.take("duration", "number"))
    if duration < dt:
        t.fail("duration", f"must be at least one time step (dt = {dt:g} s), got {duration:g}")
    if duration / dt > MAX_TIME_STEPS:
        t.fail("dt", f"duration / dt must be at most {MAX_TIME_STEPS:g} time steps, got {duration / dt:.3g}")
    integrator = t.take("integrator", "str", "bdf2")
    if integrator not in INTEGRATORS:
        t.fail("integrator", f"must be one of {', '.join(INTEGRATORS)}; got {integrator!r}")
    d = _Table(t.take("damping", "table", {}), "dynamics.damping", top.source)
    mass = _positive(d, "mass", d.take("mass", "number", 0.0), strict=False)
    stiffness = _positive(d, "stiffness", d.take("stiffness", "number", 0.0), strict=False)
    d.done()
    t.done()
    for name in used:
        if materials[name].density is None:
            raise DesignError(f"{top.source}: materials.{name}.density: missing (required with [dynamics])")
    return DynamicsSpec(dt, duration, integrator, mass, stiffness)


def _pins(top: _Table, dim: int) -> tuple:
    pins = []
    for t in _named_entries(top, "pins", required=True):
        name = t.where.split(".", 1)[1]
        region = _box(t, dim)
        kind = t.take("kind", "str", "fixed")
        if kind not in ("fixed", "spring"):
            t.fail("kind", f"must be \"fixed\" or \"spring\", got {kind!r}")
        if kind == "spring" or t.has("stiffness"):
            k = _positive(t, "stiffness", t.take("stiffness", "number"))
        else:
            k = 0.0
        move = t.take("move", "vector", np.zeros(dim), dim=dim)
        t.done()
        pins.append(PinSpec(name, region, kind, k, move))
    return tuple(pins)


def _loads(top: _Table, dim: int, region) -> tuple:
    loads = []
    for t in _named_entries(top, "loads"):
        at = _bounded(t, "at", t.take("at", "vector", dim=dim))
        _inside(t, "at", at, region, "the load point")
        force = t.take("force", "vector", dim=dim)
        t.done()
        loads.append(LoadSpec(t.where.split(".", 1)[1], at, force))
    return tuple(loads)


def _box(t: _Table, dim: int) -> np.ndarray:
    region = t.take("region", "points", dim=dim)
    if region.shape != (2, dim) or np.any(region[1] < region[0]):
        t.fail("region", "must be [min, max] corners of a box with min <= max")
    return region


def _tractions(top: _Table, dim: int) -> tuple:
    out = []
    for t in _named_entries(top, "tractions"):
        region = _box(t, dim)
        traction = t.take("traction", "vector", dim=dim)
        t.done()
        out.append(TractionSpec(t.where.split(".", 1)[1], region, traction))
    return tuple(out)


def _gravity(top: _Table, dim: int, materials: dict, used: list) -> np.ndarray | None:
    t = _Table(top.take("gravity", "table", {}), "gravity", top.source)
    if not t.data:
        return None
    g = t.take("acceleration", "vector", dim=dim)
    t.done()
    for name in used:
        if materials[name].density is None:
            raise DesignError(f"{top.source}: materials.{name}.density: missing (required with [gravity])")
    return g


def _grounds(top: _Table, dim: int, body: Body, tol: float) -> tuple:
    grounds = []
    for t in _named_entries(top, "grounds"):
        point = _bounded(t, "point", t.take("point", "vector", dim=dim))
        normal = t.take("normal", "vector", dim=dim)
        norm = float(np.linalg.norm(normal / np.abs(normal).max())) * np.abs(normal).max() \
            if np.any(normal) else 0.0
        if not norm > 0 or not math.isfinite(norm):
            t.fail("normal", "must be a non-zero vector")
        normal = normal / norm
        k = _positive(t, "stiffness", t.take("stiffness", "number"))
        t.done()
        depth = -_lowest(body, dim, point, normal)
        if depth > max(tol, 1e-9):
            t.fail("point", f"the plane cuts the body at rest ({depth:.3g} mm of it lies beyond the plane); "
                            "a ground must start on the normal's side of the body (touching is fine)")
        grounds.append(GroundSpec(t.where.split(".", 1)[1], point, normal, k))
    return tuple(grounds)


def _lowest(body: Body, dim: int, point: np.ndarray, normal: np.ndarray) -> float:
    """The smallest signed distance (x - point) . normal over the body at rest."""
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


def _body_box(body: Body, dim: int, thickness: float) -> tuple[np.ndarray, np.ndarray]:
    """An axis-aligned box around the body (3D: around its primitives, conservative for round ones)."""
    if dim == 2:
        lo, hi = body.outline.min(axis=0), body.outline.max(axis=0)
        return np.r_[lo, 0.0], np.r_[hi, thickness]
    los, his = [], []
    for prim in body.solids:
        (kind, p), = prim.items()
        if kind == "box":
            los.append(p["min"]), his.append(p["max"])
        elif kind == "cylinder":
            ends = np.array([p["from"], p["to"]])
            los.append(ends.min(axis=0) - p["radius"]), his.append(ends.max(axis=0) + p["radius"])
        elif kind == "sphere":
            los.append(p["center"] - p["radius"]), his.append(p["center"] + p["radius"])
        else:
            los.append(np.r_[p["outline"].min(axis=0), p["z"][0]]), his.append(np.r_[p["outline"].max(axis=0), p["z"][1]])
    return np.min(los, axis=0), np.max(his, axis=0)


def _fabrication(top: _Table, dim: int, thickness: float, body: Body) -> FabricationSpec:
    """[fabrication]: every key optional; defaults follow the body's size (see the README).

    bone_depth defaults to 0.8 x thickness (2D), the mould wall to 5 % of the
    body's largest extent (to 0.5 mm, at least 3 mm), the pour hole to 30 % of its
    smallest extent (at most 6 mm); the 3D parting plane to the mid-plane of
    the body's bounding box across its smallest extent. Geometric feasibility
    (channels inside bones, room for pegs and the pour hole) is checked by
    skelfem.fabricate before anything is written.
    """
    t = _Table(top.take("fabrication", "table", {}), "fabrication", top.source)
    d = FabricationSpec()
    lo, hi = _body_box(body, dim, thickness)
    extent = hi - lo
    if dim == 2:
        extent = np.r_[extent[:2], thickness]

    def length(name, default, strict=True):
        value = _positive(t, name, t.take(name, "number", default), strict)
        if value > MAX_COORDINATE:
            t.fail(name, f"must be at most {MAX_COORDINATE:g} mm, got {value:g}")
        return value

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
    if dim == 2:
        if t.has("split"):
            t.fail("split", "is for dim = 3 only (a 2D mould parts at the slab's mid-plane)")
        point, normal = np.array([0.0, 0.0, thickness / 2]), np.array([0.0, 0.0, 1.0])
    else:
        axis = 2 - int(np.argmin(extent[::-1]))      # the smallest extent; ties prefer z, then y
        s = _Table(t.take("split", "table", {}), "fabrication.split", top.source)
        point = _bounded(s, "point", s.take("point", "vector", 0.5 * (lo + hi), dim=3))
        normal = s.take("normal", "vector", np.eye(3)[axis], dim=3)
        scale = float(np.abs(normal).max())
        if not scale > 0:
            s.fail("normal", "must be a non-zero vector")
        normal = normal / scale
        normal = normal / float(np.linalg.norm(normal))
        s.done()
    t.done()
    return FabricationSpec(channel, anchor, depth, min_wall, wall, clearance, pour, vent, vents, peg, socket,
                           point, normal)


def _markers(top: _Table, dim: int, region) -> dict:
    t = _Table(top.take("markers", "table", {}), "markers", top.source)
    out = {}
    for name in list(t.data):
        if "." in name:
            t.fail(name, "marker names must not contain '.'")
        _plain_name(t, name, name, "a marker name")
        X = _bounded(t, name, t.take(name, "vector", dim=dim))
        _inside(t, name, X, region, "the marker")
        out[name] = X
    return out


def _contact(top: _Table, dim: int) -> ContactSpec:
    t = _Table(top.take("contact", "table", {}), "contact", top.source)
    spec = ContactSpec(t.take("self", "bool", False), _positive(t, "dhat", t.take("dhat", "number", 0.3)))
    if spec.self_contact and dim != 2:
        t.fail("self", "self-contact is implemented for dim = 2 only")
    t.done()
    return spec


def _solver(top: _Table) -> SolverSpec:
    t = _Table(top.take("solver", "table", {}), "solver", top.source)
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
    rtol = _positive(t, "rtol", t.take("rtol", "number", d.rtol))
    atol = _positive(t, "atol", t.take("atol", "number", d.atol))
    t.done()
    return SolverSpec(steps, its, ls, rtol, atol)


def _energy_line_search(top: _Table, solver: SolverSpec, bones: tuple, contact: ContactSpec) -> None:
    """Rigid bones move along their exact rigid motion, and self-contact's steps are bounded to
    collision-free ones, only in the energy line searches (skelfem.solver and skelfem.terms.contact
    refuse the others); "auto" resolves to one of them ("energy" with bones, else "curved")."""
    rigid = [b.name for b in bones if b.rigid]
    if solver.line_search in ("auto", *ENERGY_LINE_SEARCHES) or not (rigid or contact.self_contact):
        return
    reasons = []
    if rigid:
        reasons.append(f"keep rigid bones rigid (rigid: {', '.join(rigid)})")
    if contact.self_contact:
        reasons.append("bound steps to collision-free ones for self-contact (contact.self = true)")
    top.fail("solver.line_search", f"{solver.line_search!r} cannot {' nor '.join(reasons)}; "
                                   "use \"energy\" or \"curved\"")


# -- entry points -----------------------------------------------------------------------------------------
def parse_design(data: dict, source: str = "<design>", overrides=()) -> Design:
    """Validate a design given as parsed TOML (a dict); overrides are ``KEY=VALUE`` strings."""
    data = copy.deepcopy(data)
    for assignment in overrides:
        apply_override(data, assignment, source)
    top = _Table(data, "", source)
    fmt = top.take("format", "int")
    if fmt != FORMAT:
        top.fail("format", f"unsupported format {fmt} (this version reads format = {FORMAT})")
    name = _plain_name(top, "name", top.take("name", "str", Path(source).stem if source != "<design>" else "design"),
                       "the design name (it names the output folder)")
    dim = top.take("dim", "int", 2)
    if dim not in (2, 3):
        top.fail("dim", f"must be 2 or 3, got {dim}")
    thickness = 1.0
    if dim == 2:
        thickness = _positive(top, "thickness", top.take("thickness", "number", 1.0))
    elif top.has("thickness"):
        top.fail("thickness", "is for dim = 2 only")
    mt = _Table(top.take("mesh", "table", {}), "mesh", source)
    mesh = MeshSpec(_positive(mt, "size", mt.take("size", "number", MeshSpec.size)),
                    mt.take("degree", "int", MeshSpec.degree))
    if mesh.degree not in (1, 2):
        mt.fail("degree", f"must be 1 or 2, got {mesh.degree}")
    mt.done()
    materials = _materials(top)
    body, region, tol, body_t = _body(top, dim, materials)
    bones = _bones(top, dim, materials, region, tol, body_t)
    cables = _cables(top, dim, region, tol)
    pins = _pins(top, dim)
    loads = _loads(top, dim, region)
    friction, objects = objects_design.take(top, dim, materials, body)   # [[objects]], friction keys
    grounds = _grounds(top, dim, body, tol)
    contact = _contact(top, dim)
    markers = _markers(top, dim, region)
    solver = _solver(top)
    _energy_line_search(top, solver, bones, contact)
    gravity = _gravity(top, dim, materials, [body.material] + [b.material for b in bones])
    tractions = _tractions(top, dim)
    fabrication = _fabrication(top, dim, thickness, body)
    dynamics = _dynamics(top, materials, [body.material] + [b.material for b in bones])
    top.done()
    if dim == 2:
        measure = abs(polygons.signed_area(body.outline)) - sum(abs(polygons.signed_area(h)) for h in body.holes)
        vertices = len(body.outline) + sum(len(h) for h in body.holes) + sum(len(b.outline) for b in bones)
    else:
        from . import solids
        result = solids.check(body.solids, [(b.name, b.solids) for b in bones], [(c.name, c.path) for c in cables],
                              markers, [(ld.name, ld.at) for ld in loads], [(p.name, p.region) for p in pins], tol)
        if result.error is not None:
            key, message = result.error
            raise DesignError(f"{source}: {key}: {message}")
        measure = result.volume
        vertices = sum(len(next(iter(s.values())).get("outline", ())) + 8 for s in body.solids) \
            + sum(len(next(iter(s.values())).get("outline", ())) + 8 for b in bones for s in b.solids)
    return Design(
        source=str(source), name=name, dim=dim, thickness=thickness, mesh=mesh,
        materials=materials, body=body, bones=bones, cables=cables, pins=pins, loads=loads,
        grounds=grounds, contact=contact, markers=markers, solver=solver, gravity=gravity,
        tractions=tractions, fabrication=fabrication, dynamics=dynamics, friction=friction, objects=objects, raw=data, measure=float(measure), vertices=int(vertices),
    )


MAX_FILE = 64 * 2 ** 20      # bytes: a design is text, not a data set


def read_toml(path, what: str = "design file") -> dict:
    """Parse a TOML file; DesignError (one line) for anything that is not a readable TOML table."""
    source = str(path)
    try:
        with open(path, "rb") as f:
            raw = f.read(MAX_FILE + 1)
        if len(raw) > MAX_FILE:
            raise DesignError(f"{source}: larger than {MAX_FILE // 2 ** 20} MB; not a {what}")
        return tomllib.loads(raw.decode("utf-8"))
    except FileNotFoundError:
        raise DesignError(f"{source}: no such file") from None
    except IsADirectoryError:
        raise DesignError(f"{source}: is a folder, not a {what}") from None
    except PermissionError:
        raise DesignError(f"{source}: permission denied") from None
    except UnicodeDecodeError:
        raise DesignError(f"{source}: not a text (UTF-8) file") from None
    except tomllib.TOMLDecodeError as exc:
        raise DesignError(f"{source}: malformed TOML: {exc}") from None
    except RecursionError:
        raise DesignError(f"{source}: malformed TOML: nested too deeply") from None
    except OSError as exc:
        raise DesignError(f"{source}: cannot read ({exc.strerror or exc})") from None
    except ValueError as exc:          # e.g. an embedded NUL in the path
        raise DesignError(f"{source}: cannot read ({exc})") from None


def load_design(path, overrides=()) -> Design:
    """Read, override and validate a design file; raises DesignError for any problem."""
    path = Path(path)
    data = read_toml(path)
    data.setdefault("name", path.stem)
    return parse_design(data, str(path), overrides)


def flatten(raw: dict, prefix: str = "") -> dict:
    """{dotted key: value}: the --set keys of a design dict; named entries by name (order kept as a key)."""
    out = {}
    for key, value in raw.items():
        path = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flatten(value, path + "."))
        elif (not prefix and key in SECTIONS_BY_NAME and isinstance(value, list)
              and all(isinstance(e, dict) and isinstance(e.get("name"), str) for e in value)
              and len({e["name"] for e in value}) == len(value)):
            out[f"{path}.#order"] = tuple(e["name"] for e in value)
            for e in value:
                out.update(flatten(e, f"{path}.{e['name']}."))
        else:
            out[path] = value
    return out


def changed_keys(old: dict, new: dict) -> set:
    """The keys whose values differ between two flattened designs (present in one only included)."""
    missing = object()
    return {k for k in old.keys() | new.keys() if old.get(k, missing) != new.get(k, missing)}
