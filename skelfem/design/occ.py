"""Gmsh's OpenCASCADE kernel: one Gmsh per process, models as blocks, and the design's primitives as solids.

Used by the 3D design checks (skelfem.design.solids) before any meshing, by
meshing (skelfem.mesh.geometry) and by fabrication.
"""
from __future__ import annotations

from contextlib import contextmanager

import numpy as np


class MeshingError(RuntimeError):
    """Gmsh could not build or mesh the design's geometry."""


_GMSH_READY = False


def ensure_gmsh(gmsh) -> None:
    """Initialise Gmsh once per process (gmsh 4.8 cannot tell if it is).

    Importing gmsh resets SIGINT to the default action; our interrupt
    handlers are put back afterwards.
    """
    global _GMSH_READY
    from ..runtime import interrupts
    if interrupts.abandoned():
        raise MeshingError("Gmsh is still inside an interrupted call in this process: start a new one")
    if not _GMSH_READY:
        from ..runtime import interrupts
        with interrupts.held():
            gmsh.initialize(readConfigFiles=False)
        gmsh.option.setNumber("General.Terminal", 0)
        # one thread: Gmsh runs in a worker thread (runtime.interrupts.interruptible), where its OpenMP
        # default would otherwise mesh in parallel and number the same mesh differently from run to run
        for name in ("General.NumThreads", "Mesh.MaxNumThreads1D", "Mesh.MaxNumThreads2D", "Mesh.MaxNumThreads3D"):
            gmsh.option.setNumber(name, 1)
        _GMSH_READY = True
    from ..runtime import interrupts
    interrupts.reinstall()


@contextmanager
def gmsh_model(name: str):
    """A fresh Gmsh model for the duration of the block (this rank only); removed after."""
    from ..runtime.interrupts import import_gmsh
    gmsh = import_gmsh()
    ensure_gmsh(gmsh)
    with forget_array_types():
        gmsh.model.add(name)
        try:
            yield gmsh.model
        finally:
            gmsh.model.remove()


@contextmanager
def forget_array_types():
    """Drop the ctypes array types Gmsh's Python API made in the block, once nothing uses them.

    gmsh.py hands out arrays through numpy.ctypeslib.as_array, which makes a ctypes
    array type for each length and ctypes.POINTER keeps it (and its pointer type) in
    a process-wide cache for ever: every re-meshing left a few distinct lengths there,
    60-120 KB per edit of finger.toml. Arrays still alive keep their types.
    """
    import ctypes
    cache = ctypes._pointer_type_cache
    before = set(cache)
    try:
        yield
    finally:
        for key in [k for k in list(cache) if k not in before and isinstance(k, type)
                    and issubclass(k, ctypes.Array)]:
            cache.pop(key, None)


def add_polygon(occ, points) -> int:
    """OCC plane surface from a closed polygon (n, 2); returns its tag."""
    pts = [occ.addPoint(float(x), float(y), 0.0) for x, y in points]
    lines = [occ.addLine(pts[i], pts[(i + 1) % len(pts)]) for i in range(len(pts))]
    return occ.addPlaneSurface([occ.addCurveLoop(lines)])


def add_solid(occ, primitive: dict) -> int:
    """OCC volume from one 3D primitive of the design format (placed by its "pose", if any); returns its tag."""
    from .pose import apply
    (kind, p), = primitive.items()
    tag = _add_primitive(occ, kind, p)
    apply(occ, tag, p.get("pose"))
    return tag


def _add_primitive(occ, kind: str, p: dict) -> int:
    if kind == "box":
        lo, hi = np.asarray(p["min"], float), np.asarray(p["max"], float)
        return occ.addBox(*lo, *(hi - lo))
    if kind == "cylinder":
        a, b = np.asarray(p["from"], float), np.asarray(p["to"], float)
        return occ.addCylinder(*a, *(b - a), float(p["radius"]))
    if kind == "sphere":
        return occ.addSphere(*np.asarray(p["center"], float), float(p["radius"]))
    if kind == "extrude":
        z0, z1 = (float(z) for z in p["z"])
        pts = [occ.addPoint(float(x), float(y), z0) for x, y in p["outline"]]
        lines = [occ.addLine(pts[i], pts[(i + 1) % len(pts)]) for i in range(len(pts))]
        surface = occ.addPlaneSurface([occ.addCurveLoop(lines)])
        out = occ.extrude([(2, surface)], 0, 0, z1 - z0)
        return next(tag for dim, tag in out if dim == 3)
    raise MeshingError(f"unknown solid primitive {kind!r}")


def fuse(occ, dim: int, tags: list[int]) -> list[int]:
    if len(tags) == 1:
        return tags
    out, _ = occ.fuse([(dim, tags[0])], [(dim, t) for t in tags[1:]])
    # Gmsh 4.8's fuse can list a disjoint piece twice (the same volume under
    # two tags): meshing both would overlap elements. Keep one of each.
    seen, keep = set(), []
    for d, t in out:
        sig = tuple(np.round(occ.getBoundingBox(d, t), 6)) + (round(occ.getMass(d, t), 6),)
        if sig in seen:
            occ.remove([(d, t)])
            continue
        seen.add(sig)
        keep.append(t)
    return keep
