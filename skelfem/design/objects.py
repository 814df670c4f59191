"""Design sections for touching the world: free objects and Coulomb friction coefficients.

Keys read here (everything else of these sections is read by skelfem.design)::

    [[objects]]               # free rigid bodies the robot touches; no pins needed
    name = "ball"
    outline = [[40, 30], [60, 30], [60, 50], [40, 50]]   # 2D: simple polygon, clear of the body at rest
    solids = [{ sphere = { center = [50, 40, 10], radius = 8 } }]   # 3D instead: primitives, as the body's
    material = "pla"          # its density gives the weight under [gravity]
    rigid = true              # default: 3 rigid DOFs; false: meshed and elastic (its material's E and nu)

    [contact]
    friction = 0.5            # kinetic Coulomb coefficient, default for every contact (>= 0; default 0)
    friction_static = 0.6     # static coefficient, >= friction (default: friction)
    [contact.pairs]           # per material pair (either order): the kinetic coefficient, static = it
    "ecoflex:pla" = 0.8       # or { friction = 0.8, friction_static = 0.9 }

    [[grounds]]
    friction = 0.4            # this ground's coefficients (default: [contact]'s)
    friction_static = 0.5

:func:`take` runs before the sections it reads from are parsed: it removes
these keys from the tables that skelfem.design goes on to check (so they
are not unknown keys there), leaving the design's raw data untouched. It
needs only the ``_Table`` it is given (``take``, ``fail``, its class), so it
imports nothing from skelfem.design.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import polygons

FRICTION_KEYS = ("friction", "friction_static")
MAX_FRICTION = 100.0      # the largest Coulomb coefficient of a contact or ground (docs/guide/design-files.md)


@dataclass(frozen=True)
class Coulomb:
    """Kinetic and static Coulomb coefficients (static >= kinetic >= 0)."""
    kinetic: float = 0.0
    static: float = 0.0
    static_given: bool = False     # friction_static written (else it follows friction)

    @property
    def active(self) -> bool:
        return self.static > 0.0


@dataclass(frozen=True, eq=False)
class FrictionSpec:
    default: Coulomb = field(default_factory=Coulomb)     # [contact]
    grounds: dict = field(default_factory=dict)           # ground name -> Coulomb
    pairs: dict = field(default_factory=dict)             # frozenset({material, material}) -> Coulomb

    def ground(self, name: str) -> Coulomb:
        return self.grounds.get(name, self.default)

    def between(self, a: str, b: str) -> Coulomb:
        """The coefficients between two materials."""
        return self.pairs.get(frozenset((a, b)), self.default)

    @property
    def active(self) -> bool:
        return self.default.active or any(c.active for c in self.grounds.values())


@dataclass(frozen=True, eq=False)
class ObjectSpec:
    name: str
    outline: np.ndarray | None    # 2D: (n, 2) mm, counter-clockwise or not; 3D: None
    material: str
    rigid: bool = True
    solids: tuple = ()            # 3D: the union of these primitives (as the body's)

    @property
    def box(self) -> np.ndarray:
        """(2, dim) corners of an axis-aligned box around the object at rest (3D: conservative)."""
        if self.outline is not None:
            return np.array([self.outline.min(axis=0), self.outline.max(axis=0)])
        return np.array(primitives_box(self.solids))

    @property
    def size(self) -> float:
        """The diagonal of its box, mm."""
        return float(np.linalg.norm(np.ptp(self.box, axis=0)))


def inside(obj: ObjectSpec, X: np.ndarray) -> bool:
    """Whether point X lies in the object at rest (2D: its outline; 3D: one of its primitives)."""
    X = np.asarray(X, float)
    if obj.outline is not None:
        return bool(polygons.parity(X, [np.asarray(obj.outline, float)])[0])
    for prim in obj.solids:
        (kind, p), = prim.items()
        hit: bool
        if kind == "box":
            hit = bool(np.all(X >= p["min"]) and np.all(X <= p["max"]))
        elif kind == "sphere":
            hit = bool(np.linalg.norm(X - p["center"]) <= p["radius"])
        elif kind == "cylinder":
            a, axis = p["from"], p["to"] - p["from"]
            s = float((X - a) @ axis) / float(axis @ axis)
            hit = bool(0.0 <= s <= 1.0 and np.linalg.norm(X - a - s * axis) <= p["radius"])
        else:
            hit = bool(p["z"][0] <= X[2] <= p["z"][1]) and bool(polygons.parity(X[:2], [p["outline"]])[0])
        if hit:
            return True
    return False


def primitives_box(solids) -> tuple[np.ndarray, np.ndarray]:
    """An axis-aligned box around 3D primitives (exact for boxes and extrusions, conservative for round
    ones)."""
    los, his = [], []
    for prim in solids:
        (kind, p), = prim.items()
        if kind == "box":
            los.append(p["min"])
            his.append(p["max"])
        elif kind == "cylinder":
            ends = np.array([p["from"], p["to"]])
            los.append(ends.min(axis=0) - p["radius"])
            his.append(ends.max(axis=0) + p["radius"])
        elif kind == "sphere":
            los.append(p["center"] - p["radius"])
            his.append(p["center"] + p["radius"])
        else:
            los.append(np.r_[p["outline"].min(axis=0), p["z"][0]])
            his.append(np.r_[p["outline"].max(axis=0), p["z"][1]])
    return np.min(los, axis=0), np.max(his, axis=0)


def _coulomb(t, default: Coulomb | None) -> Coulomb | None:
    """The (friction, friction_static) pair of table t, or default if it has neither."""
    if not any(t.has(k) for k in FRICTION_KEYS):
        return default
    base = default or Coulomb()
    mu = t.take("friction", "number", base.kinetic if not t.has("friction_static") else None)
    if mu is None:
        t.fail("friction", "missing: friction_static needs friction (the kinetic coefficient) beside it")
    coefficient(t, "friction", mu)
    given = t.has("friction_static")
    mu_s = coefficient(t, "friction_static", t.take("friction_static", "number", mu))
    if mu_s < mu:
        t.fail("friction_static", f"must be >= friction ({mu:g}), got {mu_s:g}")
    return Coulomb(float(mu), float(mu_s), given)


def coefficient(t, key: str, mu: float) -> float:
    """A Coulomb coefficient of [contact], [contact.pairs] or [[grounds]]: in [0, MAX_FRICTION]."""
    if not 0.0 <= mu <= MAX_FRICTION:
        t.fail(key, f"must lie in [0, {MAX_FRICTION:g}] (a Coulomb coefficient; beyond it the contact "
                    f"read-outs lose their accuracy), got {mu:g}")
    return float(mu)


def _stripped(top, section: str, kind: str):
    """A _Table over a copy of top's section (the original, shared with the raw data, stays)."""
    value = top.data.get(section)
    if value is None:
        return None
    Table = type(top)
    if kind == "table":
        if not isinstance(value, dict):
            return None                               # skelfem.design reports the type
        t = Table(dict(value), section, top.source)
        top.data[section] = t.data
        return t
    if not isinstance(value, list) or not all(isinstance(e, dict) for e in value):
        return None
    out = []
    for i, e in enumerate(value):
        name = e.get("name")
        label = name if isinstance(name, str) and name else str(i)
        out.append((name, Table(dict(e), f"{section}.{label}", top.source)))
    top.data[section] = [t.data for _, t in out]
    return out


