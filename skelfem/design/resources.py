"""How big a design's mesh will be, estimated before Gmsh runs, and a limit.

Gmsh's meshes of the bundled designs have, away from the coarsest sizes,
about 2.4 A / h^2 triangles in 2D (equilateral triangles of edge h: 2.31)
and 6 V / h^3 tetrahedra in 3D, plus a few cells per outline vertex. The
number of unknowns per cell is about 1 (2D P1), 4 (2D P2), 0.65 (3D P1) and
4.3 (3D P2).

The limits are in unknowns (DOFs), what memory and time scale with: MUMPS's
factors grow like n log n in 2D but like n^(4/3) in 3D. On the machines this
project runs on (2 cores, 24 GB) we allow 4 million DOFs in 2D (about 4
million P1 triangles, 1 million P2) and 1 million in 3D (about 1.5 million
P1 tetrahedra, 230 thousand P2). A design over the limit is refused with
the estimate in the message; ``--force`` goes ahead anyway.
"""
from __future__ import annotations

import math

CELLS_PER_H = {2: 2.4, 3: 6.0}                    # cells per h^2 of area / h^3 of volume
CELLS_PER_VERTEX = {2: 2.0, 3: 4.0}               # outline vertices / primitive corners force cells too
DOFS_PER_CELL = {(2, 1): 1.0, (2, 2): 4.0, (3, 1): 0.65, (3, 2): 4.3}
MAX_DOFS = {2: 4_000_000, 3: 1_000_000}

FORCED = False          # set by the command line's --force for the whole process


def estimate(design) -> dict:
    """{"cells": ..., "dofs": ...}: what meshing the design at its [mesh] size would give (roughly)."""
    h = float(design.mesh.size)
    dim = design.dim
    measure = float(design.measure or 0.0)
    try:
        scale = h ** dim
    except OverflowError:
        scale = math.inf
    cells = CELLS_PER_H[dim] * measure / scale if scale > 0 else math.inf
    cells += CELLS_PER_VERTEX[dim] * getattr(design, "vertices", 0)
    if not math.isfinite(cells):
        cells = math.inf
    return {"cells": cells, "dofs": cells * DOFS_PER_CELL[(dim, design.mesh.degree)]}


def _fmt(x: float) -> str:
    if not math.isfinite(x):
        return "more than 1e300"
    if x >= 1e9:
        return f"{x:.2g}"
    if x >= 1e6:
        return f"{x / 1e6:.3g} million"
    return f"{x:,.0f}"


def check(design, force: bool | None = None) -> dict:
    """Refuse (DesignError naming mesh.size) a mesh estimated beyond the limit, unless forced."""
    from .spec import DesignError

    est = estimate(design)
    if force is None:
        force = FORCED
    limit = MAX_DOFS[design.dim]
    if est["dofs"] > limit and not force:
        raise DesignError(
            f"{design.source}: mesh.size: {design.mesh.size:g} mm gives about {_fmt(est['cells'])} cells and "
            f"{_fmt(est['dofs'])} unknowns at P{design.mesh.degree}, more than this machine solves "
            f"({_fmt(limit)} in {design.dim}D); use a larger mesh.size, or --force to try anyway")
    return est
