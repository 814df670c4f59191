"""Where a cable runs: its via points on the mesh and the anchors of its ends and bends in silicone.

A cable's sketch (polyline) is cut wherever it crosses a facet of the mesh
(edges in 2D, triangles in 3D); each cut and each sketch vertex is a via
point, a material point that moves with its cell. An end or bend lying in
silicone acts on a finite anchor, a small disk (2D) or ball (3D) of
material, instead of a point. :mod:`skelfem.terms.cables` builds the cable's
energy on these.
"""
from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
from mpi4py import MPI

from ..mesh import keep
from ..mesh.geometry import body_box, body_tags
from ..mesh.points import DofGather, cell_sizes, global_interpolation, locate_cells, owner_ranks
from .base import Context

_EPS = 1e-10


def _mesh_facets(mesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertex coordinates of every facet (n_facets, tdim, gdim), their bounding boxes' lower and
    upper corners), computed once per mesh."""
    def make() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        x = _facet_vertices(mesh)
        return x, x.min(axis=1), x.max(axis=1)
    return keep.kept(mesh, "facets", make)


FACET_CACHE_BYTES = 64 * 2**20   # a mesh keeps its facets' corners (for the next edit's cables) up to this size


def release_facets(mesh) -> None:
    """Forget the facet corners via_points cached on a big mesh (5M facets of a 3D mesh hold 0.6 GB:
    more than the Newton matrix); a small mesh keeps them for the next edit."""
    facets = keep.peek(mesh, "facets")
    if facets is not None and sum(a.nbytes for a in facets) > FACET_CACHE_BYTES:
        keep.forget(mesh, "facets")


def _facet_vertices(mesh) -> np.ndarray:
    tdim = mesh.topology.dim
    mesh.topology.create_connectivity(tdim - 1, 0)
    f2v = mesh.topology.connectivity(tdim - 1, 0).array.reshape(-1, tdim)
    # geometry nodes coincide with topology vertices for affine meshes
    from dolfinx.cpp.mesh import entities_to_geometry
    nodes = entities_to_geometry(mesh._mesh, tdim - 1, np.arange(len(f2v), dtype=np.int32), False)
    return mesh.geometry.x[nodes][:, :, :mesh.geometry.dim]


def _crossings_2d(p, q, facets) -> np.ndarray:
    """Parameters t in (0, 1) where segment p->q crosses edges a->b."""
    a, b = facets[:, 0], facets[:, 1]
    r, e = q - p, b - a
    den = r[0] * e[:, 1] - r[1] * e[:, 0]
    ok = np.abs(den) > 1e-14 * np.linalg.norm(r) * np.linalg.norm(e, axis=1)
    ap = a - p
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ap[:, 0] * e[:, 1] - ap[:, 1] * e[:, 0]) / den
        s = (ap[:, 0] * r[1] - ap[:, 1] * r[0]) / den
    hit = ok & (t > -_EPS) & (t < 1 + _EPS) & (s > -_EPS) & (s < 1 + _EPS)
    return t[hit]


def _crossings_3d(p, q, facets) -> np.ndarray:
    """Parameters t in (0, 1) where segment p->q crosses triangles (Moller-Trumbore)."""
    v0, e1, e2 = facets[:, 0], facets[:, 1] - facets[:, 0], facets[:, 2] - facets[:, 0]
    r = q - p
    h = np.cross(r, e2)
    det = np.einsum("ij,ij->i", e1, h)
    ok = np.abs(det) > 1e-14 * np.linalg.norm(r) * np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        sv = p - v0
        a = inv * np.einsum("ij,ij->i", sv, h)
        qv = np.cross(sv, e1)
        b = inv * (qv @ r)
        t = inv * np.einsum("ij,ij->i", e2, qv)
        hit = ok & (a > -_EPS) & (b > -_EPS) & (a + b < 1 + _EPS) & (t > -_EPS) & (t < 1 + _EPS)
    return t[hit]


def via_points(mesh, path: np.ndarray, pieces: int = 1) -> np.ndarray:
    """Sketch vertices plus every crossing with a mesh facet, in order along the path, and the
    piece inside each cell cut into `pieces` equal parts.

    Each rank cuts the sketch with its own facets; the cuts are gathered, so
    every rank gets the same via points as a serial run. With P1 a straight
    piece of the sketch stays straight inside its cell (the map is affine);
    with P2 it bends into a parabola, and a chord across the whole cell cuts
    its corner by kappa s^2 / 8 (kappa its curvature, s its length): the
    cable's length and its lever arm about a joint are then off by an amount
    that changes from mesh to mesh (0.015 mm at the tip of a tapered finger,
    0.04 mm on finger.toml, P2 at h = 1).
    `pieces` chords per cell cut that by pieces^2 (``PIECES``).
    """
    path = np.asarray(path, dtype=float)
    facets, lo_f, hi_f = _mesh_facets(mesh)
    crossings = _crossings_2d if mesh.geometry.dim == 2 else _crossings_3d
    cuts = []
    for p, q in zip(path[:-1], path[1:]):  # loop over sketch segments, not DOFs
        lo, hi = np.minimum(p, q), np.maximum(p, q)
        tol = 1e-9 * (1.0 + np.abs(hi).max())
        near = np.all((hi_f >= lo - tol) & (lo_f <= hi + tol), axis=1)
        cuts.append(np.clip(crossings(p, q, facets[near]), 0.0, 1.0))
    if mesh.comm.size > 1:
        cuts = [np.concatenate(mesh.comm.allgather(t)) for t in cuts]
    out = []
    for p, q, t in zip(path[:-1], path[1:], cuts):
        t = np.unique(np.concatenate([[0.0], t]))
        seg_len = float(np.linalg.norm(q - p))
        keep = np.concatenate([[True], np.diff(t) * seg_len > 1e-9 * max(seg_len, 1.0)])
        t = _subdivide(np.append(t[keep], 1.0), pieces)[:-1]
        out.append(p + t[:, None] * (q - p))
    points = np.vstack(out + [path[-1:]])
    gap = np.linalg.norm(np.diff(points, axis=0), axis=1)
    return points[np.concatenate([[True], gap > 1e-12])]


PIECES = {1: 1, 2: 4}          # chords per cell along a cable, by the displacement's degree


def _subdivide(t: np.ndarray, pieces: int) -> np.ndarray:
    """The increasing parameters t with every interval cut into `pieces` equal parts."""
    if pieces <= 1 or len(t) < 2:
        return t
    f = np.arange(pieces) / pieces
    inner = (t[:-1, None] + f * np.diff(t)[:, None]).ravel()
    return np.append(inner, t[-1])


PER_RADIUS = {2: 8, 3: 6}       # lattice points per anchor radius, at least ...
MAX_PER_RADIUS = {2: 32, 3: 8}  # ... and at most ((2n + 1)^dim lattice points)


def lattice_density(mesh, center: np.ndarray, radius: float) -> int:
    """Lattice points per radius for an anchor: two per size of the smallest cell near the disk (ball).

    The lattice approximates the disk's weighted mean displacement (a bounded
    functional of u: a finite answer) only while every cell the disk covers
    holds several lattice points; with a lattice fixed in mm, a
    mesh finer than its spacing sees each point as a point force again, and
    its 2D displacement is log-singular. Clipped to [PER_RADIUS, MAX_PER_RADIUS].
    Collective under MPI (every rank gets the same number).
    """
    dim = mesh.topology.dim
    n_owned = mesh.topology.index_map(dim).size_local
    x = mesh.geometry.x[:, :mesh.geometry.dim]
    nodes = mesh.geometry.dofmap.array.reshape(-1, dim + 1)[:n_owned]
    h = cell_sizes(mesh)[:n_owned]
    mid = x[nodes].mean(axis=1) if n_owned else np.zeros((0, dim))
    near = np.linalg.norm(mid - center, axis=1) <= radius + h        # the cells the disk touches
    h_min = mesh.comm.allreduce(float(h[near].min()) if near.any() else np.inf, op=MPI.MIN)
    if not np.isfinite(h_min):
        return PER_RADIUS[dim]
    return int(np.clip(math.ceil(2.0 * radius / h_min), PER_RADIUS[dim], MAX_PER_RADIUS[dim]))


def anchor_samples(center: np.ndarray, radius: float, per_radius: int | None = None) -> np.ndarray:
    """Points of a square (2D) or cubic (3D) lattice inside the disk/ball, spacing radius / per_radius
    (default PER_RADIUS).

    With the weights of `anchor_weights` the lattice spreads the anchor's force
    over its area (volume): a distributed load instead of a point force,
    whose 2D displacement is log-singular.
    """
    gdim = len(center)
    per_radius = per_radius or PER_RADIUS[gdim]
    axis = np.arange(-per_radius, per_radius + 1) * (radius / per_radius)
    grid = np.stack(np.meshgrid(*([axis] * gdim), indexing="ij"), axis=-1).reshape(-1, gdim)
    return center + grid[np.linalg.norm(grid, axis=1) <= radius * (1 + 1e-12)]


def anchor_weights(points: np.ndarray, center: np.ndarray, radius: float) -> np.ndarray:
    """w = (1 - rho^2)^2, rho = |x - c| / r: the anchor's load density, zero with its slope on the rim.

    A smooth density makes the lattice an accurate quadrature of the disk's
    weighted mean: on the thumb (0.72 mm anchor, P2 at h = 0.5) 8 points per
    radius are 9e-5 mm from 32, where equal weights (a density that jumps at
    the rim) were 8e-3 mm off.
    """
    rho2 = np.sum((points - center) ** 2, axis=1) / radius ** 2
    return np.clip(1.0 - rho2, 0.0, None) ** 2


def anchored_interpolation(V, X: np.ndarray, anchors: dict):
    """(X, S, DofGather, owner of each via point) for via points X of which {index: radius} (ends,
    bends) act on a disk (ball): each anchored point moves to the weighted centroid of its disk's
    lattice points inside the mesh (weights w_k of `anchor_weights`, summing to 1), its row of S
    becomes their weighted mean, and the via points inside its disk go.

    S_anchored = A S_all over the via points and every anchor's lattice
    points inside the mesh (A: identity rows, and rows of the weights).
    The anchored end is then a material point, x = sum w_k (X_k + u_k), that moves
    with the body. Had it kept the sketch's end X_e, x = X_e + sum w_k u_k would carry
    the offset X_e - sum w_k X_k (not zero when the body's edge cuts the disk) unrotated,
    and the cable's length would change under a rigid rotation. Via points
    inside the disk would make the cable turn back to its centroid.
    """
    mesh = V.mesh
    anchored = {int(i): r for i, r in anchors.items() if r > 0.0}
    if not anchored:
        return (X, *global_interpolation(V, X))
    keep = np.ones(len(X), dtype=bool)
    for i, r in anchored.items():
        keep &= np.linalg.norm(X - X[i], axis=1) >= r
    keep[list(anchored)] = True
    renumber = np.cumsum(keep) - 1
    anchored = {int(renumber[i]): r for i, r in anchored.items()}
    X = X[keep]
    gdim = mesh.geometry.dim
    points, rows, cols, vals = [X], [], [], []
    X = X.copy()
    n = len(X)
    for i in range(n):
        if i not in anchored:
            rows.append(i)
            cols.append(i)
            vals.append(1.0)
    offset = n
    for i, r in anchored.items():
        samples = anchor_samples(X[i], r, lattice_density(mesh, X[i], r))
        w = anchor_weights(samples, X[i], r)
        samples, w = samples[w > 0.0], w[w > 0.0]                # the rim carries nothing
        inside = owner_ranks(mesh, samples)[0] < mesh.comm.size
        samples, w = samples[inside], w[inside] / w[inside].sum()
        X[i] = w @ samples
        points.append(samples)
        m = len(samples)
        rows += [i] * m
        cols += list(range(offset, offset + m))
        vals += list(w)
        offset += m
    c = np.arange(gdim)                                          # A (x) I_gdim, built directly
    rows = (np.asarray(rows)[:, None] * gdim + c).ravel()
    cols = (np.asarray(cols)[:, None] * gdim + c).ravel()
    A = sp.csr_matrix((np.repeat(vals, gdim), (rows, cols)), shape=(n * gdim, offset * gdim))
    S_all, gather_all, owner = global_interpolation(V, np.vstack(points))
    S = (A @ S_all).tocsc()
    used = np.flatnonzero(np.diff(S.indptr) > 0)                # DOFs some via point still touches
    gather = DofGather(V, gather_all.dofs[used])
    return X, S[:, used].tocsr(), gather, owner[:n]


def differences(S: sp.csr_matrix, gdim: int) -> sp.csr_matrix:
    """B = D S: row block i (segment i) is S's row block i + 1 (via point i + 1) minus block i."""
    C = S.tocoo()
    n = S.shape[0] - gdim
    later, earlier = C.row >= gdim, C.row < n
    rows = np.concatenate([C.row[later] - gdim, C.row[earlier]])
    B = sp.csr_matrix((np.concatenate([C.data[later], -C.data[earlier]]),
                       (rows, np.concatenate([C.col[later], C.col[earlier]]))), shape=(n, S.shape[1]))
    B.eliminate_zeros()
    return B


def default_anchor_radius(ctx: Context) -> float:
    """1 % of the body's bounding-box diagonal (about a knot or bead on a finger-sized body): the box of
    the soft bodies' cells (bones lie inside them), never of the objects, which are not the robot (an
    object 10 m away made the radius 100 mm, and the anchors of a 60 mm tendon swallowed it whole)."""
    if ctx.anchor_radius is None:
        ctx.anchor_radius = _one_percent_of_diagonal(ctx)
    return ctx.anchor_radius


def _one_percent_of_diagonal(ctx: Context) -> float:
    lo, hi = body_box(ctx.tagged, ctx.design)
    return 0.01 * float(np.linalg.norm(hi - lo))


def anchors(ctx: Context, spec) -> dict:
    """{sketch vertex index: radius} for the cable's ends and bends that lie in silicone (the body's
    region, not a bone) and not in a fixed pin's box: those act on a finite anchor (a bend pushes
    on the silicone with 2 T sin(theta / 2), a point force unless spread); ends and bends in bones
    or on the pinned base stay material points."""
    radius = spec.anchor_radius if spec.anchor_radius is not None else default_anchor_radius(ctx)
    if radius <= 0.0:
        return {}
    points = np.asarray(spec.path, dtype=float)
    tm = ctx.tagged
    n_owned = ctx.mesh.topology.index_map(ctx.mesh.topology.dim).size_local
    cells = locate_cells(ctx.mesh, points, below=n_owned)
    soft_cells = tm.cell_tags.indices[np.isin(tm.cell_tags.values, body_tags(tm, ctx.design))]
    soft = np.where(cells >= 0, np.isin(cells, soft_cells), False).astype(np.int32)
    found = (cells >= 0).astype(np.int32)
    if ctx.comm.size > 1:
        ctx.comm.Allreduce(MPI.IN_PLACE, soft, op=MPI.MAX)
        ctx.comm.Allreduce(MPI.IN_PLACE, found, op=MPI.MAX)
    fixed_boxes = [p.region for p in ctx.design.pins if p.kind == "fixed"]
    out = {}
    for k, point in enumerate(points):
        pinned = any(np.all(point >= box[0] - 1e-9) and np.all(point <= box[1] + 1e-9) for box in fixed_boxes)
        if found[k] and soft[k] and not pinned:
            out[k] = radius
    return out