def _pairs(contact, materials: dict, default: Coulomb) -> dict:
    if contact is None or not contact.has("pairs"):
        return {}
    Table = type(contact)
    t = Table(contact.take("pairs", "table"), f"{contact.where}.pairs", contact.source)
    out: dict = {}
    written: dict = {}
    for key in list(t.data):
        names = key.split(":")
        if len(names) != 2 or not all(n in materials for n in names):
            t.fail(f'"{key}"', f"unknown material pair (write \"a:b\" with a, b among {', '.join(materials)})")
        pair = frozenset(names)
        if pair in written:
            t.fail(f'"{key}"', f"the same pair as \"{written[pair]}\" (a pair has no order): give it once")
        written[pair] = key
        value = t.data[key]
        if isinstance(value, dict):
            p = Table(t.take(key, "table"), t.key(f'"{key}"'), t.source)
            c = _coulomb(p, default)
            p.done()
        else:
            mu = coefficient(t, f'"{key}"', t.take(key, "number"))
            c = Coulomb(mu, mu)
        out[pair] = c
    return out


def _objects(top, dim: int, materials: dict, bodies: tuple, read_solids, named_entries) -> tuple:
    tables = named_entries(top, "objects")
    if not tables:
        return ()
    if dim == 2:
        tol = 1e-9 * max(float(np.ptp(np.vstack([b.outline for b in bodies]), axis=0).max()), 1.0)
    else:
        lo, hi = primitives_box([p for b in bodies for p in b.solids])
        tol = 1e-9 * max(float(np.ptp([lo, hi], axis=0).max()), 1.0)
    out = []
    for t in tables:
        name = t.where.split(".", 1)[1]
        if dim == 2:
            if t.has("solids"):
                t.fail("solids", "is for dim = 3 (a 2D object is its outline)")
            outline, solids = t.take("outline", "points", dim=2), ()
            if len(outline) < 3:
                t.fail("outline", "a polygon needs at least 3 points")
            if not polygons.is_simple(outline, tol) or abs(polygons.signed_area(outline)) <= tol:
                t.fail("outline", "polygon is not simple or has zero area")
        else:
            if t.has("outline"):
                t.fail("outline", "is for dim = 2 (a 3D object is its solids)")
            outline, solids = None, read_solids(t, dim, tol)
        material = t.take("material", "str")
        if material not in materials:
            t.fail("material", f"unknown material {material!r} (defined: {', '.join(materials)})")
        rigid = t.take("rigid", "bool", True)
        t.done()
        for section in ("gravity", "dynamics"):
            if top.has(section) and materials[material].density is None:
                top.fail(f"materials.{material}.density", f"missing (required with [{section}]: object {name!r})")
        out.append(ObjectSpec(name, outline, material, rigid, solids))
    _check_apart(tables, out, bodies, dim, tol)
    return tuple(out)


