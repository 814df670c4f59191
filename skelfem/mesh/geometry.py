"""Design outlines -> Gmsh model -> tagged DOLFINx mesh.

The body (outline minus holes) and the bones are fragmented with the OCC
kernel, so the triangulation conforms to every bone boundary. Physical groups
carry the design's names: ``body`` for the silicone and ``bone:<name>`` for
each bone. Only rank 0 talks to Gmsh; gmshio distributes the mesh.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from mpi4py import MPI

if TYPE_CHECKING:
    from dolfinx import mesh as dmesh

from ..runtime import interrupts, memory
from ..design.occ import MeshingError, add_polygon, add_solid, ensure_gmsh, forget_array_types, fuse, gmsh_model  # noqa: F401

BODY = "body"


def body_tag_name(body) -> str:
    """The region of a soft body: "body" for a design's one [body], "body:<name>" for [[bodies]]."""
    return BODY if body.name == BODY else f"{BODY}:{body.name}"


def body_tag_names(design) -> list[str]:
    return [body_tag_name(b) for b in design.bodies]


def body_tags(tm: "TaggedMesh", design) -> list[int]:
    """The integer cell tags of the design's soft bodies."""
    return [tm.tags[name] for name in body_tag_names(design)]


def body_box(tm: "TaggedMesh", design) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) corners of the box around the soft bodies' cells (bones lie inside them; objects,
    which are not the robot, do not count), over every rank: what "the body's size" means."""
    mesh, gdim = tm.mesh, tm.mesh.geometry.dim
    cells = tm.cell_tags.indices[np.isin(tm.cell_tags.values, body_tags(tm, design))]
    dofmap = mesh.geometry.dofmap
    nodes = np.unique(dofmap.array.reshape(len(dofmap.offsets) - 1, -1)[cells])
    x = mesh.geometry.x[nodes, :gdim]
    lo = x.min(axis=0) if len(x) else np.full(gdim, np.inf)
    hi = x.max(axis=0) if len(x) else np.full(gdim, -np.inf)
    if mesh.comm.size > 1:
        mesh.comm.Allreduce(MPI.IN_PLACE, lo, op=MPI.MIN)
        mesh.comm.Allreduce(MPI.IN_PLACE, hi, op=MPI.MAX)
    return lo, hi


def bone_tag_name(name: str) -> str:
    return f"bone:{name}"


def object_tag_name(name: str) -> str:
    return f"object:{name}"


def region_names(design) -> tuple:
    """The names of the mesh's cell regions for design, in order: its bodies, bones and objects. A mesh
    serves another design only if these are the same (a renamed bone has no region of its own)."""
    return tuple(body_tag_names(design)) + tuple(bone_tag_name(b.name) for b in design.bones) \
        + tuple(object_tag_name(o.name) for o in design.objects)


@dataclass
class TaggedMesh:
    """A DOLFINx mesh with its cell tags and the names of the tags."""

    mesh: dmesh.Mesh
    cell_tags: Any                   # dolfinx MeshTags (its stub lists no find, indices, values)
    tags: dict          # physical name -> integer tag, e.g. {"body": 1, "bone:proximal": 2}

    @property
    def names(self) -> dict:
        return {v: k for k, v in self.tags.items()}



def add_design_solids(occ, design, bone_depth: float | None = None, bones=None,
                      body: bool = True) -> tuple[list[int], dict]:
    """The design's body and bones as separate OCC volumes (not fragmented): (body tags, {bone: tags}).

    2D outlines are extruded along z: the body (outline minus holes) through
    [0, thickness], each bone over bone_depth centred in the slab. 3D solids
    are the unions of their primitives. bones: the names to build (default all);
    body = False builds no body (its tags are then []): a model that is written
    whole, as a bone's STEP file, must hold the bone alone.
    Used by skelfem.fabricate, which needs the solids themselves, not a mesh.
    """
    wanted = [b for b in design.bones if bones is None or b.name in bones]
    if not body:
        return [], _bone_solids(occ, design, wanted, bone_depth)
    if design.dim == 3:
        solids = fuse(occ, 3, [add_solid(occ, s) for s in design.body.solids])
        return solids, _bone_solids(occ, design, wanted, bone_depth)
    t = float(design.thickness)
    solids = [add_solid(occ, {"extrude": {"outline": design.body.outline, "z": [0.0, t]}})]
    if design.body.holes:
        holes = [(3, add_solid(occ, {"extrude": {"outline": h, "z": [-1.0, t + 1.0]}})) for h in design.body.holes]
        out, _ = occ.cut([(3, solids[0])], holes)
        solids = [tag for d, tag in out if d == 3]
    return solids, _bone_solids(occ, design, wanted, bone_depth)


def _bone_solids(occ, design, wanted: list, bone_depth: float | None) -> dict:
    if design.dim == 3:
        return {b.name: fuse(occ, 3, [add_solid(occ, s) for s in b.solids]) for b in wanted}
    t = float(design.thickness)
    z0 = 0.5 * (t - float(bone_depth if bone_depth is not None else t))
    return {b.name: [add_solid(occ, {"extrude": {"outline": b.outline, "z": [z0, t - z0]}})] for b in wanted}


def _build_model(gmsh, design) -> dict:
    """Create the geometry in the current Gmsh model; returns name -> entity tags."""
    occ = gmsh.model.occ
    dim = design.dim
    bodies = {}                                         # region name -> OCC entities (bodies lie apart)
    for b in design.bodies:
        if dim == 2:
            body = [add_polygon(occ, b.outline)]
            if b.holes:
                holes = [(2, add_polygon(occ, h)) for h in b.holes]
                out, _ = occ.cut([(2, body[0])], holes)
                body = [t for _, t in out]
        else:
            body = fuse(occ, 3, [add_solid(occ, s) for s in b.solids])
        bodies[body_tag_name(b)] = body
    if dim == 2:
        bones = {b.name: [add_polygon(occ, b.outline)] for b in design.bones}
    else:
        bones = {b.name: fuse(occ, 3, [add_solid(occ, s) for s in b.solids])
                 for b in design.bones}
    objects = {object_tag_name(o.name): [add_polygon(occ, o.outline)] if dim == 2          # apart
               else fuse(occ, 3, [add_solid(occ, s) for s in o.solids]) for o in design.objects}
    bone_list = [(name, t) for name, tags in bones.items() for t in tags]
    if not bone_list:
        occ.synchronize()
        return {**bodies, **objects}
    body_list = [(name, t) for name, tags in bodies.items() for t in tags]
    _, children = occ.fragment([(dim, t) for _, t in body_list], [(dim, t) for _, t in bone_list])
    occ.synchronize()
    groups: dict = {bone_tag_name(name): [] for name in bones}
    for (name, _), kids in zip(bone_list, children[len(body_list):]):
        groups[bone_tag_name(name)] += [t for _, t in kids]
    in_bones = {t for tags in groups.values() for t in tags}
    for name in bodies:
        groups[name] = sorted({t for (owner, _), kids in zip(body_list, children[:len(body_list)])
                               if owner == name for _, t in kids} - in_bones)
    return {**groups, **objects}


@dataclass
class SizeField:
    """A mesh size in mm, linear on each of a set of simplices (e.g. the cells of an earlier mesh).

    corners: (n, dim + 1, dim) vertex coordinates of the simplices; values:
    (n, dim + 1) the size at each vertex. Gmsh reads it as a background
    mesh (a list-based post-processing view, ``ST`` or ``SS``, and a
    ``PostView`` field), which it interpolates in C++: no Python call per
    point. Where no simplex contains a point, Gmsh uses the design's size.
    Only rank 0 needs it (only rank 0 meshes).
    """

    corners: np.ndarray
    values: np.ndarray

    @property
    def smallest(self) -> float:
        return float(np.min(self.values))

    def scaled(self, factor: float) -> "SizeField":
        """The same field times factor (a uniformly finer or coarser mesh of the same grading)."""
        return SizeField(self.corners, self.values * float(factor))

    def _view_data(self) -> tuple[str, int, list]:
        n, k, dim = self.corners.shape
        xyz = np.zeros((n, 3, k))
        xyz[:, :dim, :] = np.transpose(self.corners, (0, 2, 1))      # x of every vertex, then y, then z
        data = np.concatenate([xyz.reshape(n, 3 * k), self.values.reshape(n, k)], axis=1)
        return ("ST" if dim == 2 else "SS"), n, data.ravel().tolist()


@dataclass
class ZoneField:
    """A mesh of size `outer` with finer zones: size `inner` within `radii` of each of `centers`, growing
    linearly to `outer` over `thickness` beyond (Gmsh Ball fields, evaluated in C++).

    scaled(f) multiplies the sizes and keeps the zones' extent, so the meshes of
    zones.scaled(f) for f = 1, 1/2, 1/4 are one family of meshes whose every
    local size halves (what Richardson extrapolation needs).
    """

    centers: np.ndarray      # (n, dim) mm
    radii: np.ndarray        # (n,) mm: the fine zones
    inner: np.ndarray        # (n,) mm: the size inside them
    outer: float             # mm: the size far from them
    thickness: float | np.ndarray   # mm: the width of the transition (one, or one per zone)

    @classmethod
    def around(cls, centers, radii, inner, outer: float, grading: float = 0.3) -> "ZoneField":
        """Zones whose size grows from inner to outer by `grading` mm per mm beyond their radii."""
        inner = np.minimum(np.asarray(inner, dtype=float), outer)
        return cls(np.asarray(centers, dtype=float).reshape(len(inner), -1), np.asarray(radii, dtype=float),
                   inner, float(outer), float((outer - inner.min()) / grading))

    @property
    def smallest(self) -> float:
        return float(min(self.inner.min(), self.outer))

    def scaled(self, factor: float) -> "ZoneField":
        f = float(factor)
        return ZoneField(self.centers, self.radii, self.inner * f, self.outer * f, self.thickness)

    def at(self, points) -> np.ndarray:
        """The size at points (n, >= dim) mm, as Gmsh evaluates it: the smallest of the Ball fields (inner
        within a zone's radius, growing linearly to outer over its transition width, outer beyond)."""
        x = np.asarray(points, dtype=float)[:, :self.centers.shape[1]]
        width = np.maximum(np.broadcast_to(np.asarray(self.thickness, dtype=float), self.radii.shape), 1e-300)
        chunk = max(1, 2_000_000 // max(1, len(self.radii)))                  # (chunk, zones) at a time
        out = np.empty(len(x))
        for i in range(0, len(x), chunk):
            dist = np.linalg.norm(x[i:i + chunk, None, :] - self.centers[None, :, :], axis=2)
            t = np.clip((dist - self.radii) / width, 0.0, 1.0)
            out[i:i + chunk] = np.min(self.inner + t * (self.outer - self.inner), axis=1, initial=self.outer)
        return out

    def merged(self, other: "ZoneField | None") -> "ZoneField":
        """The zones of both fields (same outer size), each with its own transition width."""
        if other is None:
            return self
        n, m = len(self.radii), len(other.radii)
        widths = [np.broadcast_to(self.thickness, (n,)), np.broadcast_to(other.thickness, (m,))]
        return ZoneField(np.vstack([self.centers, other.centers]), np.concatenate([self.radii, other.radii]),
                         np.concatenate([self.inner, other.inner]), self.outer, np.concatenate(widths))


def _apply_zones(gmsh, zones: ZoneField) -> list[int]:
    balls = []
    thickness = np.broadcast_to(np.asarray(zones.thickness, dtype=float), zones.radii.shape)
    for c, radius, inner, width in zip(zones.centers, zones.radii, zones.inner, thickness):
        ball = gmsh.model.mesh.field.add("Ball")
        xyz = np.zeros(3)
        xyz[:len(c)] = c
        for key, value in (("Radius", radius), ("Thickness", width), ("VIn", inner),
                           ("VOut", zones.outer), ("XCenter", xyz[0]), ("YCenter", xyz[1]), ("ZCenter", xyz[2])):
            gmsh.model.mesh.field.setNumber(ball, key, float(value))
        balls.append(ball)
    low = gmsh.model.mesh.field.add("Min")
    gmsh.model.mesh.field.setNumbers(low, "FieldsList", balls)
    gmsh.model.mesh.field.setAsBackgroundMesh(low)
    return balls + [low]


def _apply_size(gmsh, size, h: float) -> tuple:
    """Put a size field (SizeField, ZoneField, or a callable size(points (n, 3)) -> (n,)) into the current model.

    The design's size h stays the upper bound (Mesh.MeshSizeMax); the lower
    bound becomes the field's smallest size (or 0.1 h, whichever is smaller).
    Returns what to undo after meshing.
    """
    undo: tuple                         # how to take the size field off again
    if isinstance(size, SizeField):
        low = size.smallest
        view = gmsh.view.add("size")
        kind, n, data = size._view_data()
        gmsh.view.addListData(view, kind, n, data)
        field = gmsh.model.mesh.field.add("PostView")
        gmsh.model.mesh.field.setNumber(field, "ViewTag", view)
        gmsh.model.mesh.field.setAsBackgroundMesh(field)
        undo = ("view", view, field)
    elif isinstance(size, ZoneField):
        low = size.smallest
        undo = ("fields", _apply_zones(gmsh, size))
    else:
        def callback(dim, tag, x, y, z, *_):
            return float(np.asarray(size(np.array([[x, y, z]])), dtype=float).ravel()[0])
        low = float(np.min(np.asarray(size(np.zeros((1, 3))), dtype=float)))
        gmsh.model.mesh.setSizeCallback(callback)
        undo = ("callback",)
    extend = gmsh.option.getNumber("Mesh.MeshSizeExtendFromBoundary")
    gmsh.option.setNumber("Mesh.MeshSizeMin", max(min(0.1 * h, 0.5 * low), 1e-6 * h))
    gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)      # the field alone sets the size inside
    return undo + (extend,)


def _remove_size(gmsh, undo: tuple) -> None:
    gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", undo[-1])   # options are global to the process
    if undo[0] == "view":
        gmsh.model.mesh.field.remove(undo[2])
        gmsh.view.remove(undo[1])
    elif undo[0] == "fields":
        for field in undo[1]:
            gmsh.model.mesh.field.remove(field)
    else:
        gmsh.model.mesh.removeSizeCallback()


def mesh_design(design, comm=MPI.COMM_WORLD, verbose: bool = False, size=None) -> TaggedMesh:
    """Mesh the design's body and bones with Gmsh (rank 0) and return a TaggedMesh (see _mesh_design)."""
    with forget_array_types():            # Gmsh's arrays would leave a ctypes type per length for ever
        return _mesh_design(design, comm, verbose, size)


def _mesh_design(design, comm=MPI.COMM_WORLD, verbose: bool = False, size=None) -> TaggedMesh:
    """Mesh the design's body and bones with Gmsh (rank 0) and return a TaggedMesh.

    size: optional non-uniform mesh size in mm, a SizeField (fast: Gmsh
    interpolates it), a ZoneField (finer zones around points) or a callable size(points (n, 3)) -> (n,) (called by
    Gmsh once per point it places); the design's [mesh] size stays the upper
    bound. Without it the mesh is the design's uniform one.
    """
    from ..runtime.interrupts import import_gmsh
    gmsh = import_gmsh()
    from dolfinx.io import gmshio

    from ..design import resources
    resources.check(design)         # refuse a mesh that would not fit (unless --force), on every rank
    dim = design.dim
    names = body_tag_names(design) + [bone_tag_name(b.name) for b in design.bones] \
        + [object_tag_name(o.name) for o in design.objects]
    tags = {name: i + 1 for i, name in enumerate(names)}
    if comm.rank == 0:
        ensure_gmsh(gmsh)
        gmsh.option.setNumber("General.Terminal", 1 if verbose else 0)
        gmsh.model.add(design.name)
        error = interrupts.interruptible(_gmsh_mesh, gmsh, design, dim, tags, size)
    else:
        error = None
    error = comm.bcast(error, root=0)
    if error is not None:
        if comm.rank == 0:
            gmsh.model.remove()
        raise MeshingError(f"meshing failed: {error}")
    mesh, cell_tags, _ = gmshio.model_to_mesh(gmsh.model, comm, 0, gdim=dim)
    if comm.rank == 0:
        gmsh.model.remove()
    memory.release(mesh.topology.index_map(dim).size_local)   # Gmsh's meshing: back to the system
    return TaggedMesh(mesh, cell_tags, tags)


def _gmsh_mesh(gmsh, design, dim: int, tags: dict, size) -> str | None:
    """Build the current Gmsh model's geometry and mesh it (rank 0; run where a signal can stop the
    caller: runtime.interrupts.interruptible). The error message, or None."""
    try:
        groups = _build_model(gmsh, design)
        for name, entities in groups.items():
            if not entities:
                raise MeshingError(f"region {name!r} vanished while meshing")
            gmsh.model.addPhysicalGroup(dim, entities, tags[name])
            gmsh.model.setPhysicalName(dim, tags[name], name)
        h = float(design.mesh.size)
        gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        gmsh.option.setNumber("Mesh.MeshSizeMin", 0.1 * h)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
        gmsh.option.setNumber("Mesh.Algorithm", 6)
        # Frontal-Delaunay triangles are good without Laplacian smoothing
        # (quality gamma >= 0.6 on the bundled designs), which costs half
        # of a 2D meshing's time: re-meshing after an edit must be quick.
        gmsh.option.setNumber("Mesh.Smoothing", 0)
        undo = _apply_size(gmsh, size, h) if size is not None else None
        try:
            gmsh.model.mesh.generate(dim)
        finally:
            if undo is not None:
                _remove_size(gmsh, undo)
        return None
    except Exception as exc:  # reported on every rank by the caller
        return str(exc) or type(exc).__name__

