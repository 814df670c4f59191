"""Moving a 3D mesh with its bones' poses, instead of re-meshing (the editor's 3D drafts).

While a person drags or turns a bone of a ``dim = 3`` design, only the
bones' poses (``move``, ``rotate``: skelfem.design.pose) change. The
tetrahedral mesh generated for the design X0 can then follow: every node of
a bone's cells moves rigidly with the bone,

    x = R X + b        (R, b: the bone's pose relative to the one meshed),

the nodes on the mesh's outer surface (and of the objects' cells) stay, and
the other nodes move by the harmonic extension of those moves (the P1
Laplace equation on the tetrahedra, factorised once per mesh):

    K_II delta_I = -K_IB delta_B.

The moved mesh has the same topology, cells, region tags and DOF numbering,
so the last solution is the exact start, and nothing is meshed or compiled.
Each move is taken from the mesh as generated (X0), so drags do not drift.
When the moved mesh would be poor (a tetrahedron turned over or shrunk below
MIN_VOLUME of its volume) or anything but the poses changed,
:meth:`Morph3D.moved` returns None and the caller re-meshes.

The answer on a moved mesh differs from a fresh mesh of the same design by
the discretisation error only; the editor re-meshes when the drag ends.
"""
from __future__ import annotations

import hashlib
import json

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from . import keep

MIN_VOLUME = 0.2         # a moved tetrahedron keeps at least this fraction of its volume (and its orientation)


def _plain(v):
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items() if k != "pose"}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    return v


def shape_key(design) -> str:
    """A digest of a 3D design's solids as written (bodies, bones without their poses, objects)."""
    parts = [[b.solids for b in design.bodies], [(b.name, b.solids) for b in design.bones],
             [(o.name, getattr(o, "solids", ())) for o in design.objects]]
    return hashlib.sha256(json.dumps(_plain(parts), sort_keys=True).encode()).hexdigest()


def same_poses(a, b) -> bool:
    """Whether two 3D designs place their bones alike (same names, same poses)."""
    pa, pb = ({x.name: x.pose for x in d.bones} for d in (a, b))
    return pa.keys() == pb.keys() and all(json.dumps(_plain(pa[k]), sort_keys=True)
                                          == json.dumps(_plain(pb[k]), sort_keys=True) for k in pa)


def signed_volumes(x: np.ndarray, cells: np.ndarray) -> np.ndarray:
    a = x[cells[:, 0]]
    return np.einsum("ni,ni->n", np.cross(x[cells[:, 1]] - a, x[cells[:, 2]] - a), x[cells[:, 3]] - a) / 6.0


def laplacian(x: np.ndarray, cells: np.ndarray) -> sp.csr_matrix:
    """The P1 stiffness matrix of the Laplacian on tetrahedra, assembled without a cell loop."""
    a = x[cells[:, 0]]
    J = np.stack([x[cells[:, 1]] - a, x[cells[:, 2]] - a, x[cells[:, 3]] - a], axis=2)   # columns: edges
    vol = np.abs(np.linalg.det(J)) / 6.0
    Jinv = np.linalg.inv(J)                          # rows: gradients of the barycentric coordinates 1..3
    grads = np.concatenate([-Jinv.sum(axis=1, keepdims=True), Jinv], axis=1)          # (n, 4, 3)
    local = np.einsum("nik,njk->nij", grads, grads) * vol[:, None, None]
    rows = np.repeat(cells, 4, axis=1)
    cols = np.tile(cells, (1, 4))
    n = len(x)
    return sp.csr_matrix((local.ravel(), (rows.ravel(), cols.ravel())), shape=(n, n))


def outer_nodes(cells: np.ndarray) -> np.ndarray:
    """The nodes on faces that belong to one tetrahedron only (the mesh's outer surface)."""
    faces = np.sort(np.concatenate([cells[:, [0, 1, 2]], cells[:, [0, 1, 3]], cells[:, [0, 2, 3]],
                                    cells[:, [1, 2, 3]]]), axis=1)
    _, index, counts = np.unique(faces, axis=0, return_index=True, return_counts=True)
    return np.unique(faces[index[counts == 1]])


