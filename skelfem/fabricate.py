"""Fabrication export: printable bones and a two-part mould from the design that is simulated.

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

import math
import os
import sys
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

FORMAT = 1
GRAZING = 0.5          # sin of the smallest angle (30 degrees) at which a channel may enter a bone
CURVATURE = 40         # triangles per full turn of a curved face in the STL files
PROBE_CURVATURE = 24   # ... in the planning pass
MIN_EDGE = 0.25        # mm: the shortest triangle edge asked for (a 1.2 mm channel gets 15 sides)
RAY = np.array([0.5377, 0.8315, 0.1402]) / np.linalg.norm([0.5377, 0.8315, 0.1402])  # off-axis, for parity


class FabricationError(ValueError):
    """A design that cannot be fabricated as asked; key names the design key to change."""

    def __init__(self, key: str, message: str):
        super().__init__(f"{key}: {message}")
        self.key, self.message = key, message


# -- triangle surfaces -----------------------------------------------------------------------------------
@dataclass
class Surface:
    """A closed triangulated surface: points (k, 3), triangles (m, 3) and the CAD face of each triangle."""

    points: np.ndarray
    tris: np.ndarray
    faces: np.ndarray

    @property
    def corners(self) -> np.ndarray:
        return self.points[self.tris]

    @property
    def normals(self) -> np.ndarray:
        c = self.corners
        n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
        return n / np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]


def _candidates(origins: np.ndarray, d: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(ray, triangle) pairs whose shadows along the common direction d can overlap.

    Rays and triangles are projected onto a plane normal to d; the plane is
    cut into about one cell per triangle, each triangle listed in every cell
    its bounding box touches, and a ray meets only the triangles of its cell.
    """
    a = np.cross(d, np.eye(3)[int(np.argmin(np.abs(d)))])
    a /= np.linalg.norm(a)
    basis = np.column_stack([a, np.cross(d, a)])
    P, C = origins @ basis, corners @ basis
    lo, hi = C.min(axis=1), C.max(axis=1)
    g0, g1 = lo.min(axis=0), hi.max(axis=0)
    h = max(float(np.sqrt(np.prod(np.maximum(g1 - g0, 1e-12)) / max(len(C), 1))), 1e-12)
    shape = np.maximum(np.ceil((g1 - g0) / h).astype(int), 1)
    i0 = np.clip(((lo - g0) / h).astype(int), 0, shape - 1)
    i1 = np.clip(((hi - g0) / h).astype(int), 0, shape - 1)
    nx, ny = i1[:, 0] - i0[:, 0] + 1, i1[:, 1] - i0[:, 1] + 1
    count = nx * ny
    tri = np.repeat(np.arange(len(C)), count)
    k = np.arange(len(tri)) - np.repeat(np.cumsum(count) - count, count)
    cx, cy = i0[tri, 0] + k % nx[tri], i0[tri, 1] + k // nx[tri]
    cell = cx * shape[1] + cy
    order = np.argsort(cell, kind="stable")
    cell, tri = cell[order], tri[order]
    r = np.floor((P - g0) / h).astype(int)
    inside_grid = np.all((r >= 0) & (r < shape), axis=1)
    rc = np.where(inside_grid, r[:, 0] * shape[1] + r[:, 1], -1)
    first, last = np.searchsorted(cell, rc, "left"), np.searchsorted(cell, rc, "right")
    n = np.where(inside_grid, last - first, 0)
    ray = np.repeat(np.arange(len(P)), n)
    j = np.arange(len(ray)) - np.repeat(np.cumsum(n) - n, n)
    return ray, tri[np.repeat(first, n) + j]


