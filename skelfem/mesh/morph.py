"""Moving a 2D mesh with its design's outlines, instead of re-meshing (the editor's drafts).

While a person drags a vertex of the body outline, a hole or a bone, the
design's polygons keep their vertex counts and only move. The mesh that was
generated for the design X0 can then follow: every mesh node on a polygon
edge (a, b) at x = (1 - t) a + t b moves with

    delta = (1 - t) delta_a + t delta_b,

and the other nodes by the harmonic extension of those moves (the P1
Laplace equation on the mesh, factorised once per mesh):

    K_II delta_I = -K_IB delta_B.

The moved mesh has the same topology, cells, region tags and DOF numbering,
so the last solution is the exact start, and nothing is meshed or compiled.
Each move is taken from the mesh as generated (X0), so drags do not drift.
When the moved mesh would be poor (a triangle turned over or its shape
ratio below MIN_QUALITY) or the polygons changed otherwise, :meth:`Morph.moved`
returns None and the caller re-meshes.

The answer on a moved mesh differs from a fresh mesh of the same design by
the discretisation error only; the editor re-meshes when the drag ends.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from . import keep

MIN_QUALITY = 0.25        # smallest shape ratio 2 r / R of a moved triangle (1: equilateral)


def same_polygons(a, b) -> bool:
    """Whether two designs have the same closed polygons, vertex for vertex."""
    new, old = polygons(a), polygons(b)
    return len(new) == len(old) and all(p.shape == q.shape and np.array_equal(p, q) for p, q in zip(new, old))


def polygons(design) -> list[np.ndarray]:
    """The design's closed polygons, in a fixed order: each body's outline and holes, bone outlines, object
    outlines."""
    out = list(design.body_loops) + [b.outline for b in design.bones] \
        + [o.outline for o in design.objects]
    return [np.asarray(p, dtype=float) for p in out]


def shape_ratio(x: np.ndarray, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(signed area, 2 r / R) of every triangle."""
    a, b, c = x[cells[:, 0]], x[cells[:, 1]], x[cells[:, 2]]
    e1, e2 = b - a, c - a
    area = 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    la, lb, lc = (np.linalg.norm(v, axis=1) for v in (c - b, c - a, b - a))
    with np.errstate(divide="ignore", invalid="ignore"):
        q = 16.0 * area ** 2 / (la * lb * lc * (la + lb + lc))     # = 2 r / R
    return area, np.nan_to_num(q)


def laplacian(x: np.ndarray, cells: np.ndarray) -> sp.csr_matrix:
    """The P1 stiffness matrix of the Laplacian (cotangent weights), assembled without a cell loop."""
    a, b, c = x[cells[:, 0]], x[cells[:, 1]], x[cells[:, 2]]
    area = np.abs(0.5 * ((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0]))
    # gradients of the barycentric coordinates: grad phi_i = rot90(opposite edge) / (2 area)
    edges = np.stack([c - b, a - c, b - a], axis=1)                         # (n, 3, 2)
    grads = np.stack([-edges[..., 1], edges[..., 0]], axis=2) / (2 * area)[:, None, None]
    local = np.einsum("nik,njk->nij", grads, grads) * area[:, None, None]
    rows = np.repeat(cells, 3, axis=1)
    cols = np.tile(cells, (1, 3))
    n = len(x)
    return sp.csr_matrix((local.ravel(), (rows.ravel(), cols.ravel())), shape=(n, n))


