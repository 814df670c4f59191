"""3D designs checked with Gmsh's OpenCASCADE kernel before anything is meshed.

One Gmsh model holds every primitive of the body and the bones, fragmented
together (no meshing): the pieces say which parts of space belong to the
body and to which bones, and the shared faces, edges and corners say what
touches what. From them:

- a bone must lie inside the body (no piece of it outside) and strictly so
  (none of its faces, edges or corners on the body's surface);
- two bones must neither overlap (a piece in both) nor touch (a shared
  face, edge or corner);
- the body's pieces, joined through shared faces, form parts; when there are
  several, each needs a pin whose box catches its surface;
- cable segments must run inside the body or on its surface (the segment is
  intersected with the pieces and the covered length compared with its
  length), markers and load points must lie in it.

The first problem found is returned as (key, message); design.py turns it
into the usual one-line error. Results are cached by geometry, so
re-validating a design whose parameters change costs nothing.
"""
from __future__ import annotations

import hashlib
import json
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

_CACHE: OrderedDict = OrderedDict()
_CACHE_SIZE = 16


@dataclass
class Check:
    volume: float                 # body volume, mm^3 (bones included)
    error: tuple | None = None    # (key, message) of the first problem, or None


def _add(occ, primitive: dict) -> int:
    from .occ import add_solid
    return add_solid(occ, primitive)


def _key(*parts) -> str:
    def plain(v):
        if isinstance(v, np.ndarray):
            return v.tolist()
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        return v
    return hashlib.sha256(json.dumps(plain(parts), sort_keys=True).encode()).hexdigest()


def check(body_solids, bones, cables, markers, loads, pins, tol: float) -> Check:
    """Check a 3D layout; bones: [(name, solids)], cables: [(name, path)], markers: {name: X},
    loads: [(name, at)], pins: [(name, region)]."""
    key = _key(body_solids, bones, cables, markers, loads, pins, tol)
    if key in _CACHE:
        _CACHE.move_to_end(key)
        return _CACHE[key]
    from ..runtime.interrupts import import_gmsh
    gmsh = import_gmsh()

    from .occ import gmsh_model
    try:
        with gmsh_model("skelfem-check"):
            result = _check(gmsh, body_solids, bones, pins, tol)
        if result.error is None:
            with gmsh_model("skelfem-check-inside"):
                result.error = _inside(gmsh, body_solids, cables, markers, loads, tol)
    except Exception as exc:      # the kernel refused the geometry itself
        result = Check(0.0, ("body.solids", f"the geometry kernel could not build the solids "
                                            f"({str(exc) or type(exc).__name__})"))
    _CACHE[key] = result
    if len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)
    return result


def common_volume(a, b) -> float:
    """The volume (mm^3) two unions of primitives share: 0 if they lie apart or only touch."""
    key = _key("common", a, b)
    if key in _CACHE:
        return _CACHE[key]
    from ..runtime.interrupts import import_gmsh
    gmsh = import_gmsh()

    from .occ import gmsh_model
    with gmsh_model("skelfem-common"):
        occ = gmsh.model.occ
        out, _ = occ.intersect([(3, _add(occ, s)) for s in a], [(3, _add(occ, s)) for s in b])
        occ.synchronize()
        volume = float(sum(occ.getMass(3, t) for d, t in out if d == 3))
    _CACHE[key] = volume
    if len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)
    return volume


def touching(a, b, tol: float) -> str | None:
    """"overlaps" or "touches" if two unions of primitives share volume, or a face, edge or corner;
    None if they lie apart."""
    if common_volume(a, b) > tol:
        return "overlaps"
    key = _key("touching", a, b)
    if key not in _CACHE:
        from ..runtime.interrupts import import_gmsh
        gmsh = import_gmsh()

        from .occ import gmsh_model
        with gmsh_model("skelfem-touching"):
            occ = gmsh.model.occ
            pa, pb = [(3, _add(occ, s)) for s in a], [(3, _add(occ, s)) for s in b]
            _, children = occ.fragment(pa, pb)
            occ.synchronize()
            kids = [{t for d, t in c if d == 3} for c in children]
            ka, kb = set().union(*kids[:len(pa)]), set().union(*kids[len(pa):])
            _CACHE[key] = bool(_closure(gmsh, ka) & _closure(gmsh, kb))
    return "touches" if _CACHE[key] else None


