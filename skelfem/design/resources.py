"""How big a design's mesh will be, estimated before Gmsh runs, and a limit.

Gmsh's meshes of the bundled designs have, away from the coarsest sizes,
about 2.4 A / h^2 triangles in 2D (equilateral triangles of edge h: 2.31)
and 6 V / h^3 tetrahedra in 3D, plus a few cells per outline vertex. The
number of unknowns per cell is about 1 (2D P1), 4 (2D P2), 0.65 (3D P1) and
4.3 (3D P2).

The limits are in unknowns (DOFs), what memory and time scale with. In 2D
the direct solver (MUMPS, factors growing like n log n) is the one used and
we allow 4 million DOFs (about 4 million P1 triangles, 1 million P2) on the
machines this project runs on (2 cores, 24 GB). In 3D the limit follows the
memory model of the linear solver the design will use (``planned_linear``:
[solver] linear, "auto" as skelfem.fem.linear.choose_linear picks it):
MUMPS's peak grows like n^(4/3) (``DIRECT_BYTES`` n^(4/3), measured 11.3 GB
at 682k P2 DOFs), multigrid's like n (``ITERATIVE_BYTES`` per DOF at P1 and
P2, measured up to 1.4M DOFs), each plus ``BASE_BYTES``; the limit is the
size whose peak fills ``MEMORY_SHARE`` of the machine's physical memory
(1 million DOFs direct, 6.8 million iterative at P1 on 24 GB). A design over
the limit is refused with the estimate in the message; ``--force`` goes
ahead anyway.
"""
from __future__ import annotations

import math

CELLS_PER_H = {2: 2.4, 3: 6.0}                    # cells per h^2 of area / h^3 of volume
CELLS_PER_VERTEX = {2: 2.0, 3: 4.0}               # outline vertices / primitive corners force cells too
DOFS_PER_CELL = {(2, 1): 1.0, (2, 2): 4.0, (3, 1): 0.65, (3, 2): 4.3}
MAX_DOFS = {2: 4_000_000}               # 2D: the direct solver's limit (3D: memory_limit)
BASE_BYTES = 0.5e9                        # the interpreter, DOLFINx, PETSc and Gmsh themselves
DIRECT_BYTES = 188.0                      # 3D MUMPS: peak bytes per DOF^(4/3) (11.3 GB at 682k P2 DOFs, the most seen)
ITERATIVE_BYTES = {1: 2.9e3, 2: 3.0e3}   # 3D multigrid: peak bytes per DOF at P1 (2.74 KiB = 2.81 KB measured on
#                                           arm3d at 1.43M DOFs), P2 (2.3 KiB on post3d's 682k reference), rounded up
MEMORY_SHARE = 0.8                        # of the machine's physical memory, the most one solve may use

FORCED = False          # set by the command line's --force for the whole process


def estimate(design) -> dict:
    """{"cells": ..., "dofs": ...}: what meshing the design at its [mesh] size would give (roughly).

    Every meshed piece counts: the bodies (holes out, bones in: design.measure) and the objects, rigid
    ones too (they are meshed; an object 400 m wide at h = 4 mm was meshed, the body alone counted)."""
    h = float(design.mesh.size)
    dim = design.dim
    objects = getattr(design, "objects", ())
    measure = float(design.measure or 0.0) + sum(object_measure(o) for o in objects)
    try:
        scale = h ** dim
    except OverflowError:
        scale = math.inf
    cells = CELLS_PER_H[dim] * measure / scale if scale > 0 else math.inf
    cells += CELLS_PER_VERTEX[dim] * (getattr(design, "vertices", 0) + sum(object_vertices(o) for o in objects))
    if not math.isfinite(cells):
        cells = math.inf
    return {"cells": cells, "dofs": cells * DOFS_PER_CELL[(dim, design.mesh.degree)]}


def object_measure(obj) -> float:
    """An object's area (2D, mm^2) or volume (3D, mm^3; the sum of its primitives': overlaps count twice,
    an upper bound)."""
    from . import polygons
    if obj.outline is not None:
        return abs(polygons.signed_area(obj.outline))
    total = 0.0
    for prim in obj.solids:
        (kind, p), = prim.items()
        if kind == "box":
            total += float(math.prod(p["max"] - p["min"]))
        elif kind == "sphere":
            total += 4.0 / 3.0 * math.pi * p["radius"] ** 3
        elif kind == "cylinder":
            total += math.pi * p["radius"] ** 2 * math.dist(p["from"], p["to"])
        else:
            total += abs(polygons.signed_area(p["outline"])) * float(p["z"][1] - p["z"][0])
    return total


