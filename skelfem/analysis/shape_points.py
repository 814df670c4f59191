"""How a material point's displacement follows the mesh nodes (2D, affine cells, serial).

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
def _triangle_element(degree: int):
    return basix.create_element(basix.ElementFamily.P, basix.CellType.triangle, degree,
                                basix.LagrangeVariant.equispaced)


class MaterialPoints:
    """Cells, reference coordinates and basis gradients of points Y in a 2D mesh of affine triangles."""

    def __init__(self, V, Y: np.ndarray):
        mesh = V.mesh
        if mesh.comm.size > 1 or mesh.geometry.dim != 2:
            raise ValueError("design gradients run in 2D on one MPI process")
        self.Y = np.asarray(Y, dtype=float).reshape(-1, 2)
        self.bs = V.dofmap.index_map_bs
        self.n_nodes = len(mesh.geometry.x)
        cells = locate_cells(mesh, self.Y)
        if np.any(cells < 0):
            raise ValueError("a material point lies outside the mesh")
        x = mesh.geometry.x[:, :2]
        self.nodes = mesh.geometry.dofmap.array.reshape(-1, 3)[cells]            # (K, 3) geometry nodes
        x0 = x[self.nodes[:, 0]]
        jac = np.stack([x[self.nodes[:, 1]] - x0, x[self.nodes[:, 2]] - x0], axis=2)   # (K, 2, 2) dX/dxi
        det = jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]
        self.jinv = np.stack([np.stack([jac[:, 1, 1], -jac[:, 0, 1]], axis=1),
                              np.stack([-jac[:, 1, 0], jac[:, 0, 0]], axis=1)], axis=1) / det[:, None, None]
        xi = np.einsum("kij,kj->ki", self.jinv, self.Y - x0)
        self.M = np.column_stack([1.0 - xi.sum(axis=1), xi])                    # P1 geometry basis (K, 3)
        element = _triangle_element(V.ufl_element().degree())
        tab = element.tabulate(1, xi)                                           # (3, K, nd, 1)
        self.N = tab[0, :, :, 0]
        dN = np.stack([tab[1, :, :, 0], tab[2, :, :, 0]], axis=2)               # (K, nd, 2) d/dxi
        self.dN = np.einsum("kbj,kji->kbi", dN, self.jinv)                      # (K, nd, 2) d/dX
        self.dofs = V.dofmap.list.array.reshape(-1, self.N.shape[1])[cells]     # (K, nd) nodes of V

    def values(self, v: np.ndarray) -> np.ndarray:
        """v(Y_k), (K, 2), from a local DOF array."""
        vb = v.reshape(-1, self.bs)[self.dofs][:, :, :2]                         # (K, nd, 2)
        return np.einsum("kb,kbi->ki", self.N, vb)

    def gradients(self, v: np.ndarray) -> np.ndarray:
        """grad v(Y_k) in the reference configuration, (K, 2, 2): [i, j] = d v_i / d X_j."""
        vb = v.reshape(-1, self.bs)[self.dofs][:, :, :2]
        return np.einsum("kbi,kbj->kij", vb, self.dN)

    def nodes_of(self, b: np.ndarray) -> np.ndarray:
        """sum_k M_a(xi_k) b_k at every geometry node a: the pull-back of coefficients of Xbar_k, (n, 2)."""
        out = np.zeros((self.n_nodes, 2))
        np.add.at(out, self.nodes.ravel(), (self.M[:, :, None] * np.asarray(b)[:, None, :]).reshape(-1, 2))
        return out
