"""fabricate/meshing (from fabricate.py)

Fabrication export: printable bones and a two-part mould from the design that is simulated.

The paper's second pipeline (section III): PLA bones with channels for the
cables, rubber-band ligaments, and a printed two-part mould into which
silicone is cast; section VI.A asks for moulds that fixture the skeleton.
``skelfem fabricate DESIGN`` turns a design into

- ``bone_<name>.stl`` / ``.step``: each bone (2D: its outline extruded over
  ``bone_depth``, centred in the slab) minus a channel of ``channel_diameter``
  along every piece of a tendon's sketch inside it, an anchor hole of
  ``anchor_diameter`` through it (along the mould's normal) where a ligament
  ends in it, and the sockets of the mould's pegs;
- ``mould_bottom.stl`` / ``mould_top.stl`` (and ``.step``): a block around the
  body split by the parting plane (2D: the slab's mid-plane z = thickness/2;
  3D: ``[fabrication] split``), each half minus the body, so that the closed
  cavity is the body; registration pins on the bottom half and holes with
  ``clearance`` in the top, a pour hole and vents through the top, exits for
  the tendons through the wall, and pegs that reach from each half through
  the silicone into sockets in the bones and so hold each bone where the
  design puts it (the fixturing of section VI.A).

Geometry in two passes. A *probe* pass builds the body and the bones with
Gmsh's OpenCASCADE kernel, triangulates their surfaces and plans everything
with numpy on the triangles (rays for the cable crossings, inside tests,
peg and pour sites; exact point-triangle distances for the walls around
channels). Every problem is found there, before any output folder is
touched, and raised as :class:`FabricationError` (key, message). A *build*
pass then makes each part in its own OCC model (boolean cuts and fuses),
measures its volume exactly (``getMass``), triangulates its surface, writes
binary STL and STEP, and checks the STL it wrote (every edge shared by
exactly two triangles, every shared edge used in opposite directions,
positive volume by the divergence theorem).
"""
from __future__ import annotations

import os
import sys
from contextlib import contextmanager

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