def object_vertices(obj) -> int:
    """The outline vertices (2D) or primitive corners (3D) of an object, as design.vertices counts them."""
    if obj.outline is not None:
        return len(obj.outline)
    return sum(len(next(iter(s.values())).get("outline", ())) + 8 for s in obj.solids)


def physical_memory() -> float:
    """This machine's physical memory in bytes (24 GB where it cannot be read)."""
    import os
    try:
        return float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return 24e9


def peak_bytes(dofs: float, linear: str, degree: int) -> float:
    """The memory model: a 3D solve's peak memory (bytes) with the direct or iterative solver."""
    if linear == "direct":
        return BASE_BYTES + DIRECT_BYTES * dofs ** (4.0 / 3.0)
    return BASE_BYTES + ITERATIVE_BYTES[degree] * dofs


def planned_linear(design, dofs: float) -> str:
    """The linear solver a 3D design of about `dofs` unknowns will use (skelfem.fem.linear.choose_linear
    on the estimate)."""
    kind = design.solver.linear
    return auto_linear(design, dofs) if kind == "auto" else kind


def _budget() -> float:
    """The bytes one solve may use beyond BASE_BYTES on this machine."""
    return max(MEMORY_SHARE * physical_memory() - BASE_BYTES, 0.0)


def direct_limit(dim: int) -> float:
    """The most unknowns the direct solver (MUMPS) solves on this machine."""
    return float(MAX_DOFS[2]) if dim == 2 else _budget() ** 0.75 / DIRECT_BYTES ** 0.75


def limit(design, dofs: float) -> tuple[float, str]:
    """(the most unknowns this machine solves for the design, the linear solver that limit is for)."""
    linear = "direct" if design.dim == 2 else planned_linear(design, dofs)
    if linear == "direct":
        return direct_limit(design.dim), linear
    return _budget() / ITERATIVE_BYTES[design.mesh.degree], linear


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
    most, linear = limit(design, est["dofs"])
    if est["dofs"] > most and not force:
        how = "" if design.dim == 2 else (f" with the {linear} solver, "
                                           f"{peak_bytes(most, linear, design.mesh.degree) / 1e9:.0f} GB "
                                           f"of {physical_memory() / 1e9:.0f}")
        raise DesignError(
            f"{design.source}: mesh.size: {design.mesh.size:g} mm gives about {_fmt(est['cells'])} cells and "
            f"{_fmt(est['dofs'])} unknowns at P{design.mesh.degree}, more than this machine solves "
            f"({_fmt(most)} in {design.dim}D{how}); use a larger mesh.size, or --force to try anyway")
    return est


AUTO_ITERATIVE_DOFS = 150_000   # "auto": 3D designs with more unknowns than this solve iteratively
AUTO_MAX_CONTRAST = 100.0       # an elastic bone this many times stiffer than its body is deflated


def stiff_elastic_bones(design) -> list[str]:
    """The elastic bones more than AUTO_MAX_CONTRAST times stiffer than the stiffest body: an iterative
    solve balances its multigrid against their rigid motions (skelfem.fem.linear)."""
    body = max(float(design.materials[b.material].E) for b in design.bodies)
    return [b.name for b in design.bones
            if not b.rigid and float(design.materials[b.material].E) > AUTO_MAX_CONTRAST * body]


def auto_linear(design, dofs: float) -> str:
    """What [solver] linear = "auto" picks for a design of `dofs` unknowns: direct in 2D and for 3D
    designs up to AUTO_ITERATIVE_DOFS (MUMPS is faster there: arm3d with its PLA bones deflated,
    iterative/direct time 1.28 at 119k DOFs, 0.80 at 219k); iterative otherwise
    (skelfem.fem.linear.choose_linear on the model, the size limit on the estimate before meshing)."""
    return "iterative" if design.dim == 3 and dofs > AUTO_ITERATIVE_DOFS else "direct"
