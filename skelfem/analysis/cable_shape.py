"""How a cable's energy, residual and tension change with the mesh nodes and its sketch (2D and 3D, no friction).

A cable (skelfem.terms.cables) runs through via points x_j = sum_k A_jk (Y_k + u(Y_k)):
A picks a sketch vertex or a cut, or spreads an anchored end over its disk's
lattice points with fixed weights. Each point Y_k depends on the geometry
psi = (mesh nodes X, sketch vertices Q, anchor radius r):

* a sketch vertex: Y = Q_m;
* a cut of sketch segment (Q0, Q1) with mesh edge (A, B): Y = A + s (B - A) = Q0 + r (Q1 - Q0),
  differentiated through the 2 x 2 system that gives (s, r); in 3D with a mesh facet (A, B, C):
  Y = A + s (B - A) + t (C - A) = Q0 + r (Q1 - Q0), through the 3 x 3 system M [r, s, t] = A - Q0,
  M = [q, A - B, A - C]: with m the first row of M^-1 and P = q m^T,
  dY = (I - P)((1 - r) dQ0 + r dQ1) + P ((1 - s - t) dA + s dB + t dC);
* a point cutting a cell into pieces (P2): Y = (1 - f) Y_a + f Y_b between its cuts;
* an anchor's lattice point: Y = Q_m + rho (r / r0), rho its offset at radius r0; the default radius
  is 1 % of the mesh's bounding-box diagonal (its derivative moves the extreme nodes; where several
  nodes tie for an extreme, their mean move).

With the material-point rule of :mod:`.shape_points` (dx_j = sum_k A_jk (F_k dY_k - G_k Xbar_k)) the
length l = sum |x_{j+1} - x_j|, the rest length L0 = sum |X_{j+1} - X_j| (X = A Y) and every scalar
made of them pull back to the nodes and the sketch exactly. The discrete choices (which edges the
sketch cuts, the lattice's points and weights) are held: exact while the moved mesh has the same
cuts, which is what the morph's same-topology moves keep for small steps. Cable friction
(skelfem.terms.cable_slip) is not covered.
"""
from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp

from ..mesh.points import owner_ranks
from ..terms.cable_route import (PIECES, anchor_samples, anchor_weights, lattice_density, via_points)
from .shape_points import MaterialPoints


PARALLEL = 1e-6     # |sin| between a sketch segment and a mesh edge below which the sketch runs along it


def radius_gradient(x: np.ndarray) -> np.ndarray:
    """d r / dX (n, 2) of r = 1 % of the bounding-box diagonal of the nodes x (ties: their mean)."""
    lo, hi = x.min(axis=0), x.max(axis=0)
    diag = hi - lo
    out = np.zeros_like(x)
    tol = 1e-12 * (1.0 + float(np.abs(x).max()))
    for c in range(x.shape[1]):
        top, bottom = np.abs(x[:, c] - hi[c]) <= tol, np.abs(x[:, c] - lo[c]) <= tol
        share = 0.01 * diag[c] / np.linalg.norm(diag)
        out[top, c] += share / top.sum()
        out[bottom, c] -= share / bottom.sum()
    return out


def mesh_edges(mesh) -> tuple[np.ndarray, np.ndarray]:
    """(geometry nodes (n_facets, d), their coordinates (n_facets, d, d)) of every mesh facet: the edges of a
    2D mesh, the triangles of a 3D one."""
    from dolfinx.cpp.mesh import entities_to_geometry
    d = mesh.geometry.dim
    mesh.topology.create_connectivity(d - 1, 0)
    imap = mesh.topology.index_map(d - 1)
    n = imap.size_local + imap.num_ghosts
    nodes = entities_to_geometry(mesh._mesh, d - 1, np.arange(n, dtype=np.int32), False)
    return nodes, mesh.geometry.x[nodes][:, :, :d]


