"""Point loads: dead forces at material points, Pi_load = -a f . u(X_load).

u(X) = S u interpolates the displacement at the load's material point (any
rank may own it: the DOFs are global, gathered on every rank). Linear in u,
so there is no Hessian. Parameter: ``loads.NAME.force``.
"""
from __future__ import annotations

import numpy as np

from ..mesh.points import global_interpolation
from .base import Context, Term


class PointLoad(Term):
    section = "loads"

    def __init__(self, ctx: Context, spec):
        self.name = spec.name
        self.S, self.gather, owner = global_interpolation(ctx.V, np.atleast_2d(spec.at))
        if owner[0] == ctx.comm.size:
            from ..design.spec import DesignError
            raise DesignError(f"{ctx.design.source}: loads.{spec.name}.at: point lies outside the mesh")
        self.f = np.asarray(spec.force, dtype=float).copy()
        self.factor = 0.0

    def set_factor(self, a: float) -> None:
        self.factor = float(a)

    def energy(self, u):
        return -self.factor * float(self.f @ (self.S @ self.gather(u)))

    def gradient(self, u):
        return self.gather.dofs, -self.factor * (self.S.T @ self.f)

    def parameters(self) -> dict:
        return {f"loads.{self.name}.force": self.f.copy()}

    def set_parameter(self, key: str, value) -> None:
        if key != f"loads.{self.name}.force":
            raise KeyError(key)
        self.f = np.asarray(value, dtype=float).reshape(self.f.shape).copy()


def build(ctx: Context) -> list[Term]:
    return [PointLoad(ctx, spec) for spec in ctx.design.loads]
