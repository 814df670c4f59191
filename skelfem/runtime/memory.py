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
"""
from __future__ import annotations

import ctypes
import ctypes.util

_LIBC = None
BIG_CELLS = 200_000          # meshes with more cells than this are worth a trim after their build


def release(cells: int) -> None:
    """Return the freed heap memory glibc holds to the operating system, after the build of a mesh of
    `cells` cells (on this rank) if it is a big one."""
    global _LIBC
    if cells <= BIG_CELLS:
        return
    if _LIBC is None:
        try:
            _LIBC = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
            _LIBC.malloc_trim.argtypes = [ctypes.c_size_t]
        except (OSError, AttributeError):
            _LIBC = False
    if _LIBC:
        _LIBC.malloc_trim(0)
