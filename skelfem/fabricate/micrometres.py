"""Printed parts are built in an OpenCASCADE model in micrometres, read and written in millimetres.

Where two round faces meet (a channel through a round bone, a body's cylinder
in a mould's slab) OpenCASCADE's boolean operations approximate the edge by a
spline to about 1e-9 of the part's size, and give the edge that deviation as
its tolerance: 1.1e-7 to 1.7e-7 mm on the bundled arm's parts. A STEP file
cannot carry an edge's tolerance: a reader gives every edge the 1e-7 mm
OpenCASCADE calls confusion, and a CAD program's check (FreeCAD's BOP check)
then finds such an edge off its face (BOPAlgo_InvalidCurveOnSurface). Built
in micrometres the same operations leave edges within 1e-10 to 1.5e-8 mm of
their faces (the arm's parts). A ball's surface degenerates at its poles; a plane through
them (a mould's parting plane through a joint's centre, as arm3d's) leaves an
edge there that such a check finds off its face, and so does a vent drilled
near a pole. A part is built with its balls' poles on the parting plane's
normal first (the plane cuts every ball along a parallel) and, if its
largest tolerance is still beyond READER_TOLERANCE, again with them on z
(files.build; ``pole_axis``).

``MicrometreOCC`` is gmsh.model.occ with every length it takes or returns in
millimetres; ``in_millimetres`` scales the finished part down exactly, to be
triangulated and written as before (Gmsh's surface meshing is slower and
less robust on a model in micrometres); ``largest_tolerance`` reads the
model's tolerances back (from a BREP file, the one format that holds them)
so that every STEP file written is checked against READER_TOLERANCE.
"""
from __future__ import annotations

import re
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from .meshing import write_file

UM_PER_MM = 1000.0
READER_TOLERANCE = 1e-7      # mm: the tolerance a STEP reader gives every vertex, edge and face
Z = np.array([0.0, 0.0, 1.0])     # where OpenCASCADE puts a ball's poles

# gmsh.model.occ's calls that take no lengths (entity tags, and booleans on them), passed through as they are
WITHOUT_LENGTHS = frozenset({"addCurveLoop", "addLine", "addPlaneSurface", "copy", "cut", "fragment", "fuse",
                             "intersect", "remove", "synchronize"})


class MicrometreOCC:
    """gmsh.model.occ for a model in micrometres, spoken to in millimetres: lengths and points scaled on the
    way in, lengths, areas and volumes on the way out. A call that is neither scaled here nor in
    WITHOUT_LENGTHS is refused, so that none takes millimetres for micrometres unnoticed."""

    def __init__(self, occ, pole_axis=Z):
        self.occ = occ
        self.pole_axis = np.asarray(pole_axis, float) / np.linalg.norm(pole_axis)

    def __getattr__(self, name):
        if name in WITHOUT_LENGTHS:
            return getattr(self.occ, name)
        raise AttributeError(f"MicrometreOCC does not scale occ.{name}: add it")

    @staticmethod
    def _um(*lengths) -> list[float]:
        return [UM_PER_MM * float(v) for v in lengths]

    def addPoint(self, x, y, z):                                   # noqa: N802 - Gmsh's names
        return self.occ.addPoint(*self._um(x, y, z))

    def addBox(self, x, y, z, dx, dy, dz):                         # noqa: N802
        return self.occ.addBox(*self._um(x, y, z, dx, dy, dz))

    def addCylinder(self, x, y, z, dx, dy, dz, r):                 # noqa: N802
        return self.occ.addCylinder(*self._um(x, y, z, dx, dy, dz, r))

    def addSphere(self, x, y, z, r):                               # noqa: N802
        """A ball, its poles turned from z to pole_axis about its centre."""
        tag = self.occ.addSphere(*self._um(x, y, z, r))
        k = np.cross(Z, self.pole_axis)              # zero when the axis is +-z: the poles are there already
        if np.linalg.norm(k) > 1e-12:
            angle = float(np.arctan2(np.linalg.norm(k), self.pole_axis[2]))
            self.occ.rotate([(3, tag)], *self._um(x, y, z), *(k / np.linalg.norm(k)), angle)
        return tag

    def extrude(self, dimtags, dx, dy, dz):
        return self.occ.extrude(dimtags, *self._um(dx, dy, dz))

    def translate(self, dimtags, dx, dy, dz):
        return self.occ.translate(dimtags, *self._um(dx, dy, dz))

    def rotate(self, dimtags, x, y, z, ax, ay, az, angle):
        return self.occ.rotate(dimtags, *self._um(x, y, z), ax, ay, az, angle)

    def getMass(self, dim, tag) -> float:                          # noqa: N802
        """Length, area or volume in mm, mm^2 or mm^3."""
        return self.occ.getMass(dim, tag) / UM_PER_MM ** dim

    def getBoundingBox(self, dim, tag) -> tuple:                   # noqa: N802
        return tuple(v / UM_PER_MM for v in self.occ.getBoundingBox(dim, tag))


def in_millimetres(gmsh, scratch: Path) -> list[int]:
    """Replace the current model (in micrometres) by the same shapes in millimetres; returns its volumes.

    A uniform scaling is a similarity: OpenCASCADE keeps every surface and
    curve as it is (Gmsh's dilate would turn them into splines) and scales
    the tolerances with them. Gmsh offers it only when a file is read (its
    option Geometry.OCCScaling), so the model goes through a BREP file at
    scratch (removed after), which holds the shapes exactly."""
    occ = gmsh.model.occ
    occ.synchronize()
    saved = gmsh.option.getNumber("Geometry.OCCScaling")
    try:
        write_file(gmsh, scratch)
        occ.remove(gmsh.model.getEntities(), recursive=True)
        gmsh.option.setNumber("Geometry.OCCScaling", 1.0 / UM_PER_MM)
        out = occ.importShapes(str(scratch), highestDimOnly=True)
    finally:
        gmsh.option.setNumber("Geometry.OCCScaling", saved)
        scratch.unlink(missing_ok=True)
    occ.synchronize()
    return [t for d, t in out if d == 3]


@contextmanager
def scratch_file(folder: Path | None, name: str):
    """A path for a file that lives only during a call: hidden in folder, or in a temporary folder."""
    if folder is not None:
        yield folder / f".{name}"
        return
    import tempfile
    with tempfile.TemporaryDirectory(prefix="skelfem-") as tmp:
        yield Path(tmp) / name


# the tolerances of a BREP file's edges ("Ed" then its tolerance and flags) and faces ("Fa" then a flag and its
# tolerance). Vertices are left out: a STEP reader widens a vertex to the ends of its edges itself (OpenCASCADE's
# booleans leave some at 2^-11 um, with their edges' ends well inside 1e-7 mm), not an edge to its faces.
BREP_TOLERANCE = re.compile(r"^(?:Ed\n\s*|Fa\n\s*\S+\s+)([-+0-9.eE]+)", re.M)


def largest_tolerance(gmsh, scratch: Path) -> float:
    """The largest tolerance of an edge or face of the current model, in its unit: written as a BREP file at
    scratch (removed after)."""
    try:
        write_file(gmsh, scratch)
        text = scratch.read_text()
    finally:
        scratch.unlink(missing_ok=True)
    return max((float(v) for v in BREP_TOLERANCE.findall(text)), default=0.0)
