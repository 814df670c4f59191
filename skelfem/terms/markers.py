"""Markers: named material points whose positions are reported (no energy).

x_m = X_m + (S u)_m, S the interpolation at the markers' material points,
gathered on every rank. Read-out: reference, position and displacement.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..mesh.points import global_interpolation
from .base import Context, Term, moved_nodes_only
from .capabilities import Follows


class Markers(Term, Follows):
    section, name = "markers", "markers"

    def __init__(self, ctx: Context):
        self.names = list(ctx.design.markers)
        self.dim, self.comm = ctx.dim, ctx.comm
        self.X = np.array([ctx.design.markers[n] for n in self.names], float).reshape(-1, self.dim)
        self.S, self.gather, owner = global_interpolation(ctx.V, self.X)
        self.n_local = len(ctx.u.x.array)
        for name, o in zip(self.names, owner):
            if o == ctx.comm.size:
                from ..design.spec import DesignError
                raise DesignError(f"{ctx.design.source}: markers.{name}: point lies outside the mesh")

    def follow(self, ctx: Context, changed: set) -> bool:
        """A draft on moved nodes only (terms.base.moved_nodes_only: a 3D bone's pose, a 2D outline's
        vertices): the markers keep their interpolation (26 ms of a frame at 10k DOFs in 3D, a new cell
        tree, not spent); anything else: built anew."""
        return moved_nodes_only(ctx, changed)

    def positions(self, u: np.ndarray) -> np.ndarray:
        """Current marker positions (every rank gets all of them; collective under MPI)."""
        return self.X + (self.S @ self.gather(u)).reshape(-1, self.dim)

    def local_operator(self) -> sp.csr_matrix:
        """u(X_m) = (S_local u)_m on one process's local DOFs (serial only)."""
        if self.comm.size > 1:
            raise RuntimeError("local_operator acts on one process's DOFs; use positions under MPI")
        S = self.S.tocoo()
        return sp.csr_matrix((S.data, (S.row, self.gather.local[S.col])), shape=(S.shape[0], self.n_local))

    def readout(self, model) -> dict:
        x = self.positions(model.u.x.array)
        return {n: {"reference": X, "position": p, "displacement": p - X}
                for n, X, p in zip(self.names, self.X, x)}


def build(ctx: Context) -> list[Term]:
    return [Markers(ctx)] if ctx.design.markers else []
