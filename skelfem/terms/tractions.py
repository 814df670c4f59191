"""Boundary tractions: dead loads per area on the boundary inside a box.

With tau the traction (MPa = N/mm^2, per area of the reference boundary)
on the boundary part Gamma inside the box,

    Pi_trac(u; a) = -a t int_Gamma tau . u ds,

t the slab thickness in 2D (1 in 3D), a the load factor. Parameter:
``tractions.NAME.traction``; read-out: the total force a t tau |Gamma| (N)
and the loaded area |Gamma| t (mm^2).
"""
from __future__ import annotations

from typing import Any

import numpy as np
import ufl
from dolfinx import fem
from mpi4py import MPI

from .base import Context, Term, constant, touched
from .capabilities import Follows


class Traction(Term, Follows):
    section = "tractions"

    def __init__(self, ctx: Context, spec):
        self.ctx, self.name = ctx, spec.name
        self.region = np.asarray(spec.region, dtype=float)
        self.box, facets = ctx.boundary(spec.region)
        self.facets = np.sort(facets)
        if ctx.comm.allreduce(len(facets)) == 0:
            from ..design.spec import DesignError
            raise DesignError(f"{ctx.design.source}: tractions.{spec.name}.region: "
                              "no boundary facet of the mesh lies inside the region")
        self.tau = np.asarray(spec.traction, dtype=float).copy()
        self._at = constant(ctx.mesh, np.zeros(ctx.dim))        # a tau, ramped
        self.factor = 0.0
        self._area_form: Any = None

    def ufl_energy(self, ctx: Context):
        ds = ctx.ds(self.box)
        self._area_form = fem.form(ctx.thickness * ds)
        return -ctx.thickness * ufl.dot(self._at, ctx.u) * ds

    def follow(self, ctx: Context, changed: set) -> bool:
        """The same box, and the same boundary facets in it after the nodes moved."""
        if touched(changed, f"tractions.{self.name}", "tractions.#order"):
            return False
        return np.array_equal(np.sort(ctx.boundary_facets(self.region)), self.facets)

    def set_factor(self, a: float) -> None:
        self.factor = float(a)
        self._at.value[:] = a * self.tau

    def parameters(self) -> dict:
        return {f"tractions.{self.name}.traction": self.tau.copy()}

    def set_parameter(self, key: str, value) -> None:
        if key != f"tractions.{self.name}.traction":
            raise KeyError(key)
        self.tau = np.asarray(value, dtype=float).reshape(self.tau.shape).copy()
        self.set_factor(self.factor)

    def readout(self, model) -> dict:
        area = self.ctx.comm.allreduce(fem.assemble_scalar(self._area_form), op=MPI.SUM)
        return {self.name: {"area": area, "force": self.factor * self.tau * area}}


def build(ctx: Context) -> list[Term]:
    return [Traction(ctx, spec) for spec in ctx.design.tractions]
