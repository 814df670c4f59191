"""Rigid bones: a bone with ``rigid = true`` moves as one rigid body.

Every node i of the bone (reference position X_i, current y_i = X_i + u_i)
follows the bone's rigid DOFs q: 3 in 2D (translation t, angle theta), 6 in
3D (translation t, rotation vector omega),

    y_i = c + t + R(q) (y0_i - c),

with c the centroid of the nodes and y0 the positions at the current state
(a local chart, q = 0 there: Newton steps and the exact update are taken
relative to the state they start from). The bone's cells carry no strain, so
Elasticity leaves them out of its form; nothing else changes for the terms
(cables, loads, markers on the bone act through the slaved node
displacements). The reduced problem minimises Pi over the free DOFs and q:

    grad_q Pi = T^T R_b,      T = du_b/dq = [e_a | rotation modes (y0 - c)]
    hess_q Pi = T^T K_bb T + sum_i R_i . d2u_i/dq2

with R_b the full gradient on the bone's nodes. The second-derivative term
(2D: -sum_i R_i . r_i; 3D: sym(S) - tr(S) I with S = sum_i r_i R_i^T,
r = y0 - c) is what makes Newton on the reduced problem quadratic. The
model assembles and solves it (``Model.jacobian``, ``skelfem.fem.linear``),
the line search moves the bone along the exact rotation
(``Elasticity.step_correction``), and the residual SNES sees on the bone's
rows is the orthogonal projection of R_b onto its rigid modes, T (T^T T)^-1
T^T R_b: zero exactly when the reduced gradient is.

This term adds no energy. It gives the model its :class:`RigidBody`, makes
the identity rows of the bone's DOFs part of the matrix pattern (interior
nodes touch no assembled cell), and reports q (``bones.NAME``: the
translation of the centroid and the rotation, an angle in 2D, a rotation
vector in 3D, in radians).
"""
from __future__ import annotations

import numpy as np
from dolfinx import fem
from mpi4py import MPI

from ..mesh.geometry import bone_tag_name
from .base import Context, Term
from .capabilities import Constraints


def _cross_matrix(r: np.ndarray) -> np.ndarray:
    """[e_a x r_i] stacked: (n, 3, 3), column a the rotation mode about axis a."""
    n = len(r)
    out = np.zeros((n, 3, 3))
    for a in range(3):
        e = np.zeros(3)
        e[a] = 1.0
        out[:, :, a] = np.cross(e, r)
    return out


def rotation(w: np.ndarray | float, dim: int) -> np.ndarray:
    """R(w): 2D the rotation by the angle w, 3D by the rotation vector w (Rodrigues)."""
    if dim == 2:
        c, s = np.cos(float(w)), np.sin(float(w))
        return np.array([[c, -s], [s, c]])
    w = np.asarray(w, float)
    angle = float(np.linalg.norm(w))
    if angle < 1e-300:
        return np.eye(3)
    k = w / angle
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * Kx + (1 - np.cos(angle)) * Kx @ Kx


def closest_rigid_motion(X: np.ndarray, y: np.ndarray, total=lambda a: a):
    """(c_X, c_y, R): the rigid motion y ~ c_y + R (X - c_X) closest to y in least squares (Kabsch).

    total sums over ranks (identity in serial); R is a rotation, not a reflection.
    """
    n = total(len(X))
    cx, cy = total(X.sum(axis=0)) / n, total(y.sum(axis=0)) / n
    H = total((X - cx).T @ (y - cy))                    # sum (X - c_X) (y - c_y)^T
    U, _, Vt = np.linalg.svd(H)
    D = np.eye(len(H))
    D[-1, -1] = np.sign(np.linalg.det(Vt.T @ U.T))
    return cx, cy, Vt.T @ D @ U.T


def rotation_readout(R: np.ndarray):
    """2D: the angle in rad; 3D: the rotation vector (axis times angle, rad)."""
    if len(R) == 2:
        return float(np.arctan2(R[1, 0], R[0, 0]))
    from scipy.spatial.transform import Rotation
    return Rotation.from_matrix(R).as_rotvec()


