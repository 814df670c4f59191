"""Material points: locate them in the mesh and evaluate the displacement there.

A material point X sits in cell c at reference coordinates xi; its displacement
is u(X) = sum_i phi_i(xi) u_i over the cell's DOFs. Stacking the rows of many
points gives a sparse interpolation matrix S with u(X_p) = (S u)_p, the one
operator that cables, point loads and markers share.
"""
from __future__ import annotations

import functools
import math

import basix
import numpy as np
import scipy.sparse as sp
from dolfinx import geometry
from mpi4py import MPI

from . import keep

_BASIX_CELL = {"triangle": basix.CellType.triangle, "tetrahedron": basix.CellType.tetrahedron}


def _cell_tree(mesh) -> geometry.BoundingBoxTree:
    """The mesh's bounding box tree of cells, built once per mesh."""
    return keep.kept(mesh, "cell_tree", lambda: geometry.BoundingBoxTree(mesh, mesh.topology.dim))


TREE_CELLS = 200_000     # a mesh with more cells (on this rank) drops its cell tree once a model is built on it


def release_cell_tree(mesh) -> None:
    """Forget the cell tree of a big mesh (more than TREE_CELLS cells on this rank; 30 MB, 0.25 KB per DOF,
    on arm3d at 118k DOFs): the model's points are all located by the time it is built, and a later
    search makes the tree again. A small mesh keeps it for the next edit."""
    if mesh.topology.index_map(mesh.topology.dim).size_local > TREE_CELLS:
        keep.forget(mesh, "cell_tree")


def locate_cells(mesh, points: np.ndarray, below: int | None = None) -> np.ndarray:
    """Cell index (local) containing each point, -1 where none does.

    With `below`, only cells with index < below count (e.g. the owned ones).
    """
    points = np.asarray(points, dtype=float).reshape(-1, mesh.geometry.dim)
    if len(points) == 0:
        return np.zeros(0, dtype=np.int32)
    p3 = np.zeros((len(points), 3))
    p3[:, :points.shape[1]] = points
    candidates = geometry.compute_collisions(_cell_tree(mesh), p3)
    colliding = geometry.compute_colliding_cells(mesh, candidates, p3)
    links, offsets = colliding.array, colliding.offsets
    at = np.flatnonzero(links < below) if below is not None else np.arange(len(links))
    point = np.searchsorted(offsets, at, side="right") - 1      # the point each link belongs to
    point, first = np.unique(point, return_index=True)          # its first (admissible) cell
    cells = np.full(len(points), -1, dtype=np.int32)
    cells[point] = links[at[first]]
    return cells


@functools.lru_cache(maxsize=None)
def _lagrange(cell: str, degree: int):
    return basix.create_element(basix.ElementFamily.P, _BASIX_CELL[cell], degree,
                                basix.LagrangeVariant.gll_warped)     # DOLFINx's "Lagrange" (equispaced to P2)


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
    bs = V.dofmap.index_map_bs
    n_local = (V.dofmap.index_map.size_local + V.dofmap.index_map.num_ghosts) * bs
    rows, cols, vals = interpolation_entries(V, points, cells)
    n = len(np.asarray(points, dtype=float).reshape(-1, V.mesh.geometry.dim))
    return sp.csr_matrix((vals, (rows, cols)), shape=(n * bs, n_local))


def interpolation_entries(V, points: np.ndarray, cells: np.ndarray | None = None) -> tuple:
    """The nonzero entries (rows, local DOF columns, values) of interpolation_matrix."""
    mesh = V.mesh
    bs = V.dofmap.index_map_bs
    points = np.asarray(points, dtype=float).reshape(-1, mesh.geometry.dim)
    if cells is None:
        cells = locate_cells(mesh, points)
    if np.any(cells < 0):
        raise ValueError("point outside the mesh")
    if len(points) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    element = _lagrange(mesh.topology.cell_type.name, V.ufl_element().degree())
    xi = reference_coordinates(mesh, points, cells)
    phi = element.tabulate(0, xi)[0, :, :, 0]                    # (n_points, n_cell_dofs)
    cell_dofs = V.dofmap.list.array.reshape(-1, phi.shape[1])[cells]  # (n_points, n_cell_dofs)
    point, k = np.nonzero(np.abs(phi) >= 1e-10)                  # exact zeros on edges/faces (and at vertices)
    c = np.arange(bs)
    rows = ((point * bs)[:, None] + c).ravel()
    cols = ((cell_dofs[point, k].astype(np.int64) * bs)[:, None] + c).ravel()
    return rows, cols, np.repeat(phi[point, k], bs)


# -- material points under MPI ------------------------------------------------------------------
def global_dof_numbers(V) -> np.ndarray:
    """Global (unrolled) DOF number of every local DOF, owned and ghost (computed once per space)."""
    def make() -> np.ndarray:
        out = _global_dof_numbers(V)
        out.flags.writeable = False
        return out
    return keep.kept(V, "global_dofs", make)


