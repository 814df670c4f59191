"""Tendons and ligaments: unilateral springs routed through via points.

A cable's sketch (polyline) is cut wherever it crosses a facet of the mesh
(edges in 2D, triangles in 3D); each cut and each sketch vertex is a via
point X_j, a material point that moves with its cell: x_j = X_j + (S u)_j.
With segment vectors d_i = x_{i+1} - x_i = d0_i + (B u)_i (B = D S, D the
difference operator), the cable length is

    l(u) = sum_i |d_i|,

and the cable stores the unilateral spring energy (paper eq. 3)

    U = k Q(l - L),  Q(s) = s^2/2 for s > 0, 0 otherwise,

with rest length L = L0 - u_c for a tendon contracted by u_c and
L = L0 - p for a ligament pretensioned by p (L0: the length at rest). Its
derivatives, with t_i = d_i/|d_i| and s = max(l - L, 0):

    grad U = k s g,                    g = B^T t
    hess U = k [l > L] (g g^T + s B^T W B),   W = blockdiag((I - t_i t_i^T)/|d_i|)

Dropping the curvature term k s B^T W B costs Newton its quadratic
convergence, so it stays. It is sparse: segment i couples only the DOFs of
the cells holding its two via points (one cell, as the sketch is cut at
every facet). The rank-one part k g g^T couples every DOF along the cable;
it never enters the Newton matrix (``low_rank``: the linear solver adds it
with the Sherman-Morrison-Woodbury formula), so a taut cable costs the
matrix a few entries per segment and the solve one extra back-substitution.
A segment at a finite anchor couples every DOF of its disk; above WIDE DOFs
its curvature block, of rank gdim - 1, joins the low-rank parts too.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from mpi4py import MPI

from ..mesh.points import DofGather, cell_sizes, global_interpolation, locate_cells, owner_ranks
from .base import Context, Term

_EPS = 1e-10


def _mesh_facets(mesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertex coordinates of every facet (n_facets, tdim, gdim), their bounding boxes' lower and
    upper corners), computed once per mesh."""
    facets = getattr(mesh, "_skelfem_facets", None)
    if facets is None:
        x = _facet_vertices(mesh)
        facets = mesh._skelfem_facets = (x, x.min(axis=1), x.max(axis=1))
    return facets


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
        seg_len = np.linalg.norm(q - p)
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


def _anchored_interpolation(V, X: np.ndarray, anchors: dict):
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
            rows.append(i), cols.append(i), vals.append(1.0)
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


def _differences(S: sp.csr_matrix, gdim: int) -> sp.csr_matrix:
    """B = D S: row block i (segment i) is S's row block i + 1 (via point i + 1) minus block i."""
    C = S.tocoo()
    n = S.shape[0] - gdim
    later, earlier = C.row >= gdim, C.row < n
    rows = np.concatenate([C.row[later] - gdim, C.row[earlier]])
    B = sp.csr_matrix((np.concatenate([C.data[later], -C.data[earlier]]),
                       (rows, np.concatenate([C.col[later], C.col[earlier]]))), shape=(n, S.shape[1]))
    B.eliminate_zeros()
    return B


WIDE = 256    # DOFs: a segment coupling more (an anchor disk's) has its curvature as rank-one parts


def _normals(t: np.ndarray) -> np.ndarray:
    """An orthonormal basis of the plane (2D: line) normal to the unit vector t, as rows."""
    if len(t) == 2:
        return np.array([[-t[1], t[0]]])
    a = np.eye(3)[int(np.argmin(np.abs(t)))]
    n1 = np.cross(t, a)
    n1 /= np.linalg.norm(n1)
    return np.array([n1, np.cross(t, n1)])


def _block_diagonal(blocks: np.ndarray) -> sp.csr_matrix:
    """Sparse block-diagonal matrix from stacked (n, b, b) blocks, no Python loop."""
    n, b, _ = blocks.shape
    base = (np.arange(n) * b)[:, None, None]
    rows = np.broadcast_to(base + np.arange(b)[None, :, None], blocks.shape)
    cols = np.broadcast_to(base + np.arange(b)[None, None, :], blocks.shape)
    return sp.csr_matrix((blocks.ravel(), (rows.ravel(), cols.ravel())), shape=(n * b, n * b))