def _check_apart(tables: list, objects: list, bodies: tuple, dim: int, tol: float) -> None:
    """Every object starts clear of the bodies and of the other objects (the first one that does not, in
    the file's order, is refused). Only pieces whose boxes overlap are compared exactly: near-linear in
    the number of objects (it was one exact test per pair: 1000 objects took minutes)."""
    key = "outline" if dim == 2 else "solids"
    clash = _clashes_2d(objects, bodies, tol) if dim == 2 else _clashes_3d(objects, bodies, tol)
    for k, t in enumerate(tables):
        if -1 in clash.get(k, ()):
            t.fail(key, "overlaps the body at rest (an object must start clear of it)")
        others = [m for m in clash.get(k, ()) if 0 <= m < k]
        if others:
            t.fail(key, f"overlaps object {objects[min(others)].name!r} at rest")


def _box_pairs(boxes: np.ndarray):
    """(i, j), i < j, of the (n, 2, dim) boxes that overlap (touching counts)."""
    dim = boxes.shape[2]
    flat = np.concatenate([boxes[:, 0, :2], boxes[:, 1, :2]], axis=1)
    for I, J in polygons.candidate_pairs(flat):
        keep = np.all((boxes[I, 0] <= boxes[J, 1]) & (boxes[J, 0] <= boxes[I, 1]), axis=1) if dim == 3 else \
            np.ones(len(I), bool)
        yield from zip(I[keep].tolist(), J[keep].tolist())


def _clashes_2d(objects: list, bodies: tuple, tol: float) -> dict:
    """{object index: the pieces it overlaps or touches: -1 for a body, else object indices}."""
    loops = polygons.loops_of(bodies)
    nl, nb = len(loops), len(bodies)
    outlines = [o.outline for o in objects]
    clash: dict = {}
    for i, j in polygons.meeting_loops([*loops, *outlines], tol):     # one pass over every edge
        if j >= nl:
            a = -1 if i < nl else i - nl
            clash.setdefault(j - nl, set()).add(a)
            if a >= 0:
                clash.setdefault(a, set()).add(j - nl)
    inside = polygons.region_contains(loops, np.array([o[0] for o in outlines]), tol)
    for k in np.flatnonzero(inside).tolist():
        clash.setdefault(k, set()).add(-1)
    pieces = [b.outline for b in bodies] + outlines      # nested ones: one's first vertex inside the other
    boxes = np.array([[p.min(axis=0) - tol, p.max(axis=0) + tol] for p in pieces])
    for i, j in _box_pairs(boxes):
        for a, b in ((i, j), (j, i)):
            if b >= nb and polygons.contains(pieces[b], pieces[a][:1], tol)[0]:
                o, other = b - nb, (a - nb if a >= nb else -1)
                clash.setdefault(o, set()).add(other)
                if other >= 0:
                    clash.setdefault(other, set()).add(o)
    return clash


def _clashes_3d(objects: list, bodies: tuple, tol: float) -> dict:
    """As _clashes_2d, with OpenCASCADE's common volume of the pieces whose boxes overlap."""
    from .solids import common_volume
    pieces = [b.solids for b in bodies] + [o.solids for o in objects]
    nb = len(bodies)
    boxes = np.array([primitives_box(p) for p in pieces])
    clash: dict = {}
    for i, j in _box_pairs(boxes):
        if j >= nb and common_volume(pieces[j], pieces[i]) > tol:
            a = -1 if i < nb else i - nb
            clash.setdefault(j - nb, set()).add(a)
            if a >= 0:
                clash.setdefault(a, set()).add(j - nb)
    return clash


def take(top, dim: int, materials: dict, bodies: tuple, read_solids, named_entries) -> tuple[FrictionSpec, tuple]:
    """Read (and remove from top's tables) [[objects]] and the friction keys of [contact] and [[grounds]].
    read_solids(table, dim, tol): a 3D object's `solids`, read as the body's (skelfem.design.shapes);
    named_entries(top, section): the entries of a named list, as every [[section]] is read
    (skelfem.design.shapes)."""
    objects = _objects(top, dim, materials, bodies, read_solids, named_entries)
    contact = _stripped(top, "contact", "table")
    default = Coulomb()
    if contact is not None:
        default = _coulomb(contact, default) or default      # never None with a default
    pairs = _pairs(contact, materials, default)
    grounds = {}
    for name, t in _stripped(top, "grounds", "tables") or ():
        c = _coulomb(t, None)
        if c is not None and isinstance(name, str):
            grounds[name] = c
    return FrictionSpec(default, grounds, pairs), objects