def _global_dof_numbers(V) -> np.ndarray:
    bs = V.dofmap.index_map_bs
    imap = V.dofmap.index_map
    nodes = imap.local_to_global(np.arange(imap.size_local + imap.num_ghosts, dtype=np.int32))
    return (nodes[:, None] * bs + np.arange(bs)).ravel().astype(np.int64)


class DofGather:
    """The values of a few global DOFs, known on every rank.

    A cable or a marker touches DOFs that may be owned by several ranks. Each
    rank copies the ones it owns into a short vector and one Allreduce sums
    them, so every rank sees u restricted to `dofs` (global, sorted). In serial
    this is plain indexing. Gradients go back with `scatter_add`, into owned
    entries only, so nothing is counted twice.
    """

    def __init__(self, V, dofs: np.ndarray):
        self.comm = V.mesh.comm
        bs = V.dofmap.index_map_bs
        imap = V.dofmap.index_map
        lo, n = imap.local_range[0] * bs, imap.size_local * bs
        self.dofs = np.asarray(dofs, dtype=np.int64)
        owned = (self.dofs >= lo) & (self.dofs < lo + n)
        self.pos = np.flatnonzero(owned)                       # where in dofs this rank owns
        self.local = (self.dofs[owned] - lo).astype(np.int32)  # their local indices
        self.serial = self.comm.size == 1

    def __len__(self) -> int:
        return len(self.dofs)

    def __call__(self, u_local: np.ndarray) -> np.ndarray:
        if self.serial:
            return u_local[self.local]
        uc = np.zeros(len(self.dofs))
        uc[self.pos] = u_local[self.local]
        self.comm.Allreduce(MPI.IN_PLACE, uc, op=MPI.SUM)
        return uc

    def scatter_add(self, values: np.ndarray, g_local: np.ndarray) -> None:
        """g_local[owned] += values (values given on all of `dofs`)."""
        g_local[self.local] += values[self.pos]

    @property
    def owned_dofs(self) -> np.ndarray:
        """Global numbers of the DOFs this rank owns (its rows of a matrix)."""
        return self.dofs[self.pos]


def owner_ranks(mesh, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(owner rank of each point, its local cell on this rank or -1).

    A point belongs to the lowest rank that owns a cell containing it;
    the owner is comm.size where no rank does.
    """
    comm = mesh.comm
    n_owned = mesh.topology.index_map(mesh.topology.dim).size_local
    cells = locate_cells(mesh, points, below=n_owned)            # ghost cells belong to others
    owner = np.where(cells >= 0, comm.rank, comm.size).astype(np.int32)
    if comm.size > 1:
        comm.Allreduce(MPI.IN_PLACE, owner, op=MPI.MIN)
    return owner, np.where(owner == comm.rank, cells, -1)


def global_interpolation(V, points: np.ndarray):
    """S (n_points*bs x len(dofs)) and the sorted global DOFs it touches, identical on every rank.

    Returns (S, DofGather, owner); points with owner == comm.size lie outside the mesh.
    """
    comm = V.mesh.comm
    bs = V.dofmap.index_map_bs
    points = np.asarray(points, dtype=float).reshape(-1, V.mesh.geometry.dim)
    owner, cells = owner_ranks(V.mesh, points)
    mine = np.flatnonzero(owner == comm.rank)
    rows, cols, vals = interpolation_entries(V, points[mine], cells[mine])
    rows = mine[rows // bs] * bs + rows % bs
    cols = global_dof_numbers(V)[cols]
    if comm.size > 1:
        rows, cols, vals = (np.concatenate(comm.allgather(a)) for a in (rows, cols, vals))
    dofs, cols = np.unique(cols, return_inverse=True)
    S = sp.csr_matrix((vals, (rows, cols)), shape=(len(points) * bs, len(dofs)))
    return S, DofGather(V, dofs), owner


def cell_centroids(mesh) -> np.ndarray:
    """The centroid of each (local) cell's vertices, (cells, gdim) mm."""
    dim = mesh.topology.dim
    x = mesh.geometry.x[:, :mesh.geometry.dim]
    return x[mesh.geometry.dofmap.array.reshape(-1, dim + 1)].mean(axis=1)


def cell_sizes(mesh) -> np.ndarray:
    """Edge length h_K of the equilateral cell with each (local) cell's area (2D) or volume (3D), mm.

    Area sqrt(3)/4 h^2, volume h^3 / (6 sqrt 2); affine cells.
    """
    dim = mesh.topology.dim
    x = mesh.geometry.x[:, :mesh.geometry.dim]
    nodes = mesh.geometry.dofmap.array.reshape(-1, dim + 1)
    v0 = x[nodes[:, 0]]
    J = np.stack([x[nodes[:, j + 1]] - v0 for j in range(dim)], axis=2)
    vol = np.abs(np.linalg.det(J)) / math.factorial(dim)
    return np.sqrt(4.0 * vol / math.sqrt(3.0)) if dim == 2 else np.cbrt(6.0 * math.sqrt(2.0) * vol)