class RigidBody:
    """The kinematics of one rigid node group: modes, reduced gradient, projection, second derivatives.

    ``dofs`` (k, bs): owned unrolled DOFs of the nodes; ``X`` (k, dim):
    their reference positions. Every method that sums over nodes is
    collective (an allreduce of a few numbers under MPI).
    """

    def __init__(self, name: str, dofs: np.ndarray, X: np.ndarray, comm):
        self.name, self.dofs, self.X, self.comm = name, dofs, X, comm
        self.dim = X.shape[1]
        self.m = 3 if self.dim == 2 else 6
        self.count = comm.allreduce(len(X), op=MPI.SUM)
        self.c0 = self._sum(X.sum(axis=0)) / self.count

    def _sum(self, a):
        return a if self.comm.size == 1 else self.comm.allreduce(a)

    def arms(self, u: np.ndarray) -> np.ndarray:
        """r_i = y_i - c: current node positions about their centroid (k, dim)."""
        y = self.X + u[self.dofs]
        return y - self._sum(y.sum(axis=0)) / self.count

    def modes(self, u: np.ndarray) -> np.ndarray:
        """T = du_b/dq at the state u: (k, dim, m), translations then rotations about the centroid."""
        r = self.arms(u)
        k, d = r.shape
        T = np.zeros((k, d, self.m))
        T[:, :, :d] = np.eye(d)
        if d == 2:
            T[:, 0, 2], T[:, 1, 2] = -r[:, 1], r[:, 0]
        else:
            T[:, :, 3:] = _cross_matrix(r)
        return T

    def reduce(self, T: np.ndarray, v: np.ndarray) -> np.ndarray:
        """T^T v_b (m,) of a full vector v (owned entries)."""
        return self._sum(np.einsum("kdm,kd->m", T, v[self.dofs]))

    def project(self, T: np.ndarray, v: np.ndarray) -> None:
        """v_b <- T (T^T T)^-1 T^T v_b in place: the part of v on the bone along its rigid modes."""
        M = self._sum(np.einsum("kdm,kdn->mn", T, T))
        a = np.linalg.solve(M, self.reduce(T, v))
        v[self.dofs] = T @ a

    def second_derivative(self, u: np.ndarray, R: np.ndarray) -> np.ndarray:
        """sum_i R_i . d2u_i/dq2 (m, m) at q = 0, R the full gradient (owned entries)."""
        r, Rb = self.arms(u), R[self.dofs]
        G = np.zeros((self.m, self.m))
        if self.dim == 2:
            G[2, 2] = -self._sum(float(np.sum(Rb * r)))
        else:
            S = self._sum(r.T @ Rb)                      # S_ab = sum_i r_ia R_ib
            G[3:, 3:] = 0.5 * (S + S.T) - np.trace(S) * np.eye(3)
        return G

    def fit(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(translation of the centroid, rotation matrix) of the rigid motion closest to u (Kabsch)."""
        _, cy, R = closest_rigid_motion(self.X, self.X + u[self.dofs], self._sum)
        return cy - self.c0, R

    def snap(self, u: np.ndarray) -> None:
        """Make the bone's displacement in u (in place) exactly its closest rigid motion."""
        t, R = self.fit(u)
        u[self.dofs] = self.c0 + t + (self.X - self.c0) @ R.T - self.X


class RigidBone(Term, Constraints):
    """One rigid bone: no energy; its kinematics for the model, its pattern and its read-out."""

    section = "bones"

    def __init__(self, ctx: Context, spec):
        self.ctx, self.name = ctx, spec.name
        tm, V, bs = ctx.tagged, ctx.V, ctx.bs
        cells = tm.cell_tags.find(tm.tags[bone_tag_name(spec.name)])
        self.nodes = fem.locate_dofs_topological(V, ctx.mesh.topology.dim, cells)
        owned = self.nodes[self.nodes < V.dofmap.index_map.size_local]
        X = V.tabulate_dof_coordinates()[owned, :ctx.dim]
        self.body = RigidBody(spec.name, owned[:, None] * bs + np.arange(bs), X, ctx.comm)

    def rigid_body(self):
        return self.body

    def pattern(self) -> list:
        return [(self.nodes[i:i + 1], self.nodes[i:i + 1]) for i in range(len(self.nodes))]

    def readout(self, model) -> dict:
        t, R = self.body.fit(model.u.x.array)
        return {self.name: {"rigid": True, "translation": t, "rotation": rotation_readout(R)}}


def build(ctx: Context) -> list[Term]:
    return [RigidBone(ctx, b) for b in ctx.design.bones if b.rigid]
