"""How a material point's displacement follows the mesh nodes (2D triangles or 3D tetrahedra, affine, serial).

A point Y sits in cell c at reference coordinates xi, with the cell's
geometry X(xi) = sum_a M_a(xi) X_a (P1 nodes X_a) and a field
v(Y) = sum_b N_b(xi) v_b (the displacement's Lagrange basis). Moving the
nodes by dX_a and the point by dY changes xi by
dxi = (dX/dxi)^-1 (dY - Xbar), Xbar = sum_a M_a(xi) dX_a, so

    d v(Y) = grad v(Y) (dY - Xbar),     grad v = (dv/dxi)(dX/dxi)^-1,

and the point's current position y = Y + u(Y) moves by
dy = (I + grad u) dY - grad u Xbar. For a point on an edge, dY - Xbar is
along the edge and grad v's tangential part is the same in both cells, so
either cell gives the same answer. A scalar f that depends on points and
nodes through coefficient vectors a_k (of dY_k) and b_k (of Xbar_k) pulls
back to the nodes with ``nodes``: g_a = sum_k M_a(xi_k) b_k.
"""
from __future__ import annotations

import functools

import basix
import numpy as np

from ..mesh.points import locate_cells


@functools.lru_cache(maxsize=None)
def _simplex_element(dim: int, degree: int):
    cell = basix.CellType.triangle if dim == 2 else basix.CellType.tetrahedron
    return basix.create_element(basix.ElementFamily.P, cell, degree, basix.LagrangeVariant.equispaced)


class MaterialPoints:
    """Cells, reference coordinates and basis gradients of points Y in a mesh of affine simplices (2D, 3D)."""

    def __init__(self, V, Y: np.ndarray):
        mesh = V.mesh
        if mesh.comm.size > 1:
            raise ValueError("design gradients run on one MPI process")
        d = self.dim = mesh.geometry.dim
        self.Y = np.asarray(Y, dtype=float).reshape(-1, d)
        self.bs = V.dofmap.index_map_bs
        self.n_nodes = len(mesh.geometry.x)
        cells = locate_cells(mesh, self.Y)
        if np.any(cells < 0):
            raise ValueError("a material point lies outside the mesh")
        x = mesh.geometry.x[:, :d]
        self.nodes = mesh.geometry.dofmap.array.reshape(-1, d + 1)[cells]        # (K, d + 1) geometry nodes
        x0 = x[self.nodes[:, 0]]
        jac = np.stack([x[self.nodes[:, k]] - x0 for k in range(1, d + 1)], axis=2)   # (K, d, d) dX/dxi
        self.jinv = np.linalg.inv(jac) if len(jac) else jac
        xi = np.einsum("kij,kj->ki", self.jinv, self.Y - x0)
        self.M = np.column_stack([1.0 - xi.sum(axis=1), xi])                    # P1 geometry basis (K, d + 1)
        element = _simplex_element(d, V.ufl_element().degree())
        tab = element.tabulate(1, xi)                                           # (d + 1, K, nd, 1)
        self.N = tab[0, :, :, 0]
        dN = np.stack([tab[k, :, :, 0] for k in range(1, d + 1)], axis=2)       # (K, nd, d) d/dxi
        self.dN = np.einsum("kbj,kji->kbi", dN, self.jinv)                      # (K, nd, d) d/dX
        self.dofs = V.dofmap.list.array.reshape(-1, self.N.shape[1])[cells]     # (K, nd) nodes of V

    def values(self, v: np.ndarray) -> np.ndarray:
        """v(Y_k), (K, d), from a local DOF array."""
        vb = v.reshape(-1, self.bs)[self.dofs][:, :, :self.dim]                  # (K, nd, d)
        return np.einsum("kb,kbi->ki", self.N, vb)

    def gradients(self, v: np.ndarray) -> np.ndarray:
        """grad v(Y_k) in the reference configuration, (K, d, d): [i, j] = d v_i / d X_j."""
        vb = v.reshape(-1, self.bs)[self.dofs][:, :, :self.dim]
        return np.einsum("kbi,kbj->kij", vb, self.dN)

    def nodes_of(self, b: np.ndarray) -> np.ndarray:
        """sum_k M_a(xi_k) b_k at every geometry node a: the pull-back of coefficients of Xbar_k, (n, d)."""
        d = self.dim
        out = np.zeros((self.n_nodes, d))
        np.add.at(out, self.nodes.ravel(), (self.M[:, :, None] * np.asarray(b)[:, None, :]).reshape(-1, d))
        return out
