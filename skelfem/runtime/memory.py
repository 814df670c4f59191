"""Handing freed memory back to the operating system.

glibc keeps the heap memory a big computation freed (Gmsh's mesh
generation, a model's build) for the process's next allocations; where the
pieces are too scattered to be reused whole, they stay resident for the
rest of the run. ``release()`` asks glibc to return what it can
(``malloc_trim``), so a 3D solve's peak memory is what the solve itself
holds (about 0.2 KB per DOF less on arm3d at 118k DOFs). A trim walks the
whole heap (50 ms at 2 GB) and the pages it returns must be faulted in again,
so it is done after big meshes only (``BIG_CELLS``). Elsewhere (another C
library) it does nothing.

Open MPI's initialisation (``MPI_Init``, run when mpi4py or petsc4py is
imported) turns glibc's mapping of big blocks off (an 80 MB array made
after it comes from the heap; one made before it is mapped on its own).
Then every big block (K, the multigrid's levels, the packed coefficients)
comes from the one heap, and the pieces freed between blocks still alive
stay resident: arm3d at 1.43M DOFs peaked at 6.38 GB (4.7 KB per DOF).
``allow_mmap(vector_bytes)`` maps blocks of at least MMAP_VECTORS vectors
again (at least MMAP_BYTES) and trims the heap's top (TRIM_BYTES):
the matrices and packs are mapped on their own and unmapped when freed,
while a solve's vector-sized scratch, made and freed at every Krylov
iteration, stays in the heap. (Mapping everything from 1 MB up cut the
peak a little more but faulted every such scratch in afresh: on arm3d at
364k DOFs 8.5M page faults against 1.05M, 22 s of system time against 7.)
Open MPI's memory hooks still see every unmap, so its registration caches
stay right.
"""
from __future__ import annotations

import ctypes
import ctypes.util
from typing import Any

_LIBC: Any = None
BIG_CELLS = 200_000          # meshes with more cells than this are worth a trim after their build
MMAP_VECTORS = 8             # blocks of this many solution vectors or more are mapped on their own ...
MMAP_BYTES = 1 << 20         # ... and always those of this many bytes
TRIM_BYTES = 8 << 20         # free memory at the top of the heap beyond this goes back at once
MMAP_BLOCKS = 1 << 16        # glibc's default count of blocks it may map (Open MPI sets 0)
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD, _M_MMAP_MAX = -1, -3, -4     # glibc's mallopt parameters


def _libc():
    global _LIBC
    if _LIBC is None:
        try:
            _LIBC = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
            _LIBC.malloc_trim.argtypes = [ctypes.c_size_t]
            _LIBC.mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
        except (OSError, AttributeError):
            _LIBC = False
    return _LIBC


def allow_mmap(vector_bytes: int = 0) -> bool:
    """Blocks of MMAP_VECTORS vectors of vector_bytes (at least MMAP_BYTES) mapped on their own and the
    heap trimmed again, whatever MPI_Init set (after MPI is initialised; the last model built sets the
    size). False where the C library is not glibc."""
    threshold = int(min(max(MMAP_VECTORS * vector_bytes, MMAP_BYTES), 2**31 - 1))
    return bool(_libc() and _LIBC.mallopt(_M_MMAP_MAX, MMAP_BLOCKS) and _LIBC.mallopt(_M_MMAP_THRESHOLD, threshold)
                and _LIBC.mallopt(_M_TRIM_THRESHOLD, TRIM_BYTES))


def release(cells: int) -> None:
    """Return the freed heap memory glibc holds to the operating system, after the build of a mesh of
    `cells` cells (on this rank) if it is a big one."""
    if cells > BIG_CELLS and _libc():
        _LIBC.malloc_trim(0)
