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
imported) turns glibc's mmap of big blocks off and its heap trimming off
(``mallopt(M_MMAP_MAX, 0)``, ``M_TRIM_THRESHOLD = -1``), for the memory
registration of network cards. Then every big block (K, the multigrid's
levels, work vectors) comes from the one heap and nothing freed goes back:
the pieces left between blocks that are still alive stay resident. On arm3d
at 364k DOFs that was 0.9 KB per DOF of a 4.6 KB peak. ``allow_mmap()``
puts mmap and trimming back (``MMAP_BYTES``, ``TRIM_BYTES``); the models
call it when they are built. Open MPI's memory hooks still see every unmap,
so its registration caches stay right.
"""
from __future__ import annotations

import ctypes
import ctypes.util

_LIBC = None
BIG_CELLS = 200_000          # meshes with more cells than this are worth a trim after their build
MMAP_BYTES = 1 << 20         # blocks this big or bigger are mapped on their own and unmapped when freed
TRIM_BYTES = 8 << 20         # free memory at the top of the heap beyond this goes back at once
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD, _M_MMAP_MAX = -1, -3, -4     # glibc's mallopt parameters
_MMAP_ALLOWED = False


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


def allow_mmap() -> bool:
    """Big blocks mapped on their own and the heap trimmed again, whatever MPI_Init set (once per process,
    after MPI is initialised). False where the C library is not glibc."""
    global _MMAP_ALLOWED
    if not _MMAP_ALLOWED and _libc():
        _MMAP_ALLOWED = bool(_LIBC.mallopt(_M_MMAP_MAX, 1 << 16) and _LIBC.mallopt(_M_MMAP_THRESHOLD, MMAP_BYTES)
                             and _LIBC.mallopt(_M_TRIM_THRESHOLD, TRIM_BYTES))
    return _MMAP_ALLOWED


def release(cells: int) -> None:
    """Return the freed heap memory glibc holds to the operating system, after the build of a mesh of
    `cells` cells (on this rank) if it is a big one."""
    if cells > BIG_CELLS and _libc():
        _LIBC.malloc_trim(0)