class Morph3D:
    """The mesh of one 3D design, movable to designs that differ from it only in the bones' poses."""

    def __init__(self, tagged_mesh, design):
        mesh = tagged_mesh.mesh
        self.mesh = mesh
        self.X0 = mesh.geometry.x[:, :3].copy()
        self.cells = mesh.geometry.dofmap.array.reshape(-1, 4)
        self.shape = shape_key(design)
        self.poses0 = {b.name: b.pose for b in design.bones}
        self.vol0 = signed_volumes(self.X0, self.cells)
        ct = tagged_mesh.cell_tags
        tag_of = np.zeros(len(self.cells), dtype=int)
        tag_of[np.asarray(ct.indices)] = np.asarray(ct.values)
        self.bone_nodes = {}
        taken = np.zeros(len(self.X0), dtype=bool)
        for b in design.bones:
            tag = tagged_mesh.tags.get(f"bone:{b.name}")
            nodes = np.unique(self.cells[tag_of == tag]) if tag is not None else np.zeros(0, dtype=int)
            self.bone_nodes[b.name] = nodes
            taken[nodes] = True
        fixed = np.zeros(len(self.X0), dtype=bool)
        fixed[outer_nodes(self.cells)] = True
        for name, tag in tagged_mesh.tags.items():
            if name.startswith("object:"):
                fixed[np.unique(self.cells[tag_of == tag])] = True
        fixed &= ~taken
        self.bound = np.flatnonzero(taken | fixed)
        self.free = np.flatnonzero(~(taken | fixed))
        K = laplacian(self.X0, self.cells)
        self.K_IB = K[self.free][:, self.bound]
        self._solve = spla.factorized(K[self.free][:, self.free].tocsc()) if len(self.free) else None

    def moved(self, design) -> np.ndarray | None:
        """Node coordinates (n, 3) of this mesh with design's bone poses, or None if it cannot follow."""
        if design.dim != 3 or shape_key(design) != self.shape:
            return None
        from ..design.pose import relative
        delta = np.zeros_like(self.X0)
        for b in design.bones:
            if b.name not in self.poses0:
                return None
            R, t = relative(self.poses0[b.name], b.pose)
            X = self.X0[self.bone_nodes[b.name]]
            delta[self.bone_nodes[b.name]] = X @ R.T + t - X
        if self._solve is not None and np.any(delta):
            rhs = -(self.K_IB @ delta[self.bound])
            delta[self.free] = np.column_stack([self._solve(np.ascontiguousarray(rhs[:, j])) for j in range(3)])
        x = self.X0 + delta
        vol = signed_volumes(x, self.cells)
        if np.any(vol * np.sign(self.vol0) < MIN_VOLUME * np.abs(self.vol0)):
            return None
        return x

    def pull_back(self, g: np.ndarray) -> np.ndarray:
        """The transpose of the harmonic extension: for g = dJ/dX (n, 3) at every node, dJ/d(the moves of the
        bones' and the outer surface's nodes) (n, 3; zero on the other nodes), whatever moves them. One solve
        with K_II per axis (K_II is symmetric)."""
        g = np.asarray(g, dtype=float)
        out = np.zeros_like(g)
        out[self.bound] = g[self.bound]
        if self._solve is not None:
            y = np.column_stack([self._solve(np.ascontiguousarray(g[self.free, j])) for j in range(3)])
            out[self.bound] -= self.K_IB.T @ y
        return out

    def apply(self, x: np.ndarray) -> None:
        """Put the node coordinates x into the mesh and forget what was computed from the old ones."""
        self.mesh.geometry.x[:, :3] = x
        keep.forget(self.mesh, "cell_tree", "facets")