def ray_hits(origins: np.ndarray, direction: np.ndarray, corners: np.ndarray, tol: float,
             chunk: int = 2_000_000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where rays o + t d (t > -tol) cross triangles: (ray index, t, triangle index), sorted by ray then t.

    Moller-Trumbore with triple products: for a triangle a, b, c with
    e1 = b - a, e2 = c - a, det = (d x e2).e1 and s = o - a,
    u = s.(d x e2)/det, v = s.(e1 x d)/det, t = s.(e1 x e2)/det; a hit has
    u, v >= 0 and u + v <= 1 (a little slack, so that a ray through a shared
    edge hits both triangles; such repeats, within tol along the ray, are
    merged). direction is one vector for all rays (then only the pairs that
    _candidates finds are tested) or one per ray (r, 3).
    """
    origins = np.atleast_2d(np.asarray(origins, float))
    direction = np.asarray(direction, float)
    if direction.ndim == 1:
        rays, tris = _candidates(origins, direction / np.linalg.norm(direction), corners)
        d = np.broadcast_to(direction, (len(rays), 3))
    else:
        rays = np.repeat(np.arange(len(origins)), len(corners))
        tris = np.tile(np.arange(len(corners)), len(origins))
        d = direction[rays]
    R, T, I = [np.zeros(0, int)], [np.zeros(0)], [np.zeros(0, int)]
    for i0 in range(0, len(rays), chunk):
        r, k, dd = rays[i0:i0 + chunk], tris[i0:i0 + chunk], d[i0:i0 + chunk]
        a = corners[k, 0]
        e1, e2 = corners[k, 1] - a, corners[k, 2] - a
        p = np.cross(dd, e2)
        det = (p * e1).sum(1)
        ok = np.abs(det) > 1e-12 * np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1)
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = origins[r] - a
        u = (s * p).sum(1) * inv
        v = (s * np.cross(e1, dd)).sum(1) * inv
        t = (s * np.cross(e1, e2)).sum(1) * inv
        eps = 1e-9
        hit = ok & (u >= -eps) & (v >= -eps) & (u + v <= 1 + eps) & (t > -tol)
        R.append(r[hit]), T.append(t[hit]), I.append(k[hit])
    r, t, k = np.concatenate(R), np.concatenate(T), np.concatenate(I)
    order = np.lexsort((t, r))
    r, t, k = r[order], t[order], k[order]
    keep = np.ones(len(r), bool)
    keep[1:] = (r[1:] != r[:-1]) | (t[1:] - t[:-1] > tol)
    return r[keep], t[keep], k[keep]


def inside(points: np.ndarray, surface: Surface, tol: float) -> np.ndarray:
    """Which points lie inside a closed surface: the parity of crossings of an off-axis ray."""
    points = np.atleast_2d(points)
    r, t, _ = ray_hits(points, RAY, surface.corners, tol)
    r = r[t > tol]
    return np.bincount(r, minlength=len(points)) % 2 == 1


def point_triangle_distance(points: np.ndarray, corners: np.ndarray, chunk: int = 400_000) -> np.ndarray:
    """Exact distances (p, t) from points to triangles.

    The point's projection onto the triangle's plane, w = p - a = s e1 + t e2
    + h n, lies inside when s, t >= 0 and s + t <= 1: the distance is |h|.
    Otherwise the nearest point lies on an edge: min over the three segments
    of |p - x - clip((p - x).e / e.e, 0, 1) e|.
    """
    points = np.atleast_2d(points)
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    e1, e2 = b - a, c - a
    d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    den = np.maximum(d11 * d22 - d12 ** 2, 1e-300)
    n = np.cross(e1, e2)
    n /= np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
    out = np.empty((len(points), len(a)))
    step = max(1, chunk // max(len(a), 1))
    for i0 in range(0, len(points), step):
        p = points[i0:i0 + step, None, :]
        w = p - a
        w1, w2 = np.einsum("ptk,tk->pt", w, e1), np.einsum("ptk,tk->pt", w, e2)
        s, t = (d22 * w1 - d12 * w2) / den, (d11 * w2 - d12 * w1) / den
        face = np.abs(np.einsum("ptk,tk->pt", w, n))
        edge = np.full(face.shape, np.inf)
        for x, e in ((a, e1), (b, c - b), (a, e2)):
            y = p - x
            f = np.clip(np.einsum("ptk,tk->pt", y, e) / np.maximum((e * e).sum(1), 1e-300), 0.0, 1.0)
            edge = np.minimum(edge, np.linalg.norm(y - f[..., None] * e, axis=2))
        out[i0:i0 + step] = np.where((s >= 0) & (t >= 0) & (s + t <= 1), face, edge)
    return out


def face_distances(points: np.ndarray, surface: Surface) -> tuple[np.ndarray, np.ndarray]:
    """Distances (p, f) from points to each CAD face of a surface, and the face ids (f,)."""
    order = np.argsort(surface.faces, kind="stable")
    faces, starts = np.unique(surface.faces[order], return_index=True)
    d = point_triangle_distance(points, surface.corners[order])
    return np.minimum.reduceat(d, starts, axis=1), faces


# -- STL files and their checks ----------------------------------------------------------------------------
STL_RECORD = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])


def signed_volume(points: np.ndarray, tris: np.ndarray) -> float:
    """Volume enclosed by an outward-oriented closed surface (divergence theorem): sum a.(b x c) / 6."""
    a, b, c = points[tris[:, 0]], points[tris[:, 1]], points[tris[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def _edges(tris: np.ndarray):
    """Half-edges (3m, 2) of the triangles, their triangle, and undirected edge ids with counts."""
    half = tris[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    owner = np.repeat(np.arange(len(tris)), 3)
    key = np.sort(half, axis=1)
    _, edge, count = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return half, owner, edge.ravel(), count


def orient(points: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """The triangles of a closed 2-manifold, reordered so that every shared edge is used once each way
    and every connected part encloses positive volume.

    Neighbours across an edge agree when they use it in opposite
    directions. A breadth-first tree over the triangles (scipy) gives each
    triangle a parent; whether it must flip is the parity of disagreements on
    its path to the root, found for all triangles at once by pointer doubling
    (log depth numpy steps). Raises ValueError if an edge is not shared by
    exactly two triangles.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, connected_components

    m = len(tris)
    half, owner, edge, count = _edges(tris)
    if np.any(count != 2):
        raise ValueError(f"{int(np.sum(count != 2))} edges are not shared by exactly two triangles")
    order = np.argsort(edge, kind="stable")
    i, j = order[0::2], order[1::2]                       # the two half-edges of each edge
    same = np.all(half[i] == half[j], axis=1)             # used the same way: the triangles disagree
    ti, tj = owner[i], owner[j]
    w = coo_matrix((np.r_[same, same] + 1.0, (np.r_[ti, tj], np.r_[tj, ti])), shape=(m, m)).tocsr()
    ncomp, label = connected_components(w, directed=False)
    parent = np.arange(m)
    for comp in range(ncomp):
        root = int(np.flatnonzero(label == comp)[0])
        _, pred = breadth_first_order(w, root, directed=False, return_predecessors=True)
        members = np.flatnonzero(label == comp)
        members = members[members != root]
        parent[members] = pred[members]
    flip = (np.asarray(w[np.arange(m), parent]).ravel() == 2.0)
    flip[parent == np.arange(m)] = False
    jump = parent.copy()
    while np.any(jump != jump[jump]):
        flip = flip ^ flip[jump]
        jump = jump[jump]
    flip = flip ^ flip[jump]                              # the last step up to the root (root's flip is 0)
    out = tris.copy()
    out[flip] = out[flip][:, [0, 2, 1]]
    for comp in range(ncomp):
        sel = label == comp
        if signed_volume(points, out[sel]) < 0:
            out[sel] = out[sel][:, [0, 2, 1]]
    return out


def write_stl(path, points: np.ndarray, tris: np.ndarray, name: str) -> None:
    """Binary STL: 80-byte header, uint32 count, per triangle its unit normal and corners (float32)."""
    c = points[tris]
    n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
    # Readers that guess ASCII or binary from the bytes after the header (admesh: any byte > 127 means
    # binary) are sure to see one if the first triangle's normal has a negative component.
    first = int(np.argmin(n.min(axis=1))) if len(n) else 0
    n, c = np.roll(n, -first, axis=0), np.roll(c, -first, axis=0)
    rec = np.zeros(len(tris), STL_RECORD)
    rec["normal"], rec["corners"] = n, c
    header = f"skelfem fabricate: {name} (mm)".encode("utf-8", "replace")[:80].ljust(80, b" ")
    with open(path, "wb") as f:
        f.write(header)
        f.write(np.uint32(len(tris)).tobytes())
        f.write(rec.tobytes())


def read_stl(path) -> tuple[np.ndarray, np.ndarray]:
    """A binary STL as (points, triangles), corners merged where their float32 coordinates are equal."""
    data = Path(path).read_bytes()
    count = int(np.frombuffer(data, "<u4", 1, 80)[0])
    if len(data) != 84 + count * STL_RECORD.itemsize:
        raise ValueError(f"{path}: not a binary STL of {count} triangles ({len(data)} bytes)")
    corners = np.frombuffer(data, STL_RECORD, count, 84)["corners"].reshape(-1, 3)
    points, index = np.unique(corners, axis=0, return_inverse=True)
    return points.astype(float), index.reshape(-1, 3)


def check_mesh(points: np.ndarray, tris: np.ndarray) -> dict:
    """Is the triangle surface a closed, consistently oriented solid? Counts of what is wrong.

    open_edges: edges of one triangle only; nonmanifold_edges: of three or
    more; misoriented_edges: shared edges that both triangles run the same
    way; degenerate: triangles with a repeated corner or zero area; parts:
    connected pieces (through shared edges); volume: divergence theorem.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    half, owner, edge, count = _edges(tris)
    order = np.argsort(edge, kind="stable")
    pairs = np.flatnonzero(count[edge[order]] == 2)
    i, j = order[pairs[0::2]], order[pairs[1::2]]
    misoriented = int(np.sum(np.all(half[i] == half[j], axis=1)))
    c = points[tris]
    area = 0.5 * np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=1)
    scale = float(np.ptp(points, axis=0).max()) if len(points) else 1.0
    repeated = (tris[:, 0] == tris[:, 1]) | (tris[:, 1] == tris[:, 2]) | (tris[:, 0] == tris[:, 2])
    degenerate = int(np.sum(repeated | (area <= 1e-14 * scale ** 2)))
    m = len(tris)
    ti, tj = owner[i], owner[j]
    graph = coo_matrix((np.ones(len(ti)), (ti, tj)), shape=(m, m))
    parts = int(connected_components(graph, directed=False)[0]) if m else 0
    report = {"triangles": m, "open_edges": int(np.sum(count == 1)), "nonmanifold_edges": int(np.sum(count > 2)),
              "misoriented_edges": misoriented, "degenerate": degenerate, "parts": parts,
              "volume": signed_volume(points, tris), "area": float(area.sum())}
    report["closed"] = report["open_edges"] == 0 and report["nonmanifold_edges"] == 0
    report["oriented"] = report["closed"] and misoriented == 0 and report["volume"] > 0
    return report


# -- Gmsh ----------------------------------------------------------------------------------------------------
@contextmanager
def _quiet():
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


def _mesh(gmsh, size: float, curvature: int) -> None:
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


def _surface(gmsh, volumes) -> Surface:
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


# -- the plan ----------------------------------------------------------------------------------------------------
@dataclass
class Frame:
    """The mould's axes: u, v span the parting plane n . x = c; the block spans lo..hi in (u, v, n)."""

    u: np.ndarray
    v: np.ndarray
    n: np.ndarray
    c: float
    lo: np.ndarray = None
    hi: np.ndarray = None

    @classmethod
    def from_normal(cls, point, normal) -> "Frame":
        n = np.asarray(normal, float) / np.linalg.norm(normal)
        k = int(np.argmax(np.abs(n)))
        axis = np.eye(3)[(k + 1) % 3]
        u = axis - (axis @ n) * n
        u /= np.linalg.norm(u)
        return cls(u, np.cross(n, u), n, float(n @ np.asarray(point, float)))

    @property
    def matrix(self) -> np.ndarray:
        """Columns u, v, n: global = matrix @ (u, v, n) coordinates."""
        return np.column_stack([self.u, self.v, self.n])

    def local(self, x) -> np.ndarray:
        return np.asarray(x, float) @ self.matrix

    def world(self, y) -> np.ndarray:
        return np.asarray(y, float) @ self.matrix.T


@dataclass
class Tool:
    """A cylinder-swept cut or addition: an axis polyline, its radius, where it extends past its ends."""

    kind: str              # "channel", "anchor", "socket", "peg", "pin", "pin_hole", "pour", "vent", "exit"
    points: np.ndarray     # (k, 3) axis polyline
    radius: float
    bone: str | None = None
    cable: str | None = None
    extend: tuple = (0.0, 0.0)     # lengths the cylinder runs on beyond the first and the last point
    side: str | None = None        # pegs: the mould half they belong to, "bottom" or "top"

    @property
    def length(self) -> float:
        return float(np.linalg.norm(np.diff(self.points, axis=0), axis=1).sum())

    def ends(self) -> tuple[np.ndarray, np.ndarray]:
        """The cylinder's end points, each end extended along its segment."""
        p = self.points
        d0 = (p[0] - p[1]) / np.linalg.norm(p[0] - p[1])
        d1 = (p[-1] - p[-2]) / np.linalg.norm(p[-1] - p[-2])
        return p[0] + self.extend[0] * d0, p[-1] + self.extend[1] * d1


@dataclass
class Plan:
    """Everything the build pass needs: tools per part, the frame and block, the reference volumes."""

    design: object
    spec: object
    frame: Frame
    scale: float
    bone_tools: dict = field(default_factory=dict)      # bone name -> [Tool]
    pegs: list = field(default_factory=list)            # Tools of kind "peg"
    mould_tools: list = field(default_factory=list)     # pins, pin holes, pour, vents, exits
    body_volume: float = 0.0
    bone_volumes: dict = field(default_factory=dict)    # un-cut bone volumes (probe pass)
    notes: list = field(default_factory=list)


def _samples(points: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Points every <= step along a polyline (its corners included) and their arclengths."""
    seg = np.diff(points, axis=0)
    lengths = np.linalg.norm(seg, axis=1)
    out, arc = [points[:1]], [np.zeros(1)]
    s0 = 0.0
    for a, d, L in zip(points[:-1], seg, lengths):
        k = max(1, int(math.ceil(L / step)))
        f = np.arange(1, k + 1) / k
        out.append(a + f[:, None] * d), arc.append(s0 + f * L)
        s0 += L
    return np.concatenate(out), np.concatenate(arc)


def _where(x) -> str:
    return "(" + ", ".join(f"{v:.3g}" for v in x) + ")"


class _Planner:
    """Builds the plan from the probe surfaces; every check raises FabricationError."""

    def __init__(self, design, body: Surface, bones: dict, scale: float):
        self.design, self.spec = design, design.fabrication
        self.body, self.bones, self.scale = body, bones, scale
        self.tol = 1e-7 * scale
        self.dim = design.dim
        spec = self.spec
        self.frame = Frame.from_normal(spec.split_point, spec.split_normal)
        self.r_channel, self.r_anchor = spec.channel_diameter / 2, spec.anchor_diameter / 2
        self.r_peg = spec.peg_diameter / 2
        self.r_socket = self.r_peg + spec.clearance
        self.wall = spec.min_wall

    # cables in 3D coordinates
    def cable_points(self, cable) -> np.ndarray:
        p = np.asarray(cable.path, float)
        if self.dim == 2:
            p = np.column_stack([p, np.full(len(p), self.design.thickness / 2)])
        return p

    def cable_key(self, cable) -> str:
        return f"cables.{cable.name}.path"

    # -- where a cable runs inside a bone
    def pieces(self, points: np.ndarray, surface: Surface) -> list[dict]:
        """The stretches of a polyline inside a closed surface, each with how it starts and ends.

        A start or end is either the polyline's own end ("end") or a crossing
        of the surface, with the crossed CAD face and sin of the angle between
        the polyline and the face (|d . n| with n the triangle's normal).
        """
        seg = np.diff(points, axis=0)
        L = np.linalg.norm(seg, axis=1)
        d = seg / L[:, None]
        arc0 = np.r_[0.0, np.cumsum(L)]
        r, t, k = ray_hits(points[:-1], d, surface.corners, self.tol)
        ok = (t > self.tol) & (t <= L[r] + self.tol)     # a crossing at a corner: at the end of one segment
        r, t, k = r[ok], t[ok], k[ok]
        s = arc0[r] + t
        order = np.argsort(s)
        r, s, k = r[order], s[order], k[order]
        keep = np.r_[True, np.diff(s) > self.tol] if len(s) else np.zeros(0, bool)
        r, s, k = r[keep], s[keep], k[keep]
        sin = np.abs(np.einsum("ij,ij->i", d[r], surface.normals[k]))
        state = bool(inside(points[:1], surface, self.tol)[0])
        out, start = [], ({"at": "end", "s": 0.0} if state else None)
        for seg_i, si, ki, sn in zip(r, s, k, sin):
            cross = {"at": "face", "s": float(si), "face": int(surface.faces[ki]), "sin": float(sn),
                     "point": points[seg_i] + (si - arc0[seg_i]) * d[seg_i]}
            if state:
                out.append((start, cross))
            else:
                start = cross
            state = not state
        if state:
            out.append((start, {"at": "end", "s": float(arc0[-1])}))
        pieces = []
        for a, b in out:
            inner = points[(arc0 > a["s"] + self.tol) & (arc0 < b["s"] - self.tol)]
            pa = points[0] if a["at"] == "end" else a["point"]
            pb = points[-1] if b["at"] == "end" else b["point"]
            pieces.append({"points": np.vstack([pa, inner, pb]), "start": a, "end": b})
        return pieces

    def check_wall(self, tool: Tool, start: dict, end: dict, key_path: str, key_size: str, what: str) -> None:
        """Every point of the tool's axis at least radius + min_wall from the bone's surface.

        Near a crossing the axis is close to the crossed face by construction:
        a point at distance s from the crossing lies s sin(theta) from that
        face, so the face is ignored there while s < (r + min_wall)/sin(theta).
        """
        surface = self.bones[tool.bone]
        need = tool.radius + self.wall
        for end_ in (start, end):
            if end_["at"] == "face" and end_["sin"] < GRAZING:
                angle = math.degrees(math.asin(min(1.0, end_["sin"])))
                raise FabricationError(key_path, f"{what} meets the surface of bone {tool.bone!r} at "
                                                 f"{_where(end_['point'])} at a grazing {angle:.0f} degrees "
                                                 f"(at least 30 are needed, or the channel opens the bone's side)")
        pts, arc = _samples(tool.points, min(0.25, tool.radius / 2))
        dist, faces = face_distances(pts, surface)
        total = arc[-1]
        for end_, s_from in ((start, arc), (end, total - arc)):
            if end_["at"] == "face":
                near = s_from < need / max(end_["sin"], 1e-9) + self.tol
                dist[np.ix_(near, faces == end_["face"])] = np.inf
        worst = dist.min(axis=1)
        bad = worst < need - 1e-6 * self.scale
        if not bad.any():
            return
        if need > self.inradius(tool.bone):
            raise FabricationError(key_size, f"{2 * tool.radius:g} mm with min_wall {self.wall:g} mm on each "
                                             f"side does not fit in bone {tool.bone!r} (at most "
                                             f"{2 * max(self.inradius(tool.bone) - self.wall, 0):.3g} mm there)")
        i = int(np.argmin(worst))
        raise FabricationError(key_path, f"{what} would open the side of bone {tool.bone!r}: near "
                                         f"{_where(pts[i])} its axis passes {worst[i]:.2f} mm from the bone's "
                                         f"surface, and radius + min_wall = {need:g} mm are needed")

    def inradius(self, bone: str) -> float:
        """Radius of the largest ball inside a bone (a grid of inside points, their distance to the surface)."""
        cache = self.__dict__.setdefault("_inradius", {})
        if bone not in cache:
            surface = self.bones[bone]
            lo, hi = surface.points.min(axis=0), surface.points.max(axis=0)
            h = max(float(np.prod(np.maximum(hi - lo, 1e-9))) / 6000.0, 1e-12) ** (1 / 3)
            axes = [np.arange(a + h / 2, b, h) for a, b in zip(lo, hi)]
            grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
            grid = grid[inside(grid, surface, self.tol)]
            cache[bone] = float(point_triangle_distance(grid, surface.corners).min(axis=1).max()) if len(grid) else 0.0
        return cache[bone]

    # -- channels and anchors
    def route(self) -> dict:
        """Channels and anchor holes per bone, every wall checked; records each tendon's way out (spool)."""
        design = self.design
        tools = {b.name: [] for b in design.bones}
        spool = {}
        for cable in design.cables:
            pts = self.cable_points(cable)
            in_bone = {}
            for bone in design.bones:
                for piece in self.pieces(pts, self.bones[bone.name]):
                    a, b = piece["start"], piece["end"]
                    if a["at"] == "end":
                        in_bone[0] = bone.name
                    if b["at"] == "end":
                        in_bone[len(pts) - 1] = bone.name
                    if cable.kind == "tendon" or (a["at"] == "face" and b["at"] == "face"):
                        r = self.r_channel if cable.kind == "tendon" else self.r_anchor
                        ext = tuple(0.0 if e["at"] == "end" else
                                    r * math.sqrt(max(1 - e["sin"] ** 2, 0)) / max(e["sin"], 1e-9) + 0.5
                                    for e in (a, b))
                        tool = Tool("channel", piece["points"], r, bone.name, cable.name, ext)
                        tools[bone.name].append((tool, a, b))
                    for e, end_point in ((a, pts[0]), (b, pts[-1])):
                        if cable.kind == "ligament" and e["at"] == "end":
                            tools[bone.name].append(self.anchor(bone.name, cable.name, end_point))
            if cable.kind == "tendon":
                spool[cable.name] = self.spool_end(cable, pts, in_bone)
        self.check_depth(tools)
        for bone, items in tools.items():
            for tool, a, b in items:
                cable = self.design.cable(tool.cable)
                if tool.kind == "channel":
                    self.check_wall(tool, a, b, self.cable_key(cable),
                                    "fabrication.channel_diameter" if cable.kind == "tendon"
                                    else "fabrication.anchor_diameter", f"the channel of {cable.name!r}")
                else:
                    self.check_wall(tool, a, b, self.cable_key(cable), "fabrication.anchor_diameter",
                                    f"the anchor hole of {cable.name!r}")
            self.check_apart(bone, [t for t, _, _ in items])
        self.spool = spool
        return {bone: [t for t, _, _ in items] for bone, items in tools.items()}

    def anchor(self, bone: str, cable: str, point: np.ndarray):
        """A hole through the bone along the mould's normal, through the ligament's end point."""
        surface, n = self.bones[bone], self.frame.n
        ends = []
        for sign in (1.0, -1.0):
            r, t, k = ray_hits(point, sign * n, surface.corners, self.tol)
            t, k = t[t > self.tol], k[t > self.tol]
            if not len(t):
                raise FabricationError(f"cables.{cable}.path", f"its end in bone {bone!r} is not inside it")
            ends.append({"at": "face", "point": point + sign * t[0] * n, "face": int(surface.faces[k[0]]),
                         "sin": float(abs(surface.normals[k[0]] @ n))})
        a, b = ends[1], ends[0]
        tool = Tool("anchor", np.vstack([a["point"], point, b["point"]]), self.r_anchor, bone, cable,
                    extend=(self.r_anchor + 0.5, self.r_anchor + 0.5))
        return tool, a, b

    def spool_end(self, cable, pts: np.ndarray, in_bone: dict) -> dict:
        """The tendon's end toward the spool (its first point unless that lies in a bone) and its way out."""
        key = self.cable_key(cable)
        if 0 in in_bone and len(pts) - 1 in in_bone:
            raise FabricationError(key, f"both ends lie in bones ({in_bone[0]!r}, {in_bone[len(pts) - 1]!r}); "
                                        "a tendon needs one end that leaves the body for its spool")
        i, j = (0, 1) if 0 not in in_bone else (len(pts) - 1, len(pts) - 2)
        p, d = pts[i], (pts[i] - pts[j]) / np.linalg.norm(pts[i] - pts[j])
        back = min(self.r_channel, 0.5 * float(np.linalg.norm(pts[i] - pts[j])))
        origin = p - back * d
        _, t, _ = ray_hits(origin, d, self.body.corners, self.tol)
        t = t[t > self.tol]
        if not len(t):
            raise FabricationError(key, f"its end at {_where(p)} does not lead out of the body")
        leave = float(t[0])
        for bone, surface in self.bones.items():
            _, tb, _ = ray_hits(origin, d, surface.corners, self.tol)
            if np.any((tb > self.tol) & (tb < leave)):
                raise FabricationError(key, f"its end at {_where(p)} runs into bone {bone!r} on its way out of the "
                                            "body (a tendon leaves the body straight on from its spool end)")
        if len(t) > 1:
            raise FabricationError(key, f"straight on from its end at {_where(p)} the tendon would re-enter the "
                                        "body; route its spool end to the surface")
        return {"point": p, "direction": d, "origin": origin, "leave": origin + leave * d}

    def check_depth(self, tools: dict) -> None:
        """2D: a bone must be deep enough for a channel in its mid-plane."""
        if self.dim != 2 or not any(t.kind == "channel" for items in tools.values() for t, _, _ in items):
            return
        r = max(t.radius for items in tools.values() for t, _, _ in items if t.kind == "channel")
        need = 2 * (r + self.wall)
        if self.spec.bone_depth < need - 1e-9:
            raise FabricationError("fabrication.bone_depth", f"{self.spec.bone_depth:g} mm is too thin for the "
                                                             f"bones' channels: a {2 * r:g} mm channel with min_wall "
                                                             f"{self.wall:g} mm needs {need:g} mm")

    def check_apart(self, bone: str, tools: list) -> None:
        """Channels and holes of different cables in one bone must not meet."""
        from scipy.spatial import cKDTree
        for i, a in enumerate(tools):
            pa, _ = _samples(a.points, 0.1)
            tree = cKDTree(pa)
            for b in tools[:i]:
                if b.cable == a.cable:
                    continue
                pb, _ = _samples(b.points, 0.1)
                gap = float(tree.query(pb)[0].min())      # sampled every 0.1 mm: within 0.05 mm
                need = a.radius + b.radius + self.wall
                if gap < need - 0.05:
                    raise FabricationError(f"cables.{a.cable}.path", f"its {a.kind} in bone {bone!r} comes within "
                                                                     f"{gap:.2f} mm of the {b.kind} of {b.cable!r} "
                                                                     f"(axes {need:g} mm apart are needed)")

    # -- the mould's block
    def block(self) -> None:
        f = self.frame
        y = f.local(self.body.points)
        lo, hi = y.min(axis=0), y.max(axis=0)
        if not (lo[2] + self.tol < f.c < hi[2] - self.tol):
            raise FabricationError("fabrication.split.point", f"the parting plane n.x = {f.c:g} does not cut the body "
                                                             f"(it spans {lo[2]:.3g} to {hi[2]:.3g} along the normal)")
        w = self.spec.wall
        f.lo, f.hi = lo - w, hi + w

    def column(self, uv: np.ndarray, surfaces: list[Surface]) -> list:
        """For lines along n through the points uv (q, 2) of the plane: the n-coordinates where each
        line crosses each surface (a list per surface of q sorted arrays)."""
        f = self.frame
        origins = f.world(np.column_stack([uv, np.full(len(uv), f.lo[2] - 1.0)]))
        out = []
        for s in surfaces:
            r, t, _ = ray_hits(origins, f.n, s.corners, self.tol)
            split = np.searchsorted(r, np.arange(len(uv) + 1))
            out.append([f.lo[2] - 1.0 + t[split[i]:split[i + 1]] for i in range(len(uv))])
        return out

    @staticmethod
    def ring(center: np.ndarray, radius: float, count: int = 8) -> np.ndarray:
        """count points around center whose polygon contains the circle of the given radius."""
        a = 2 * np.pi * np.arange(count) / count
        return center + radius / math.cos(math.pi / count) * np.column_stack([np.cos(a), np.sin(a)])

    def grid(self, uv_points: np.ndarray, target: int, margin: float = 0.0) -> np.ndarray:
        lo, hi = uv_points.min(axis=0) + margin, uv_points.max(axis=0) - margin
        if np.any(hi <= lo):
            return np.zeros((0, 2))
        h = math.sqrt(float(np.prod(hi - lo)) / target)
        axes = [np.arange(a + 0.5 * ((b - a) % h), b + 1e-12, h) if b - a > h else np.array([(a + b) / 2])
                for a, b in zip(lo, hi)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 2)

    # -- pegs and sockets
    def pegs(self, bone_tools: dict) -> list:
        """Up to two pegs per bone from each half, along the mould's normal (so that they pull out).

        A site (u, v) on side s (+1: top half, -1: bottom) is taken where the
        line along n leaves the bone at E (its last crossing toward s) and:
        the bone is flat enough there for a socket (a ring of radius socket +
        min_wall crosses it within socket_depth/2 of E, with 2 socket_depth +
        min_wall of bone beneath, room for a socket from the other side too);
        nothing of the bone, of another bone, or of the body after it leaves
        it, lies in the peg's column beyond E (a ring of radius peg +
        clearance); the body is left on the peg's own side of the parting
        plane; the column keeps clear of every cable, and the socket of every
        channel and anchor hole. The peg's tip stops clearance short of the
        socket's bottom, and clearance separates it from the socket's wall.
        """
        from scipy.spatial import cKDTree
        spec, f = self.spec, self.frame
        h = spec.socket_depth
        cable_pts = [_samples(self.cable_points(c), 0.2)[0] for c in self.design.cables]
        cable_tree = cKDTree(np.concatenate(cable_pts)) if cable_pts else None
        pegs = []
        for bone in self.design.bones:
            surface = self.bones[bone.name]
            others = [s for name, s in self.bones.items() if name != bone.name]
            holes = [t for t in bone_tools[bone.name]]
            hole_pts = [_samples(t.points, 0.2)[0] for t in holes]
            hole_r = np.concatenate([np.full(len(p), t.radius) for p, t in zip(hole_pts, holes)]) if holes else None
            hole_tree = cKDTree(np.concatenate(hole_pts)) if holes else None
            sites = self.grid(f.local(surface.points)[:, :2], 150, margin=self.r_socket + self.wall)
            if not len(sites):
                continue
            ring_s = np.stack([self.ring(p, self.r_socket + self.wall) for p in sites])
            ring_p = np.stack([self.ring(p, self.r_peg + spec.clearance) for p in sites])
            lines = np.concatenate([sites, ring_s.reshape(-1, 2), ring_p.reshape(-1, 2)])
            hits = self.column(lines, [surface, self.body] + others)
            q = len(sites)
            for side in (-1, 1):
                ok = []
                for i in range(q):
                    site = self._peg_site(i, q, side, hits, h)
                    if site is None:
                        continue
                    e, leave = site
                    tip = e - side * (h - spec.clearance)
                    axis = f.world([[*sites[i], tip], [*sites[i], leave]])
                    sock = f.world([[*sites[i], e], [*sites[i], e - side * h]])
                    if cable_tree is not None:
                        near = cable_tree.query(_samples(axis, 0.2)[0])[0].min()
                        if near < self.r_peg + self.r_channel + self.wall:
                            continue
                    if hole_tree is not None:
                        d, j = hole_tree.query(_samples(sock, 0.2)[0])
                        if np.any(d < self.r_socket + hole_r[j] + self.wall):
                            continue
                    ok.append((sites[i], e, tip, leave))
                for site, e, tip, leave in self._spread(ok, 2):
                    far = leave + side * spec.wall / 2          # into the half's material beyond the body
                    peg = Tool("peg", f.world([[*site, tip], [*site, far]]), self.r_peg, bone.name,
                               side="top" if side > 0 else "bottom")
                    sock = Tool("socket", f.world([[*site, e + side * h], [*site, e - side * h]]), self.r_socket,
                                bone.name)
                    pegs.append(peg)
                    bone_tools[bone.name].append(sock)
        return pegs

    def _peg_site(self, i, q, side, hits, h):
        """(E, n where the peg leaves the body) for site i on side, or None; see pegs()."""
        mine, body, others = hits[0], hits[1], hits[2:]
        rs = range(q + 8 * i, q + 8 * i + 8)
        rp = range(9 * q + 8 * i, 9 * q + 8 * i + 8)
        ax = mine[i]
        if len(ax) < 2:
            return None
        e = ax[-1] if side > 0 else ax[0]
        beneath = (ax[-1] - ax[-2]) if side > 0 else (ax[1] - ax[0])
        if beneath < 2 * h + self.wall:                 # room for a socket from the other side too
            return None
        for j in rs:
            if not len(mine[j]):
                return None
            ej = mine[j][-1] if side > 0 else mine[j][0]
            if side * (ej - e) < -h / 2 or side * (ej - e) > h:
                return None
        leave = None
        for j in [i, *rp]:
            # bone beyond E within the peg's radius (a face not normal to n) is cut away by the socket,
            # which starts socket_depth beyond E: up to half that is accepted
            if len(mine[j]) and side * ((mine[j][-1] if side > 0 else mine[j][0]) - e) > h / 2:
                return None
            beyond = body[j][side * (body[j] - e) > self.tol]
            if len(beyond) != 1:
                return None                  # leaves the body more than once, or never
            if side * (beyond[0] - self.frame.c) < 0:
                return None                  # leaves the body in the other half
            if any(np.any(side * (o[j] - e) > -h - self.tol) for o in others):
                return None
            if j == i:
                leave = float(beyond[0])
        return e, leave

    @staticmethod
    def _spread(items: list, count: int) -> list:
        """Up to count items far apart: the one farthest from their centre, then the farthest from it."""
        if len(items) <= 1:
            return items
        uv = np.array([it[0] for it in items])
        first = int(np.argmax(np.linalg.norm(uv - uv.mean(axis=0), axis=1)))
        second = int(np.argmax(np.linalg.norm(uv - uv[first], axis=1)))
        return [items[first], items[second]][:count]

    # -- pour hole, vents, pins, exits
    def openings(self, pegs: list) -> list:
        """The pour hole and vents through the top half, where the body's top surface is flat enough.

        Sites on a grid over the body: a line along n must meet the body's
        top with a ring of the hole's radius meeting it within a radius of the
        same height, above the parting plane, with body beneath for a radius;
        and keep clear of the top pegs. The pour hole takes the site nearest
        the middle, the vents the sites farthest from it and from each other.
        """
        spec, f = self.spec, self.frame
        top_pegs = np.array([f.local(p.points[0])[:2] for p in pegs if p.side == "top"]).reshape(-1, 2)
        sites = self.grid(f.local(self.body.points)[:, :2], 600)
        tools = []

        def usable(radius):
            rings = np.stack([self.ring(p, radius) for p in sites])
            body = self.column(np.concatenate([sites, rings.reshape(-1, 2)]), [self.body])[0]
            q, good, tops = len(sites), [], []
            for i in range(q):
                ax = body[i]
                if len(ax) < 2 or ax[-1] - ax[-2] < radius or ax[-1] - f.c < radius:
                    continue
                ring = [body[q + 8 * i + k] for k in range(8)]
                if any(not len(r) or abs(r[-1] - ax[-1]) > 0.5 * radius for r in ring):
                    continue
                if len(top_pegs) and np.linalg.norm(top_pegs - sites[i], axis=1).min() < \
                        radius + self.r_peg + spec.clearance + self.wall:
                    continue
                good.append(i), tops.append(ax[-1] - min(radius, 0.5 * (ax[-1] - ax[-2])))
            return np.array(good, int), np.array(tops)

        good, tops = usable(spec.pour_diameter / 2)
        if not len(good):
            raise FabricationError("fabrication.pour_diameter", f"no place on the top of the body (above the parting "
                                                                f"plane) fits a pour hole of {spec.pour_diameter:g} mm")
        mid = f.local(self.body.points)[:, :2].mean(axis=0)
        k = int(np.argmin(np.linalg.norm(sites[good] - mid, axis=1)))
        pour = sites[good[k]]
        tools.append(Tool("pour", f.world([[*pour, tops[k]], [*pour, f.hi[2]]]), spec.pour_diameter / 2,
                          extend=(0.0, 1.0)))
        if spec.vents:
            good, tops = usable(spec.vent_diameter / 2)
            far = np.linalg.norm(sites[good] - pour, axis=1)
            ok = far >= (spec.pour_diameter + spec.vent_diameter) / 2 + 2 * self.wall
            good, tops, far = good[ok], tops[ok], far[ok]
            chosen = []
            for _ in range(spec.vents):
                if not len(good):
                    raise FabricationError("fabrication.vents", f"room for only {len(chosen)} vent(s) of "
                                                                f"{spec.vent_diameter:g} mm on the top of the body")
                k = int(np.argmax(far))
                chosen.append(sites[good[k]])
                tools.append(Tool("vent", f.world([[*sites[good[k]], tops[k]], [*sites[good[k]], f.hi[2]]]),
                                  spec.vent_diameter / 2, extend=(0.0, 1.0)))
                far = np.minimum(far, np.linalg.norm(sites[good] - sites[good[k]], axis=1))
                ok = far >= spec.vent_diameter + 2 * self.wall
                good, tops, far = good[ok], tops[ok], far[ok]
        return tools

    def pins(self) -> list:
        """Four registration pins at the block's corners (radius wall/4, height wall/2) and their holes."""
        f, w, c = self.frame, self.spec.wall, self.spec.clearance
        r, h = w / 4, w / 2
        tools = []
        for a in (f.lo[0] + w / 2, f.hi[0] - w / 2):
            for b in (f.lo[1] + w / 2, f.hi[1] - w / 2):
                tools.append(Tool("pin", f.world([[a, b, f.c - 1.0], [a, b, f.c + h]]), r))
                tools.append(Tool("pin_hole", f.world([[a, b, f.c - 1.0], [a, b, f.c + h + c]]), r + c))
        return tools

    def exits(self) -> list:
        """A channel through the mould wall where each tendon leaves the body toward its spool."""
        f = self.frame
        tools = []
        for name, s in self.spool.items():
            d = s["direction"]
            # distance along d from the point to the block's boundary (a slab test in frame coordinates)
            y0, dy = f.local(s["origin"]), f.local(d)
            with np.errstate(divide="ignore", invalid="ignore"):
                t = np.where(dy > 0, (f.hi - y0) / dy, np.where(dy < 0, (f.lo - y0) / dy, np.inf))
            tools.append(Tool("exit", np.vstack([s["origin"], s["origin"] + (float(t.min()) + 1.0) * d]),
                              self.r_channel, cable=name))
        return tools


def plan(design) -> Plan:
    """Check a design for fabrication and plan every part; raises FabricationError (key, message)."""
    import gmsh

    from .geometry import add_design_solids, gmsh_model

    spec = design.fabrication
    with gmsh_model("skelfem-fabricate-probe"):
        occ = gmsh.model.occ
        body_tags, bone_tags = add_design_solids(occ, design, spec.bone_depth or None)
        occ.synchronize()
        box = np.array([occ.getBoundingBox(3, t) for t in body_tags]).reshape(-1, 2, 3)
        scale = float((box[:, 1].max(axis=0) - box[:, 0].min(axis=0)).max())
        body_volume = float(sum(occ.getMass(3, t) for t in body_tags))
        bone_volumes = {name: float(sum(occ.getMass(3, t) for t in tags)) for name, tags in bone_tags.items()}
        _mesh(gmsh, scale / 8, PROBE_CURVATURE)
        body = _surface(gmsh, body_tags)
        bones = {name: _surface(gmsh, tags) for name, tags in bone_tags.items()}
    planner = _Planner(design, body, bones, scale)
    planner.block()
    bone_tools = planner.route()
    pegs = planner.pegs(bone_tools)
    mould = planner.openings(pegs) + planner.pins() + planner.exits()
    p = Plan(design, spec, planner.frame, scale, bone_tools, pegs, mould, body_volume, bone_volumes)
    unheld = [b.name for b in design.bones if not any(t.bone == b.name for t in pegs)]
    if unheld:
        p.notes.append(f"no peg can reach bone(s) {', '.join(unheld)} along the mould's normal; "
                       "they are not fixtured")
    return p


# -- the build pass --------------------------------------------------------------------------------------------
@dataclass
class Part:
    """One printed part: its file stem, kind, oriented surface and exact (CAD) volume."""

    name: str
    kind: str                    # "bone" or "mould"
    surface: Surface
    cad_volume: float
    info: dict = field(default_factory=dict)


def _shapes(occ, tool: Tool) -> list:
    """OCC solids of a tool: a cylinder per segment of its axis (the ends extended), a ball at each bend."""
    p = tool.points.copy()
    p[0], p[-1] = tool.ends()
    out = []
    for a, b in zip(p[:-1], p[1:]):
        out.append((3, occ.addCylinder(*a, *(b - a), tool.radius)))
    for x in tool.points[1:-1]:
        out.append((3, occ.addSphere(*x, tool.radius)))
    return out


def _mass(occ, dimtags) -> float:
    occ.synchronize()
    return float(sum(occ.getMass(*v) for v in dimtags))


def _volumes(out) -> list[int]:
    return [t for d, t in out if d == 3]


def _solid(occ, out) -> list:
    """The volumes of a boolean's result without the empty slivers OpenCASCADE sometimes leaves
    (a solid of zero volume where a plane touches a sphere, say); those are removed from the model."""
    occ.synchronize()
    vols = [(3, t) for t in _volumes(out)]
    mass = np.array([occ.getMass(*v) for v in vols])
    empty = [v for v, m in zip(vols, mass) if m <= 1e-9 * max(mass.max(initial=0.0), 1.0)]
    if empty:
        occ.remove(empty, recursive=True)
    return [v for v in vols if v not in empty]


def _finish(gmsh, name: str, kind: str, volumes: list[int], plan: Plan, folder: Path | None, info: dict) -> Part:
    """Measure, triangulate and (if folder) write the STEP file of the part in the current model."""
    occ = gmsh.model.occ
    occ.synchronize()
    if len(volumes) != 1:
        raise RuntimeError(f"{name}: the geometry kernel made {len(volumes)} solids instead of one")
    cad = float(occ.getMass(3, volumes[0]))
    if folder is not None:
        with _quiet():
            gmsh.write(str(folder / f"{name}.step"))
    _mesh(gmsh, plan.scale / 6, CURVATURE)
    surface = _surface(gmsh, volumes)
    surface.tris = orient(surface.points, surface.tris)
    return Part(name, kind, surface, cad, info)


def build_bone(plan: Plan, bone, folder: Path | None = None) -> Part:
    """A bone minus its channels, anchor holes and sockets.

    The removed volume is measured on its own, as the OCC intersection of the
    fused tools with an un-cut copy of the bone, so that the bone's volume
    can be checked against (un-cut volume) - (removed volume).
    """
    import gmsh

    from .geometry import add_design_solids, gmsh_model
    design = plan.design
    with gmsh_model(f"skelfem-fabricate-bone-{bone.name}"):
        occ = gmsh.model.occ
        _, tags = add_design_solids(occ, design, plan.spec.bone_depth or None, bones=[bone.name])
        solid = [(3, t) for t in tags[bone.name]]
        tools = [s for tool in plan.bone_tools[bone.name] for s in _shapes(occ, tool)]
        removed = 0.0
        if tools:
            copies = occ.copy(tools)
            if len(copies) > 1:
                copies, _ = occ.fuse(copies[:1], copies[1:])
            common, _ = occ.intersect(occ.copy(solid), copies)
            occ.synchronize()
            removed = float(sum(occ.getMass(3, t) for t in _volumes(common)))
            occ.remove(common, recursive=True)
            solid = _solid(occ, occ.cut(solid, tools)[0])
        kinds = [t.kind for t in plan.bone_tools[bone.name]]
        info = {"uncut_volume": plan.bone_volumes[bone.name], "removed_volume": removed,
                "channels": kinds.count("channel"), "anchor_holes": kinds.count("anchor"),
                "sockets": kinds.count("socket")}
        return _finish(gmsh, f"bone_{bone.name}", "bone", _volumes(solid), plan, folder, info)


def _block(occ, frame: Frame, n0: float, n1: float) -> tuple[int, float]:
    """The block's slab between n0 and n1 (frame coordinates) as an OCC box; (tag, volume).

    When the frame's axes are the coordinate axes (2D, and 3D planes normal
    to an axis) the box is made in place; otherwise it is made in frame
    coordinates and rotated rigidly (an affine map would turn its faces into
    general surfaces, which the boolean operations handle badly).
    """
    lo, hi = frame.lo.copy(), frame.hi.copy()
    lo[2], hi[2] = n0, n1
    M = frame.matrix
    if np.allclose(np.abs(M), np.round(np.abs(M)), atol=1e-12):
        corners = frame.world(np.array([lo, hi]))
        a, b = corners.min(axis=0), corners.max(axis=0)
        return occ.addBox(*a, *(b - a)), float(np.prod(hi - lo))
    from scipy.spatial.transform import Rotation
    tag = occ.addBox(*lo, *(hi - lo))
    rv = Rotation.from_matrix(M).as_rotvec()
    angle = float(np.linalg.norm(rv))
    if angle > 0:
        occ.rotate([(3, tag)], 0.0, 0.0, 0.0, *(rv / angle), angle)
    return tag, float(np.prod(hi - lo))


def build_half(plan: Plan, side: str, folder: Path | None = None) -> Part:
    """One mould half: its slab of the block minus the body, with pins or pin holes, its pegs, the
    tendon exits and (top) the pour hole and vents."""
    import gmsh

    from .geometry import add_design_solids, gmsh_model
    f = plan.frame
    with gmsh_model(f"skelfem-fabricate-mould-{side}"):
        occ = gmsh.model.occ
        body, _ = add_design_solids(occ, plan.design, bones=[])
        n0, n1 = (f.lo[2], f.c) if side == "bottom" else (f.c, f.hi[2])
        box, block = _block(occ, f, n0, n1)
        half = _solid(occ, occ.cut([(3, box)], [(3, t) for t in body])[0])
        mass = [_mass(occ, half)]                     # the slab minus the body
        adds = [t for t in plan.pegs if t.side == side] + [t for t in plan.mould_tools if t.kind == "pin"
                                                            and side == "bottom"]
        if adds:
            half = _solid(occ, occ.fuse(half, [s for t in adds for s in _shapes(occ, t)])[0])
        mass.append(_mass(occ, half))
        cuts = [t for t in plan.mould_tools
                if t.kind == "exit" or (side == "top" and t.kind in ("pin_hole", "pour", "vent"))]
        if cuts:
            half = _solid(occ, occ.cut(half, [s for t in cuts for s in _shapes(occ, t)])[0])
        mass.append(_mass(occ, half))
        info = {"block_volume": block, "pegs": sum(t.side == side for t in plan.pegs),
                "added_volume": mass[1] - mass[0], "cut_volume": mass[1] - mass[2]}
        return _finish(gmsh, f"mould_{side}", "mould", _volumes(half), plan, folder, info)


# -- the picture ---------------------------------------------------------------------------------------------------
def coarsen(points: np.ndarray, tris: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertex clustering, for drawing: corners in one cube of side h merge at their mean, triangles
    that collapse are dropped. Keeps the look of a surface at a fraction of its triangles."""
    keys = np.floor(points / h).astype(np.int64)
    _, cluster, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    cluster = cluster.ravel()
    merged = np.zeros((len(counts), 3))
    np.add.at(merged, cluster, points)
    t = cluster[tris]
    keep = (t[:, 0] != t[:, 1]) & (t[:, 1] != t[:, 2]) & (t[:, 0] != t[:, 2])
    return merged / counts[:, None], t[keep]


COLOURS = {"bone": (0.93, 0.55, 0.18), "mould_bottom": (0.45, 0.62, 0.85), "mould_top": (0.55, 0.75, 0.60)}


def picture(path, parts: list, plan: Plan, title: str = "") -> None:
    """Exploded view of the parts (matplotlib, headless): mould halves drawn apart along the mould's
    normal (up in the picture), bones between them where they are cast.

    Each triangle is shaded by Lambert's law, colour x (0.35 + 0.65 max(0, n . l)),
    with n its outward normal and l a fixed light from above and in front;
    triangles facing away from the eye (n . e <= 0) are left out, which also
    spares matplotlib's painter's algorithm most of its depth-order mistakes.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    from .output import atomic_write

    f = plan.frame
    elev, azim = math.radians(22), math.radians(-58)
    eye = np.array([math.cos(elev) * math.cos(azim), math.cos(elev) * math.sin(azim), math.sin(elev)])
    height = float(f.hi[2] - f.lo[2])
    shift = {"mould_bottom": -0.9 * height, "mould_top": 0.9 * height}
    light = np.array([0.4, -0.6, 0.7]) / np.linalg.norm([0.4, -0.6, 0.7])
    fig = plt.figure(figsize=(9, 7), dpi=110)
    ax = fig.add_subplot(projection="3d")
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for part in parts:
        h = plan.scale / (150 if part.kind == "mould" else 600)     # the mould halves carry most triangles
        points, tris = coarsen(part.surface.points, part.surface.tris, h)
        y = f.local(points)
        y[:, 2] += shift.get(part.name, 0.0)
        tri = y[tris]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        n /= np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
        facing = n @ eye > 0                # back faces are hidden in a closed solid: not drawn
        tri, n = tri[facing], n[facing]
        base = np.array(COLOURS.get(part.name, COLOURS["bone"]))
        shade = 0.35 + 0.65 * np.clip(n @ light, 0.0, 1.0)
        alpha = 0.35 if part.name == "mould_top" else 1.0
        colours = np.column_stack([np.clip(shade[:, None] * base, 0, 1), np.full(len(tri), alpha)])
        ax.add_collection3d(Poly3DCollection(tri, facecolors=colours, edgecolors=colours,
                                             linewidths=0.2 if alpha == 1.0 else 0.0))
        lo, hi = np.minimum(lo, y.min(axis=0)), np.maximum(hi, y.max(axis=0))
    centre, span = (lo + hi) / 2, (hi - lo)
    for set_lim, c, s in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre, span):
        set_lim(c - s / 2, c + s / 2)
    ax.set_box_aspect(span)
    ax.view_init(elev=math.degrees(elev), azim=math.degrees(azim))
    ax.set_xlabel("u [mm]"), ax.set_ylabel("v [mm]"), ax.set_zlabel("n [mm]")
    ax.tick_params(labelsize=7)
    handles = [plt.Rectangle((0, 0), 1, 1, color=COLOURS[k]) for k in ("mould_top", "bone", "mould_bottom")]
    ax.legend(handles, ["mould top (translucent)", "bones", "mould bottom"], loc="upper left", fontsize=8)
    ax.set_title(title or f"{plan.design.name}: parts, exploded along the mould's normal", fontsize=10)
    fig.subplots_adjust(left=0.0, right=1.0, bottom=0.04, top=0.94)
    atomic_write(Path(path), lambda tmp: fig.savefig(tmp, format="png"))
    plt.close(fig)


# -- everything, into a folder -------------------------------------------------------------------------------------
TOLERANCE = 0.01       # relative: bone volumes and the mould's cavity against their references


def build(plan: Plan, folder: Path | None = None) -> list[Part]:
    """Every part of the plan: the bones in design order, then mould_bottom and mould_top (STEP files
    into folder if given)."""
    parts = [build_bone(plan, b, folder) for b in plan.design.bones]
    return parts + [build_half(plan, side, folder) for side in ("bottom", "top")]


def _plain(x) -> list:
    return [round(float(v), 6) for v in np.ravel(x)]


def write(plan: Plan, folder: Path, picture_file: bool = True) -> dict:
    """Build every part into folder (STL, STEP), check the STL files as written, and write
    fabrication.json and fabrication.png; returns the report (fabrication.json's content)."""
    from . import polygons
    from .output import write_json

    folder = Path(folder)
    design, spec, f = plan.design, plan.spec, plan.frame
    parts = build(plan, folder)
    report = {"format": FORMAT, "design": design.name, "dim": design.dim,
              "bone_depth": spec.bone_depth if design.dim == 2 else None,
              "fabrication": {k: (_plain(v) if isinstance(v, np.ndarray) else v)
                              for k, v in vars(spec).items() if k not in ("split_point", "split_normal")},
              "parts": {}, "bones": {}, "mould": {}, "checks": {}, "notes": list(plan.notes)}
    report["fabrication"]["split"] = {"point": _plain(spec.split_point), "normal": _plain(f.n)}
    if design.dim == 3:
        report["fabrication"].pop("bone_depth")
    stl = {}
    for part in parts:
        path = folder / f"{part.name}.stl"
        write_stl(path, part.surface.points, part.surface.tris, part.name)
        stl[part.name] = check_mesh(*read_stl(path))
        report["parts"][part.name] = {"kind": part.kind, "stl": path.name, "step": f"{part.name}.step",
                                      "volume": part.cad_volume, "stl_volume": stl[part.name]["volume"],
                                      "triangles": stl[part.name]["triangles"]}
    checks = report["checks"]
    checks["stl"] = stl
    for bone, part in zip(design.bones, parts):
        info = part.info
        uncut = abs(polygons.signed_area(bone.outline)) * spec.bone_depth if design.dim == 2 else info["uncut_volume"]
        expected = uncut - info["removed_volume"]
        got = stl[part.name]["volume"]
        report["bones"][bone.name] = {
            "file": f"{part.name}.stl", "uncut_volume": uncut, "removed_volume": info["removed_volume"],
            "expected_volume": expected, "volume": part.cad_volume, "stl_volume": got,
            "relative_error": (got - expected) / expected, "channels": info["channels"],
            "anchor_holes": info["anchor_holes"], "pegs": info["sockets"],
            "cables": sorted({t.cable for t in plan.bone_tools[bone.name] if t.cable})}
    halves = {p.name: p for p in parts if p.kind == "mould"}
    block = sum(p.info["block_volume"] for p in halves.values())
    cavity = block - sum(stl[name]["volume"] for name in halves)
    cavity_cad = block - sum(p.cad_volume for p in halves.values())
    cut = sum(p.info["cut_volume"] for p in halves.values())
    added = sum(p.info["added_volume"] for p in halves.values())
    closed = cavity - cut + added
    report["mould"] = {
        "split": report["fabrication"]["split"], "axes": {"u": _plain(f.u), "v": _plain(f.v), "n": _plain(f.n)},
        "block": {"min": _plain(f.lo), "max": _plain(f.hi), "volume": block},
        "body_volume": plan.body_volume, "cavity_volume": cavity, "cavity_volume_cad": cavity_cad,
        "relative_error": (cavity - plan.body_volume) / plan.body_volume,
        "openings_volume": cut, "pegs_and_pins_volume": added, "closed_cavity_volume": closed,
        "closed_relative_error": (closed - plan.body_volume) / plan.body_volume,
        "pins": [{"at": _plain(t.points[0]), "diameter": 2 * t.radius} for t in plan.mould_tools if t.kind == "pin"],
        "pour": [{"from": _plain(t.points[-1]), "to": _plain(t.points[0]), "diameter": 2 * t.radius}
                 for t in plan.mould_tools if t.kind == "pour"],
        "vents": [{"from": _plain(t.points[-1]), "to": _plain(t.points[0]), "diameter": 2 * t.radius}
                  for t in plan.mould_tools if t.kind == "vent"],
        "exits": {t.cable: {"from": _plain(t.points[0]), "to": _plain(t.points[-1])}
                  for t in plan.mould_tools if t.kind == "exit"},
        "pegs": [{"bone": t.bone, "half": t.side, "tip": _plain(t.points[0]), "diameter": 2 * t.radius}
                 for t in plan.pegs]}
    checks["stl_closed_and_oriented"] = all(r["oriented"] and r["degenerate"] == 0 and r["parts"] == 1
                                            for r in stl.values())
    checks["bone_volumes"] = all(abs(b["relative_error"]) <= TOLERANCE for b in report["bones"].values())
    # the cavity (block minus both halves, from the STL files) holds the body plus what the pour hole,
    # vents, exits and pin holes take out of the halves, minus what the pegs and pins put in
    checks["cavity_is_body"] = abs(report["mould"]["closed_relative_error"]) <= TOLERANCE
    checks["tolerance"] = TOLERANCE
    checks["passed"] = checks["stl_closed_and_oriented"] and checks["bone_volumes"] and checks["cavity_is_body"]
    if picture_file:
        picture(folder / "fabrication.png", parts, plan)
    write_json(folder / "fabrication.json", report)
    return report
