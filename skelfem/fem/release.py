"""Releasing the PETSc objects of a model that is dropped (a re-meshing edit makes a new one)."""
from __future__ import annotations

from petsc4py import PETSc


def release_vectors(model) -> None:
    """Destroy the PETSc objects of a model being dropped: DOLFINx's Function.vector wrappers and
    the vectors and matrices its terms hold.

    Python's collection of them destroys nothing: petsc4py 3.18 parks collected
    objects until a collective ``PETSc.garbage_cleanup`` on their own
    communicator (the mesh's duplicate, gone with the mesh), and DOLFINx's
    wrapper of a function's array is never freed; every re-meshing edit left
    ~65 KB of vectors in PETSc on finger.toml. Call it only on a model no
    longer used (a Function's wrapper is made again on access, but a term's
    vectors are not).
    """
    from dolfinx import fem
    seen, stack = set(), [(model, 0)]
    while stack:                           # the model, its terms and what they hold, a few levels down
        obj, depth = stack.pop()
        if obj is None or id(obj) in seen or depth > 5:
            continue
        seen.add(id(obj))
        if isinstance(obj, fem.Function):
            wrapped = getattr(obj, "_petsc_x", None)   # DOLFINx's PETSc Vec over the array, made on first use
            if wrapped is not None:
                wrapped.destroy()
                obj._petsc_x = None
            continue
        if isinstance(obj, PETSc.Object):       # vectors and matrices the terms made (rank-one parts...)
            obj.destroy()
            continue
        if isinstance(obj, dict):
            items = list(obj.values())
        elif isinstance(obj, (list, tuple)):
            items = list(obj)
        elif type(obj).__module__.startswith("skelfem.") and hasattr(obj, "__dict__"):
            items = list(vars(obj).values())
        else:
            continue
        stack.extend((v, depth + 1) for v in items)