def _segment_distance(y: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    e = b - a
    t = np.clip(np.einsum("ni,ni->n", y - a, e) / np.maximum(np.einsum("ni,ni->n", e, e), 1e-300), 0.0, 1.0)
    return np.linalg.norm(a + t[:, None] * e - y, axis=1)


def _on_triangles(y: np.ndarray, tri: np.ndarray, tol: float) -> np.ndarray:
    """Whether y (3,) lies on each triangle (k, 3, 3), within tol."""
    a, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    n = np.cross(e1, e2)
    area2 = np.linalg.norm(n, axis=1)
    w = y - a
    off = np.abs(np.einsum("ij,ij->i", w, n)) / np.maximum(area2, 1e-300)
    s = np.einsum("ij,ij->i", np.cross(w, e2), n) / np.maximum(area2 ** 2, 1e-300)
    t = np.einsum("ij,ij->i", np.cross(e1, w), n) / np.maximum(area2 ** 2, 1e-300)
    eps = tol / np.maximum(np.sqrt(area2), 1e-300)
    return (off <= tol) & (s >= -eps) & (t >= -eps) & (s + t <= 1 + eps)


class CableShape:
    """A frictionless cable's geometric derivatives at the model's present mesh (serial, 2D or 3D)."""

    def __init__(self, model, term, edges=None):
        if term.cable.friction:
            raise ValueError(f"cables.{term.name}.friction: design gradients do not cover cable friction")
        self.term, self.cable = term, term.cable
        mesh, V = model.mesh, model.V
        spec = model.design.cable(term.name)
        self.path = np.asarray(spec.path, dtype=float)
        d = self.dim = mesh.geometry.dim
        x = mesh.geometry.x[:, :d]
        self.n_nodes, nq = len(x), len(self.path)
        self.q0, self.r_col = d * self.n_nodes, d * self.n_nodes + d * nq
        n_cols = self.r_col + 1
        Xv = via_points(mesh, self.path, PIECES.get(V.ufl_element().degree(), 4))
        edges = edges if edges is not None else mesh_edges(mesh)
        rows = self._provenance(mesh, Xv, edges)                    # dY of each via point: {col: d x d}
        Y, dY, A_entries, n = self._anchored(mesh, Xv, rows, term.anchors, spec.anchor_radius is None)
        self.A = sp.csr_matrix(A_entries, shape=(n, len(Y)))
        self.DY = self._matrix(dY, n_cols, d)
        if not np.allclose(self.A @ Y, self.cable.X, rtol=0.0, atol=1e-9 * (1.0 + float(np.abs(Y).max()))):
            raise ValueError(f"cables.{term.name}: its via points could not be traced back to the sketch")
        self.points = MaterialPoints(V, Y)
        self.dr_dX = radius_gradient(x)

    # -- where each point comes from --------------------------------------------------------------------
    def _provenance(self, mesh, Xv: np.ndarray, edges) -> list[dict]:
        """{column: d x d block} of dY_j / dpsi for every via point of the sketch."""
        if self.dim == 3:
            return self._provenance_3d(Xv, edges)
        path, q0 = self.path, self.q0
        tol = 1e-9 * (1.0 + float(np.abs(Xv).max()))
        edge_nodes, edge_x = edges
        lo, hi = edge_x.min(axis=1) - tol, edge_x.max(axis=1) + tol
        rows: list = [None] * len(Xv)
        vertex = np.array([int(np.argmin(np.linalg.norm(path - y, axis=1))) for y in Xv])
        is_vertex = np.linalg.norm(path[vertex] - Xv, axis=1) <= tol
        segment, pending = 0, []
        eye = np.eye(2)
        near_segment = []                                 # the edges whose boxes meet each sketch segment's
        for Q0, Q1 in zip(path[:-1], path[1:]):
            near_segment.append(np.flatnonzero(np.all((lo <= np.maximum(Q0, Q1)) & (hi >= np.minimum(Q0, Q1)),
                                                      axis=1)))
        for j, y in enumerate(Xv):
            if is_vertex[j]:
                segment = min(int(vertex[j]), len(path) - 2)
                rows[j] = {q0 + 2 * int(vertex[j]): eye}
                continue
            near = near_segment[segment]
            near = near[np.all((lo[near] <= y) & (hi[near] >= y), axis=1)]
            on = near[_segment_distance(np.broadcast_to(y, (len(near), 2)), edge_x[near, 0], edge_x[near, 1]) <= tol]
            if not len(on):
                pending.append((j, segment))             # a piece point inside a cell (P2)
                continue
            Q0, Q1 = path[segment], path[segment + 1]
            q = Q1 - Q0
            e_all = edge_x[on, 1] - edge_x[on, 0]
            sines = np.abs(q[0] * e_all[:, 1] - q[1] * e_all[:, 0]) / np.linalg.norm(e_all, axis=1)
            best = on[int(np.argmax(sines))]      # at a mesh node several edges meet it: the most transverse
            (ia, ib), (a, b) = edge_nodes[best], edge_x[best]
            e = b - a
            det = -e[0] * q[1] + q[0] * e[1]                  # of M = [e, -q]
            if abs(det) <= PARALLEL * math.hypot(*e) * math.hypot(*q):
                # the sketch runs along this edge (a cut of two nearly parallel lines, placed by round-off):
                # the point moves with the edge; along a straight deformed edge its place changes no length
                s = float(np.clip(np.dot(y - a, e) / np.dot(e, e), 0.0, 1.0))
                rows[j] = {2 * int(ia): (1 - s) * eye, 2 * int(ib): s * eye}
                continue
            m2 = np.array([-e[1], e[0]]) / det               # the second row of M^-1 (2 x 2, explicit)
            rhs = Q0 - a
            s, r = (-q[1] * rhs[0] + q[0] * rhs[1]) / det, float(m2 @ rhs)
            P = np.outer(q, m2)
            rows[j] = {q0 + 2 * segment: (1 - r) * (eye + P), q0 + 2 * (segment + 1): r * (eye + P),
                       2 * int(ia): -(1 - s) * P, 2 * int(ib): -s * P}
        for j, _ in pending:                              # between the nearest traced points on each side
            ja = max(k for k in range(j) if rows[k] is not None and k not in dict(pending))
            jb = min(k for k in range(j + 1, len(Xv)) if rows[k] is not None and k not in dict(pending))
            f = np.linalg.norm(Xv[j] - Xv[ja]) / np.linalg.norm(Xv[jb] - Xv[ja])
            rows[j] = {}
            for k, w in ((ja, 1 - f), (jb, f)):
                for col, C in rows[k].items():
                    rows[j][col] = rows[j].get(col, 0.0) + w * C
        return rows

    def _provenance_3d(self, Xv: np.ndarray, facets) -> list[dict]:
        """{column: 3 x 3 block} of dY_j / dpsi for every via point of a 3D sketch: a vertex, or a cut with a
        facet (the most transverse of those that hold it); P1 (no points inside cells)."""
        path, q0 = self.path, self.q0
        tol = 1e-9 * (1.0 + float(np.abs(Xv).max()))
        facet_nodes, facet_x = facets
        lo, hi = facet_x.min(axis=1) - tol, facet_x.max(axis=1) + tol
        vertex = np.array([int(np.argmin(np.linalg.norm(path - y, axis=1))) for y in Xv])
        is_vertex = np.linalg.norm(path[vertex] - Xv, axis=1) <= tol
        eye, segment, rows = np.eye(3), 0, []
        for j, y in enumerate(Xv):
            if is_vertex[j]:
                segment = min(int(vertex[j]), len(path) - 2)
                rows.append({q0 + 3 * int(vertex[j]): eye})
                continue
            near = np.flatnonzero(np.all((lo <= y) & (hi >= y), axis=1))
            on = near[_on_triangles(y, facet_x[near], tol)]
            if not len(on):
                raise ValueError(f"cables.{self.term.name}: a via point at {y} lies on no facet (3D design gradients "
                                 "cover P1 meshes)")
            Q0, Q1 = path[segment], path[segment + 1]
            q = Q1 - Q0
            tri = facet_x[on]
            n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            k = int(np.argmax(np.abs(n @ q) / np.linalg.norm(n, axis=1)))
            (ia, ib, ic), (a, b, c) = facet_nodes[on[k]], tri[k]
            M = np.column_stack([q, a - b, a - c])
            if abs(np.linalg.det(M)) <= PARALLEL * np.linalg.norm(q) * np.linalg.norm(n[k]):
                raise ValueError(f"cables.{self.term.name}: its sketch runs in a mesh facet at {y}")
            Minv = np.linalg.inv(M)
            r, s_, t_ = Minv @ (a - Q0)
            P = np.outer(q, Minv[0])
            rows.append({q0 + 3 * segment: (1 - r) * (eye - P), q0 + 3 * (segment + 1): r * (eye - P),
                         3 * int(ia): (1 - s_ - t_) * P, 3 * int(ib): s_ * P, 3 * int(ic): t_ * P})
        return rows

    def _anchored(self, mesh, Xv, rows, anchors: dict, default_radius: bool):
        """(points Y, their dY rows, the entries of A, its rows) as skelfem.terms.cable_route.anchored_interpolation
        makes them: anchored via points spread over their disks' lattice points."""
        path = self.path
        at = {}
        for k, r in anchors.items():
            i = 0 if k == 0 else len(Xv) - 1 if k in (-1, len(path) - 1) else \
                int(np.argmin(np.linalg.norm(Xv - path[k], axis=1)))
            if r > 0.0:
                at[i] = r
        keep = np.ones(len(Xv), dtype=bool)
        for i, r in at.items():
            keep &= np.linalg.norm(Xv - Xv[i], axis=1) >= r
        keep[list(at)] = True
        kept = np.flatnonzero(keep)
        n = len(kept)
        Y, dY = [Xv[kept]], [rows[j] for j in kept]
        self.lattice = []                                 # (lattice points, the sketch vertex they follow)
        a_rows, a_cols, a_vals = [], [], []
        offset = n
        for new, old in enumerate(kept):
            if old not in at:
                a_rows.append(new), a_cols.append(new), a_vals.append(1.0)
        for new, old in enumerate(kept):
            if old not in at:
                continue
            r, centre = at[old], Xv[old]
            samples = anchor_samples(centre, r, lattice_density(mesh, centre, r))
            w = anchor_weights(samples, centre, r)
            samples, w = samples[w > 0.0], w[w > 0.0]
            inside = owner_ranks(mesh, samples)[0] < mesh.comm.size
            samples, w = samples[inside], w[inside] / w[inside].sum()
            for y, wk in zip(samples, w):
                row = dict(rows[old])
                if default_radius:                    # the lattice scales with the radius
                    row[self.r_col] = ((y - centre) / r)[:, None]
                dY.append(row)
                a_rows.append(new), a_cols.append(offset), a_vals.append(wk)
                offset += 1
            Y.append(samples)
            self.lattice.append((samples, int(np.argmin(np.linalg.norm(path - centre, axis=1)))))
        return np.vstack(Y), dY, (np.array(a_vals), (np.array(a_rows), np.array(a_cols))), n

    @staticmethod
    def _matrix(dY: list[dict], n_cols: int, d: int = 2) -> sp.csr_matrix:
        """The rows of dY (d per point) as one sparse matrix over psi."""
        r, c, v = [], [], []
        for k, row in enumerate(dY):
            for col, C in row.items():
                C = np.asarray(C, dtype=float).reshape(d, -1)
                m = C.shape[1]
                for i in range(d):
                    r += [d * k + i] * m
                c += list(range(col, col + m)) * d
                v += C.ravel().tolist()
        return sp.csr_matrix((v, (r, c)), shape=(d * len(dY), n_cols))

    # -- pulling scalars back -------------------------------------------------------------------------
    def positions(self, u: np.ndarray) -> np.ndarray:
        """The via points now, A (Y + u(Y)) (the cable's own positions, computed from the traced points)."""
        return self.A @ (self.points.Y + self.points.values(u))

    def _pull(self, u, pi, rho, sigma=None, z=None) -> tuple[np.ndarray, np.ndarray]:
        """(d/dX (n, 2), d/dQ (m, 2)) of f with df = sum_j pi_j.dx_j + rho_j.dX_j + sigma_j.dzeta_j
        (x the via points now, X at rest, zeta the field z at them)."""
        pts, A = self.points, self.A
        G = pts.gradients(u)
        Api, Arho = A.T @ pi, A.T @ rho
        a = Api + np.einsum("kji,kj->ki", G, Api) + Arho
        b = -np.einsum("kji,kj->ki", G, Api)
        if sigma is not None:
            Z, As = pts.gradients(z), A.T @ sigma
            zs = np.einsum("kji,kj->ki", Z, As)
            a, b = a + zs, b - zs
        g = self.DY.T @ a.ravel()
        gX = g[:self.q0].reshape(-1, self.dim) + pts.nodes_of(b) + g[self.r_col] * self.dr_dX
        return gX, g[self.q0:self.r_col].reshape(-1, self.dim)

    def _state(self, u):
        x, X = self.positions(u), self.A @ self.points.Y
        d, d0 = np.diff(x, axis=0), np.diff(X, axis=0)
        norm, norm0 = np.linalg.norm(d, axis=1), np.linalg.norm(d0, axis=1)
        t, t0 = d / norm[:, None], d0 / norm0[:, None]
        s = float(norm.sum() - self.term.rest_length)
        return d, norm, t, _ends(t), _ends(t0), s

    def energy_gradient(self, u) -> tuple[np.ndarray, np.ndarray]:
        """d/dX and d/dQ of the cable's energy k Q(l - L) at fixed u."""
        _, _, _, tau, tau0, s = self._state(u)
        k = self.cable.k * max(s, 0.0)
        return self._pull(u, k * tau, -k * tau0)

    def tension_gradient(self, u) -> tuple[np.ndarray, np.ndarray]:
        """d/dX and d/dQ of the tension k max(l - L, 0) at fixed u (zero while slack)."""
        _, _, _, tau, tau0, s = self._state(u)
        k = self.cable.k if s > 0.0 else 0.0
        return self._pull(u, k * tau, -k * tau0)

    def adjoint_gradient(self, u, z) -> tuple[np.ndarray, np.ndarray]:
        """d/dX and d/dQ of z^T R_cable(u) = k s (grad l . z) at fixed u and z (local DOF arrays)."""
        _, norm, t, tau, tau0, s = self._state(u)
        if s <= 0.0:
            return np.zeros((self.n_nodes, self.dim)), np.zeros((len(self.path), self.dim))
        k = self.cable.k
        dz = np.diff(self.A @ self.points.values(z), axis=0)
        lam = float(np.sum(t * dz))
        w = (dz - t * np.sum(t * dz, axis=1)[:, None]) / norm[:, None]
        return self._pull(u, k * lam * tau + k * s * _ends(w), -k * lam * tau0, k * s * tau, z)


def _ends(t: np.ndarray) -> np.ndarray:
    """tau_j = t_{j-1} - t_j over the via points (t_{-1} = t_n = 0): sum_i t_i.(dx_{i+1} - dx_i) = sum_j tau_j.dx_j."""
    zero = np.zeros((1, t.shape[1]))
    return np.vstack([zero, t]) - np.vstack([t, zero])