@dataclass(eq=False)
class Cable:
    """One tendon or ligament, with its via points bound to the mesh."""

    name: str
    kind: str                # "tendon" or "ligament"
    k: float                 # spring constant, N/mm
    X: np.ndarray            # via points at rest, (n, gdim)
    dofs: np.ndarray         # global DOF numbers the cable touches, sorted (m,); local = global in serial
    S: sp.csr_matrix         # via point interpolation restricted to dofs, (n*gdim, m)
    B: sp.csr_matrix         # D S restricted to dofs, (n_seg*gdim, m)
    d0: np.ndarray           # rest segment vectors D X, (n_seg, gdim)
    L0: float                # length through the via points at rest
    gather: DofGather        # u (local array) -> u on `dofs`, on every rank
    contraction: float = 0.0
    pretension: float = 0.0

    def __post_init__(self):
        self.BT = self.B.T.tocsr()      # g = B^T t, every gradient evaluation

    @classmethod
    def build(cls, V, spec, anchors: dict | None = None) -> "Cable":
        """The cable through its via points; anchors = {sketch vertex index: radius} makes that vertex
        (an end, or a bend) act on the mean displacement of a disk (2D) or ball (3D) of that radius
        (a finite anchor: the cable runs through the disk's material centroid) instead of a material point."""
        mesh = V.mesh
        X = via_points(mesh, spec.path, PIECES.get(V.ufl_element().degree(), 4))
        path = np.asarray(spec.path, dtype=float)
        at = {}
        for k, r in (anchors or {}).items():       # sketch vertex -> its via point (the sketch's own vertex)
            i = 0 if k == 0 else len(X) - 1 if k in (-1, len(path) - 1) else \
                int(np.argmin(np.linalg.norm(X - path[k], axis=1)))
            at[i] = r
        X, S, gather, owner = _anchored_interpolation(V, X, at)
        if np.any(owner == mesh.comm.size):
            raise ValueError(f"cable {spec.name!r} leaves the mesh")
        d0 = np.diff(X, axis=0)
        return cls(spec.name, spec.kind, float(spec.stiffness), X, gather.dofs,
                   S, _differences(S, mesh.geometry.dim), d0, float(np.linalg.norm(d0, axis=1).sum()), gather,
                   float(spec.contraction), float(spec.pretension))

    # -- state ---------------------------------------------------------------
    def rest_length(self, factor: float = 1.0) -> float:
        """L = L0 - u_c (tendon) or L0 - p (ligament), ramped by the load factor."""
        shortening = self.contraction if self.kind == "tendon" else self.pretension
        return self.L0 - factor * shortening

    def values(self, u: np.ndarray) -> np.ndarray:
        """u on the cable's DOFs (`dofs`), from the local array u."""
        return self.gather(u)

    def segments(self, u: np.ndarray) -> np.ndarray:
        """Current segment vectors d_i, (n_seg, gdim)."""
        return self.d0 + (self.B @ self.values(u)).reshape(self.d0.shape)

    def positions(self, u: np.ndarray) -> np.ndarray:
        """Current via point positions, (n, gdim)."""
        return self.X + (self.S @ self.values(u)).reshape(self.X.shape)

    def length(self, u: np.ndarray) -> float:
        return float(np.linalg.norm(self.segments(u), axis=1).sum())

    def tension(self, u: np.ndarray, L: float) -> float:
        return self.k * max(0.0, self.length(u) - L)

    # -- energy and derivatives -------------------------------------------------
    def energy(self, u: np.ndarray, L: float) -> float:
        s = max(0.0, self.length(u) - L)
        return 0.5 * self.k * s * s

    def _t_and_g(self, u):
        d = self.segments(u)
        norm = np.linalg.norm(d, axis=1)
        t = d / norm[:, None]
        return d, norm, t, self.BT @ t.ravel()

    def gradient(self, u: np.ndarray, L: float) -> np.ndarray:
        """Gradient on self.dofs: k s g."""
        _, norm, _, g = self._t_and_g(u)
        s = max(0.0, norm.sum() - L)
        return self.k * s * g

    def _segment_blocks(self):
        """Per narrow segment i: B_i densely on the cable DOFs J_i it touches, grouped by |J_i|, and the COO
        indices; and the wide segments (more than WIDE DOFs: an anchored end or bend touches every DOF of
        its anchor disk), whose curvature goes to the low-rank part (`wide_parts`).

        Built once; the curvature part is then sum_i B_i^T W_i B_i evaluated
        for all narrow segments of a group at once (batched matrix products),
        grouped by width rather than padded to the widest. The COO row and
        column arrays are the same objects every call (the model caches their
        map into the Newton matrix). Returns (groups, rows, cols, J, wide)
        with groups = [(segments, B_g, B_g^T)], J[i] the cable DOFs of
        segment i, and wide the wide segments' indices.
        """
        if getattr(self, "_blocks", None) is None:
            C = self.B.tocoo()
            nseg, gdim = self.d0.shape
            m = self.B.shape[1]
            seg, comp = C.row // gdim, C.row % gdim
            keys, inv = np.unique(seg.astype(np.int64) * m + C.col, return_inverse=True)
            useg, ucol = keys // m, keys % m                      # (segment, DOF) pairs, sorted
            start = np.searchsorted(useg, np.arange(nseg))
            pos = np.arange(len(keys)) - start[useg]              # the DOF's slot in its segment
            width = np.bincount(useg, minlength=nseg)
            J = np.split(ucol, start[1:])
            groups, rows, cols = [], [], []
            for w in np.unique(width[(width > 0) & (width <= WIDE)]):
                members = np.flatnonzero(width == w)
                slot = np.full(nseg, -1)
                slot[members] = np.arange(len(members))
                e = width[seg] == w                               # the entries of this group's segments
                Bd = np.zeros((len(members), gdim, w))
                np.add.at(Bd, (slot[seg[e]], comp[e], pos[inv[e]]), C.data[e])
                Jg = np.stack([J[i] for i in members])            # once per cable, not per call
                rows.append(np.broadcast_to(Jg[:, :, None], (len(members), w, w)).ravel())
                cols.append(np.broadcast_to(Jg[:, None, :], (len(members), w, w)).ravel())
                groups.append((members, Bd, np.ascontiguousarray(Bd.transpose(0, 2, 1))))
            cat = (lambda a: np.concatenate(a).astype(np.int32)) if groups else \
                (lambda a: np.zeros(0, dtype=np.int32))
            self._blocks = (groups, cat(rows), cat(cols), J, np.flatnonzero(width > WIDE))
        return self._blocks

    def curvature(self, u: np.ndarray, L: float) -> sp.coo_matrix:
        """Sparse part of the Hessian on self.dofs: k [s > 0] s B_i^T W_i B_i of the narrow segments
        (COO, duplicates summed later)."""
        d, norm, t, g = self._t_and_g(u)
        s = norm.sum() - L
        m = len(self.dofs)
        if s <= 0.0:
            return sp.coo_matrix((m, m))
        groups, rows, cols, _, _ = self._segment_blocks()
        gdim = d.shape[1]
        W = (np.eye(gdim)[None] - t[:, :, None] * t[:, None, :]) / norm[:, None, None]
        data = [np.matmul(BdT, np.matmul(W[members], Bd)).ravel() for members, Bd, BdT in groups]
        data = (self.k * s) * np.concatenate(data) if data else np.zeros(0)
        return sp.coo_matrix((data, (rows, cols)), shape=(m, m))

    def wide_parts(self, u: np.ndarray, L: float) -> list[tuple[float, np.ndarray]]:
        """The wide segments' curvature k s B_i^T W_i B_i as rank-one parts [(c, g)] on self.dofs.

        W_i = (I - t_i t_i^T) / |d_i| = sum_j n_j n_j^T / |d_i| over an orthonormal
        basis n_j of the plane normal to t_i (one vector in 2D, two in 3D), so
        the block is sum_j (k s / |d_i|) (B_i^T n_j)(B_i^T n_j)^T: gdim - 1 rank-one
        parts per wide segment instead of a dense block over its disk's DOFs
        in the Newton matrix (whose factorisation fills in with it).
        """
        _, norm, t, _ = self._t_and_g(u)
        return self._wide(t, norm, norm.sum() - L)

    def _wide(self, t: np.ndarray, norm: np.ndarray, s: float) -> list[tuple[float, np.ndarray]]:
        wide = self._segment_blocks()[4]
        if s <= 0.0 or not len(wide):
            return []
        gdim = t.shape[1]
        out = []
        for i in wide:                                   # a few per cable: its anchored ends and bends
            Bi = self.B[i * gdim:(i + 1) * gdim]
            for n in _normals(t[i]):
                out.append((self.k * s / norm[i], np.asarray(Bi.T @ n).ravel()))
        return out

    def low_rank_parts(self, u: np.ndarray, L: float) -> list[tuple[float, np.ndarray]]:
        """[(c, g)] on self.dofs: k g g^T (g = B^T t) and the wide segments' curvature, when taut."""
        _, norm, t, g = self._t_and_g(u)
        s = norm.sum() - L
        return [(self.k, g)] + self._wide(t, norm, s) if s > 0.0 else []

    def length_gradient(self, u: np.ndarray) -> np.ndarray:
        """g = grad l = B^T t on self.dofs."""
        return self._t_and_g(u)[3]

    def hessian(self, u: np.ndarray, L: float) -> np.ndarray:
        """Dense Hessian on self.dofs, k [s > 0] (g g^T + s B^T W B) (for tests)."""
        g = self.length_gradient(u)
        taut = self.length(u) > L
        H = self.curvature(u, L).toarray() + (self.k * np.outer(g, g) if taut else 0.0)
        for c, w in self.wide_parts(u, L):
            H += c * np.outer(w, w)
        return H

    def segment_nodes(self, bs: int) -> list[np.ndarray]:
        """Global node numbers each narrow segment's curvature block couples (one array per segment; a
        node may repeat, once per component: the matrix pattern takes repeats)."""
        nodes = self.dofs // bs
        _, _, _, J, wide = self._segment_blocks()
        narrow = np.ones(len(J), dtype=bool)
        narrow[wide] = False
        return [nodes[j] for j, keep in zip(J, narrow) if keep]