def _boundary(gmsh, dimtags) -> set:
    if not dimtags:
        return set()
    return set(gmsh.model.getBoundary(list(dimtags), combined=False, oriented=False, recursive=False))


def _closure(gmsh, volumes) -> set:
    """Faces, edges and corners of the given volumes."""
    faces = _boundary(gmsh, [(3, v) for v in volumes])
    edges = _boundary(gmsh, faces)
    corners = _boundary(gmsh, edges)
    return faces | edges | corners


def _where(gmsh, volumes) -> str:
    box = np.array([gmsh.model.occ.getBoundingBox(3, v) for v in volumes])
    c = 0.5 * (box[:, :3].min(axis=0) + box[:, 3:].max(axis=0))
    return "(" + ", ".join(f"{x:g}" for x in c) + ")"


def _check(gmsh, body_solids, bones, pins, tol) -> Check:
    occ = gmsh.model.occ
    body_prims = [_add(occ, s) for s in body_solids]
    bone_prims = [[_add(occ, s) for s in solids] for _, solids in bones]
    objects = [(3, t) for t in body_prims] + [(3, t) for ts in bone_prims for t in ts]
    if len(objects) > 1:
        _, children = occ.fragment(objects[:1], objects[1:])
    else:
        children = [[objects[0]]]
    occ.synchronize()
    kids = [{t for d, t in c if d == 3} for c in children]
    body = set().union(*kids[:len(body_prims)])
    volume = float(sum(occ.getMass(3, v) for v in body))
    bone_sets, i = [], len(body_prims)
    for ts in bone_prims:
        bone_sets.append(set().union(*kids[i:i + len(ts)]) if ts else set())
        i += len(ts)
    everything = body.union(*bone_sets)

    # faces of exactly one piece make the outer surface
    face_count: dict = {}
    for v in everything:
        for f in _boundary(gmsh, [(3, v)]):
            face_count[f] = face_count.get(f, 0) + 1
    outer_faces = {f for f, n in face_count.items() if n == 1}
    outer_edges = _boundary(gmsh, outer_faces)
    outer = outer_faces | outer_edges | _boundary(gmsh, outer_edges)

    closures: list = []
    for (name, _), pieces in zip(bones, bone_sets):
        where = f"bones.{name}.solids"
        if not pieces <= body:
            return Check(volume, (where, f"a bone must lie strictly inside the body: part of it, around "
                                         f"{_where(gmsh, sorted(pieces - body))}, is outside"))
        closure = _closure(gmsh, pieces)
        if closure & outer:
            return Check(volume, (where, "a bone must lie strictly inside the body: it touches the body's surface"))
        for (other, _), other_pieces, other_closure in zip(bones, bone_sets, closures):
            if pieces & other_pieces:
                return Check(volume, (where, f"overlaps bone {other!r}"))
            if closure & other_closure:
                return Check(volume, (where, f"touches bone {other!r} (bones must be separated by silicone)"))
        closures.append(closure)

    # parts of the body: pieces joined through shared faces
    parts = _components(gmsh, sorted(everything))
    if len(parts) > 1:
        caught = _pinned_parts(gmsh, parts, outer_faces, pins, tol)
        for part, ok in zip(parts, caught):
            if not ok:
                return Check(volume, ("body.solids", f"the body falls apart into {len(parts)} pieces and the one "
                                                     f"around {_where(gmsh, part)} has no pin (no [[pins]] "
                                                     f"region catches its surface)"))

    return Check(volume, None)


def _components(gmsh, volumes) -> list:
    parent = {v: v for v in volumes}

    def find(v):
        while parent[v] != v:
            parent[v] = parent[parent[v]]
            v = parent[v]
        return v
    by_face: dict = {}
    for v in volumes:
        for f in _boundary(gmsh, [(3, v)]):
            by_face.setdefault(f, []).append(v)
    for vs in by_face.values():
        for w in vs[1:]:
            parent[find(w)] = find(vs[0])
    groups: dict = {}
    for v in volumes:
        groups.setdefault(find(v), []).append(v)
    return sorted(groups.values(), key=min)


