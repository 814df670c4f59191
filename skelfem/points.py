"""Material points: locate them in the mesh and evaluate the displacement there.

A material point X sits in cell c at reference coordinates xi; its displacement
is u(X) = sum_i phi_i(xi) u_i over the cell's DOFs. Stacking the rows of many
points gives a sparse interpolation matrix S with u(X_p) = (S u)_p, the one
operator that cables, point loads and markers share.
"""
from __future__ import annotations

import basix
import numpy as np
import scipy.sparse as sp
from dolfinx import geometry

_BASIX_CELL = {"triangle": basix.CellType.triangle, "tetrahedron": basix.CellType.tetrahedron}


def locate_cells(mesh, points: np.ndarray) -> np.ndarray:
    """Cell index (local) containing each point, -1 where none does."""
    points = np.asarray(points, dtype=float).reshape(-1, mesh.geometry.dim)
    if len(points) == 0:
        return np.zeros(0, dtype=np.int32)
    p3 = np.zeros((len(points), 3))
    p3[:, :points.shape[1]] = points
    tree = geometry.BoundingBoxTree(mesh, mesh.topology.dim)
    candidates = geometry.compute_collisions(tree, p3)
    colliding = geometry.compute_colliding_cells(mesh, candidates, p3)
    cells = np.full(len(points), -1, dtype=np.int32)
    for i in range(len(points)):  # one entry per point (not per DOF or cell)
        links = colliding.links(i)
        if len(links):
            cells[i] = links[0]
    return cells


def reference_coordinates(mesh, points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Pull points back to reference coordinates of affine simplex cells."""
    gdim = mesh.geometry.dim
    x = mesh.geometry.x[:, :gdim]
    nodes = mesh.geometry.dofmap.array.reshape(-1, gdim + 1)[cells]
    v0 = x[nodes[:, 0]]
    Jac = np.stack([x[nodes[:, j + 1]] - v0 for j in range(gdim)], axis=2)  # (n, gdim, tdim)
    xi = np.linalg.solve(Jac, (points - v0)[..., None])[..., 0]
    return np.clip(xi, 0.0, 1.0)


def interpolation_matrix(V, points: np.ndarray, cells: np.ndarray | None = None) -> sp.csr_matrix:
    """Sparse S of shape (n_points*bs, n_local_dofs*bs) with (S u)[p*bs + c] = u_c(X_p)."""
    mesh = V.mesh
    bs = V.dofmap.index_map_bs
    points = np.asarray(points, dtype=float).reshape(-1, mesh.geometry.dim)
    if cells is None:
        cells = locate_cells(mesh, points)
    if np.any(cells < 0):
        raise ValueError("point outside the mesh")
    n_local = (V.dofmap.index_map.size_local + V.dofmap.index_map.num_ghosts) * bs
    if len(points) == 0:
        return sp.csr_matrix((0, n_local))
    element = basix.create_element(
        basix.ElementFamily.P, _BASIX_CELL[mesh.topology.cell_type.name],
        V.ufl_element().degree(), basix.LagrangeVariant.equispaced)
    xi = reference_coordinates(mesh, points, cells)
    phi = element.tabulate(0, xi)[0, :, :, 0]                    # (n_points, n_cell_dofs)
    cell_dofs = V.dofmap.list.array.reshape(-1, phi.shape[1])[cells]  # (n_points, n_cell_dofs)
    rows = (np.arange(len(points))[:, None, None] * bs + np.arange(bs)[None, None, :])
    cols = cell_dofs[:, :, None] * bs + np.arange(bs)[None, None, :]
    rows = np.broadcast_to(rows, cols.shape)
    phi = np.where(np.abs(phi) < 1e-14, 0.0, phi)   # exact zeros on edges/faces
    vals = np.broadcast_to(phi[:, :, None], cols.shape)
    S = sp.csr_matrix((vals.ravel(), (rows.ravel(), cols.ravel())), shape=(len(points) * bs, n_local))
    S.eliminate_zeros()
    return S