class CableTerm(Term):
    """One cable as an energy term; its rest length follows the load factor.

    Parameters: ``cables.NAME.contraction`` (tendons) or ``.pretension``
    (ligaments), and ``.stiffness``. Read-out: kind, contraction, rest
    length, length and tension.
    """

    section = "cables"

    def __init__(self, ctx: Context, spec):
        try:
            self.anchors = anchors(ctx, spec)
            self.cable = Cable.build(ctx.V, spec, self.anchors)
        except ValueError as exc:
            from ..design.spec import DesignError
            raise DesignError(f"{ctx.design.source}: cables.{spec.name}.path: {exc}") from None
        self.name, self.kind, self.bs = spec.name, spec.kind, ctx.bs
        self.actuated = spec.kind == "tendon"
        self.disks = [(np.asarray(spec.path[k], dtype=float), r) for k, r in self.anchors.items()]   # (centre, r)
        self.gather = self.cable.gather
        self.factor = 0.0

    def finite_anchors(self) -> list:
        return list(self.disks)

    @property
    def rest_length(self) -> float:
        return self.cable.rest_length(self.factor)

    def set_factor(self, a: float) -> None:
        self.factor = float(a)

    def energy(self, u):
        return self.cable.energy(u, self.rest_length)

    def gradient(self, u):
        return self.cable.dofs, self.cable.gradient(u, self.rest_length)

    def hessian(self, u):
        return [(self.cable.dofs, self.cable.curvature(u, self.rest_length))]

    def low_rank(self, u):
        return [(c, self.cable.dofs, g) for c, g in self.cable.low_rank_parts(u, self.rest_length)]

    def pattern(self):
        return [(n, n) for n in self.cable.segment_nodes(self.bs)]

    def parameters(self) -> dict:
        c = self.cable
        which = "contraction" if self.kind == "tendon" else "pretension"
        return {f"cables.{self.name}.{which}": getattr(c, which), f"cables.{self.name}.stiffness": c.k}

    def set_parameter(self, key: str, value) -> None:
        which = key.rsplit(".", 1)[1]
        if which not in self.parameters() and key not in self.parameters():
            raise KeyError(key)
        if which == "stiffness":
            self.cable.k = float(value)
        else:
            setattr(self.cable, which, float(value))

    def readout(self, model) -> dict:
        u, c, L = model.u.x.array, self.cable, self.rest_length
        return {self.name: {"kind": self.kind, "contraction": float(c.contraction), "rest_length": L,
                            "length": c.length(u), "tension": c.tension(u, L)}}


def default_anchor_radius(ctx: Context) -> float:
    """1 % of the body's bounding-box diagonal (about a knot or bead on a finger-sized body)."""
    radius = getattr(ctx, "_anchor_radius", None)
    if radius is None:
        radius = ctx._anchor_radius = _one_percent_of_diagonal(ctx)
    return radius


def _one_percent_of_diagonal(ctx: Context) -> float:
    x = ctx.mesh.geometry.x[:, :ctx.dim]
    lo = x.min(axis=0) if len(x) else np.full(ctx.dim, np.inf)
    hi = x.max(axis=0) if len(x) else np.full(ctx.dim, -np.inf)
    if ctx.comm.size > 1:
        ctx.comm.Allreduce(MPI.IN_PLACE, lo, op=MPI.MIN)
        ctx.comm.Allreduce(MPI.IN_PLACE, hi, op=MPI.MAX)
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
    soft_cells = tm.cell_tags.indices[tm.cell_tags.values == tm.tags["body"]]
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


def build(ctx: Context) -> list[Term]:
    return [CableTerm(ctx, spec) for spec in ctx.design.cables]
