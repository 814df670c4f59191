"""Gmsh for fabrication: quiet runs, surface meshes at a given curvature, triangle surfaces of volumes.
"""
from __future__ import annotations

import os
import sys
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from .surfaces import MIN_EDGE, Surface


# -- Gmsh ----------------------------------------------------------------------------------------------------
@contextmanager
def quiet_gmsh():
    """Send what C++ libraries print on stdout (OpenCASCADE's STEP writer) to /dev/null."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def generate_surface_mesh(gmsh, size: float, curvature: int) -> None:
    """Triangulate every surface of the current model: planar faces coarsely (they are exact anyway),
    curved ones with `curvature` triangles per turn. Gmsh's options are global to the process: the
    previous values are put back, so that later finite-element meshes are not affected."""
    options = {"Mesh.MeshSizeFromCurvature": curvature, "Mesh.MeshSizeMax": size,
               "Mesh.MeshSizeMin": min(MIN_EDGE, size / 4), "Mesh.MeshSizeExtendFromBoundary": 0,
               "Mesh.Algorithm": 5}
    saved = {name: gmsh.option.getNumber(name) for name in options}
    try:
        for name, value in options.items():
            gmsh.option.setNumber(name, value)
        gmsh.model.mesh.generate(2)
    finally:
        for name, value in saved.items():
            gmsh.option.setNumber(name, value)


def triangle_surface(gmsh, volumes) -> Surface:
    """The triangulated closed surface of meshed volumes of the current model, with each triangle's face."""
    faces = gmsh.model.getBoundary([(3, v) for v in volumes], combined=True, oriented=False, recursive=False)
    tags, coords, _ = gmsh.model.mesh.getNodes()
    index = np.zeros(int(tags.max()) + 1, int)
    index[tags.astype(int)] = np.arange(len(tags))
    tris, owner = [], []
    for _, f in faces:
        types, _, nodes = gmsh.model.mesh.getElements(2, abs(f))
        for kind, n in zip(types, nodes):
            if kind == 2:
                t = index[np.asarray(n, int)].reshape(-1, 3)
                tris.append(t), owner.append(np.full(len(t), abs(f)))
    tris = np.concatenate(tris)
    used, inv = np.unique(tris, return_inverse=True)
    return Surface(coords.reshape(-1, 3)[used], inv.reshape(-1, 3), np.concatenate(owner))


def write_file(gmsh, path: Path) -> None:
    """gmsh.write (quiet), whose failures (a full disk: a plain Exception) become the OSError of the file."""
    import errno
    import os
    try:
        with quiet_gmsh():
            gmsh.write(str(path))
    except Exception as exc:  # noqa: BLE001 - Gmsh raises Exception for every failure
        probe = None
        try:                                   # why: the same write from Python names the errno
            with open(path, "ab") as f:
                f.write(b"\0")
                f.flush()
                os.fsync(f.fileno())
        except OSError as err:
            probe = err
        if probe is not None:
            raise probe from None
        raise OSError(errno.EIO, f"Gmsh could not write it ({exc})", str(path)) from None
    if not path.is_file() or path.stat().st_size == 0:
        raise OSError(errno.EIO, "Gmsh wrote nothing", str(path))
