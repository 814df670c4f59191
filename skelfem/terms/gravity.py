"""Gravity: the weight of every region as a dead body force.

With rho the density of each region's material (kg/m^3, as people quote it)
and g the acceleration (m/s^2), the body force per volume is
b = 1e-9 rho g N/mm^3 (1 kg/m^3 x 1 m/s^2 = 1 N/m^3 = 1e-9 N/mm^3), and

    Pi_grav(u; a) = -a t int_Omega b . u dx,

t the slab thickness in 2D (1 in 3D), a the load factor. rho is a DG0 field,
so ``gravity.acceleration`` and ``materials.NAME.density`` change live.
Read-out: the acceleration and the total weight (N).
"""
from __future__ import annotations

import numpy as np
import ufl
from dolfinx import fem
from mpi4py import MPI

from .base import Context, Term, constant, touched
from .capabilities import Follows
from .elasticity import region_cells, region_materials

KG_PER_M3_TIMES_M_PER_S2 = 1e-9     # N/mm^3


class Gravity(Term, Follows):
    section, name = "gravity", "gravity"

    def __init__(self, ctx: Context):
        self.ctx = ctx
        design = ctx.design
        self.g = np.asarray(design.gravity, dtype=float).copy()
        self.cells = region_cells(ctx, design)
        self.regions = region_materials(design)
        self.density = {n: float(design.materials[n].density) for n in self.cells}
        self.rho = fem.Function(fem.FunctionSpace(ctx.mesh, ("DG", 0)), name="density")
        self._update_density()
        self._ga = constant(ctx.mesh, np.zeros(ctx.dim))        # a g, ramped
        self.factor = 0.0
        self._mass_form = fem.form(ctx.thickness * self.rho * ufl.dx)

    def _update_density(self) -> None:
        for name, cells in self.cells.items():
            self.rho.x.array[cells] = self.density[name]

    def ufl_energy(self, ctx: Context):
        return -KG_PER_M3_TIMES_M_PER_S2 * ctx.thickness * self.rho * ufl.dot(self._ga, ctx.u) * ufl.dx

    def follow(self, ctx: Context, changed: set) -> bool:
        """The same regions' materials, compared as built whatever keys changed them (densities and the
        acceleration are live)."""
        return not touched(changed, "gravity", "materials") and region_materials(ctx.design) == self.regions

    def set_factor(self, a: float) -> None:
        self.factor = float(a)
        self._ga.value[:] = a * self.g

    def parameters(self) -> dict:
        out: dict = {"gravity.acceleration": self.g.copy()}
        out.update({f"materials.{n}.density": rho for n, rho in self.density.items()})
        return out

    def set_parameter(self, key: str, value) -> None:
        if key == "gravity.acceleration":
            self.g = np.asarray(value, dtype=float).reshape(self.g.shape).copy()
            self.set_factor(self.factor)
            return
        _, name, which = key.split(".")
        if which != "density" or name not in self.density:
            raise KeyError(key)
        self.density[name] = float(value)
        self._update_density()

    def readout(self, model) -> dict:
        mass = self.ctx.comm.allreduce(fem.assemble_scalar(self._mass_form), op=MPI.SUM)   # kg/m^3 mm^3
        return {"acceleration": self.g, "weight": KG_PER_M3_TIMES_M_PER_S2 * mass * self.g}


def build(ctx: Context) -> list[Term]:
    return [Gravity(ctx)] if ctx.design.gravity is not None else []