def _pinned_parts(gmsh, parts, outer_faces, pins, tol) -> list:
    occ = gmsh.model.occ
    part_of = {v: i for i, part in enumerate(parts) for v in part}
    faces_of: list[set] = [set() for _ in parts]
    for v, i in part_of.items():
        faces_of[i] |= _boundary(gmsh, [(3, v)]) & outer_faces
    caught = [False] * len(parts)
    for _, region in pins:
        lo = np.asarray(region[0], float) - tol
        hi = np.asarray(region[1], float) + tol
        for i, faces in enumerate(faces_of):
            if caught[i]:
                continue
            near = []
            for f in faces:
                b = np.asarray(occ.getBoundingBox(*f))
                if np.all(b[:3] <= hi) and np.all(b[3:] >= lo):
                    near.append(f)
            if not near:
                continue
            box = occ.addBox(*lo, *(hi - lo))
            _, hit = occ.intersect(near, [(3, box)], removeObject=False, removeTool=True)
            caught[i] = any(hit)
    return caught


def _inside(gmsh, body_solids, cables, markers, loads, tol):
    """Cable segments, markers and load points inside the body (or on its surface).

    Tested against the body's primitives fused into one solid (intersecting
    with the many pieces of the fragment is ten times slower).
    """
    occ = gmsh.model.occ
    if not (cables or markers or loads):
        return None
    from .occ import fuse
    volumes = fuse(occ, 3, [_add(occ, s) for s in body_solids])
    objects, what = [], []
    for name, path in cables:
        path = np.asarray(path, float)
        for k, (a, b) in enumerate(zip(path[:-1], path[1:])):
            line = occ.addLine(occ.addPoint(*a), occ.addPoint(*b))
            objects.append((1, line))
            what.append(("cable", name, k, a, b))
    for name, X in markers.items():
        objects.append((0, occ.addPoint(*np.asarray(X, float))))
        what.append(("marker", name, None, X, None))
    for name, at in loads:
        objects.append((0, occ.addPoint(*np.asarray(at, float))))
        what.append(("load", name, None, at, None))
    if not objects:
        return None
    _, pieces = occ.intersect(objects, [(3, v) for v in volumes], removeObject=True, removeTool=False)
    occ.synchronize()
    for (kind, name, k, a, b), got in zip(what, pieces):
        if kind == "marker" and not got:
            return (f"markers.{name}", "the marker lies outside the body")
        if kind == "load" and not got:
            return (f"loads.{name}.at", "the load point lies outside the body")
        if kind == "cable":
            a, b = np.asarray(a, float), np.asarray(b, float)
            length = float(np.linalg.norm(b - a))
            covered = _covered(gmsh, [t for d, t in got if d == 1], a, b)
            if covered < length - max(10 * tol, 1e-6 * length):
                return (f"cables.{name}.path", f"the cable leaves the body (it must run inside it or on its "
                                               f"surface): segment {k + 1} from {_pt(a)} to {_pt(b)} has "
                                               f"{length - covered:.3g} mm outside")
    return None


def _pt(x) -> str:
    return "(" + ", ".join(f"{v:g}" for v in x) + ")"


def _covered(gmsh, curves, a, b) -> float:
    """Length of segment a->b covered by the given straight pieces of it (their union)."""
    if not curves:
        return 0.0
    d = b - a
    dd = float(d @ d)
    spans = []
    for c in curves:
        ends = gmsh.model.getBoundary([(1, c)], combined=False, oriented=False)
        ts = [float((np.asarray(gmsh.model.getValue(0, t, [])) - a) @ d / dd) for _, t in ends]
        if len(ts) == 2:
            spans.append(sorted(ts))
    if not spans:
        return 0.0
    spans.sort()
    total, (s0, s1) = 0.0, spans[0]
    for t0, t1 in spans[1:]:
        if t0 > s1:
            total += s1 - s0
            s0, s1 = t0, t1
        else:
            s1 = max(s1, t1)
    total += s1 - s0
    return total * np.sqrt(dd)