class Morph:
    """The mesh of one design, movable to designs whose polygons differ only in vertex positions."""

    def __init__(self, tagged_mesh, design):
        mesh = tagged_mesh.mesh
        self.mesh, self.tagged = mesh, tagged_mesh
        self.X0 = mesh.geometry.x[:, :2].copy()
        self.cells = mesh.geometry.dofmap.array.reshape(-1, 3)
        self.polys0 = polygons(design)
        self.area0, _ = shape_ratio(self.X0, self.cells)
        self.bound, self.edge, self.t = self._on_edges()
        free = np.ones(len(self.X0), dtype=bool)
        free[self.bound] = False
        self.free = np.flatnonzero(free)
        K = laplacian(self.X0, self.cells)
        self.K_IB = K[self.free][:, self.bound]
        self._solve = spla.factorized(K[self.free][:, self.free].tocsc()) if len(self.free) else None

    def _on_edges(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The nodes lying on polygon edges: (node, (polygon, edge) of each, parameter t along it)."""
        X = self.X0
        tol = 1e-7 * (1.0 + float(np.abs(X).max()))
        on_edge = np.zeros(len(X), dtype=bool)
        which = np.zeros((len(X), 2), dtype=int)
        t_of = np.zeros(len(X))
        for k, poly in enumerate(self.polys0):        # a loop over polygon edges, not over nodes
            for i, (a, b) in enumerate(zip(poly, np.roll(poly, -1, axis=0))):
                ab = b - a
                t = np.clip((X - a) @ ab / max(float(ab @ ab), 1e-300), 0.0, 1.0)
                on = np.linalg.norm(X - (a + t[:, None] * ab), axis=1) <= tol
                on_edge |= on
                which[on] = (k, i)
                t_of[on] = t[on]
        bound = np.flatnonzero(on_edge)
        return bound, which[bound], t_of[bound]

    def moved(self, design) -> np.ndarray | None:
        """Node coordinates (n, 2) of this mesh moved to `design`'s polygons, or None if it cannot follow."""
        if design.dim != 2:
            return None
        polys = polygons(design)
        if len(polys) != len(self.polys0) or any(p.shape != q.shape for p, q in zip(polys, self.polys0)):
            return None
        x = self.X0 + self.displacement([p - q for p, q in zip(polys, self.polys0)])
        area, quality = shape_ratio(x, self.cells)
        if np.any(area * np.sign(self.area0) <= 0.0) or quality.min() < MIN_QUALITY:
            return None
        return x

    def _vertex_map(self) -> sp.csr_matrix:
        """W: the boundary nodes' moves (n_bound, per axis) from the stacked polygon vertex moves."""
        n_vertices = np.array([len(p) for p in self.polys0])
        offsets = np.r_[0, np.cumsum(n_vertices)[:-1]]
        k, i = self.edge[:, 0], self.edge[:, 1]
        a, b = offsets[k] + i, offsets[k] + (i + 1) % n_vertices[k]
        rows = np.arange(len(self.bound))
        return sp.csr_matrix((np.r_[1.0 - self.t, self.t], (np.r_[rows, rows], np.r_[a, b])),
                             shape=(len(self.bound), int(n_vertices.sum())))

    def displacement(self, moves) -> np.ndarray:
        """The node moves (n, 2) for polygon vertex moves (one (m_i, 2) array per polygon, in
        ``polygons`` order): linear in them (the edge interpolation, then the harmonic extension)."""
        delta = np.zeros_like(self.X0)
        delta[self.bound] = self._vertex_map() @ np.vstack(moves)
        if self._solve is not None:
            rhs = -(self.K_IB @ delta[self.bound])
            delta[self.free] = np.column_stack([self._solve(rhs[:, j]) for j in range(2)])
        return delta

    def pull_back(self, g: np.ndarray) -> list[np.ndarray]:
        """The transpose of ``displacement``: for g = dJ/dX (n, 2) at fixed vertex moves, dJ/d(vertex
        moves), one (m_i, 2) array per polygon. One solve with K_II per axis, whatever the number of
        design variables (K_II is symmetric)."""
        g = np.asarray(g, dtype=float)
        g_bound = g[self.bound].copy()
        if self._solve is not None:
            y = np.column_stack([self._solve(np.ascontiguousarray(g[self.free, j])) for j in range(2)])
            g_bound -= self.K_IB.T @ y
        flat = self._vertex_map().T @ g_bound
        ends = np.cumsum([len(p) for p in self.polys0])[:-1]
        return np.split(flat, ends)

    def apply(self, x: np.ndarray) -> None:
        """Put the node coordinates x into the mesh and forget what was computed from the old ones."""
        self.mesh.geometry.x[:, :2] = x
        keep.forget(self.mesh, "cell_tree", "facets")
