"""Pins: the body's boundary inside a box held in place (or moved).

``kind = "fixed"``: Dirichlet conditions u = a * move on every DOF of the
boundary facets inside the box (a: the load factor). ``kind = "spring"``:
zero-length springs of stiffness k per area,

    Pi_pin = k t/2 int_{Gamma_pin} |u - a move|^2 ds.

The read-out is the force the pin exerts on the body (``reaction``): for a
fixed pin the sum of grad Pi over its DOFs (the Dirichlet rows of the full
gradient: the force the rest of the body would need there, which the pin
supplies), for a spring pin minus the sum of its own gradient. A load f on
a pinned body gives reaction -f (tests/test_mechanics.py).
"""
from __future__ import annotations

import numpy as np
import ufl
from dolfinx import fem
from dolfinx.fem import petsc as fem_petsc
from petsc4py import PETSc

from .base import Context, Term, constant, touched


class Pin(Term):
    section = "pins"

    def __init__(self, ctx: Context, spec):
        self.ctx, self.spec, self.name, self.kind = ctx, spec, spec.name, spec.kind
        self.box, facets = ctx.boundary(spec.region)
        self.facets = np.sort(facets)
        if ctx.comm.allreduce(len(facets)) == 0:
            from ..design.spec import DesignError
            raise DesignError(f"{ctx.design.source}: pins.{spec.name}.region: "
                              "no boundary facet of the mesh lies inside the region")
        V, bs = ctx.V, ctx.bs
        self.nodes = fem.locate_dofs_topological(V, ctx.mesh.topology.dim - 1, facets)
        self.dofs = (self.nodes[:, None] * bs + np.arange(bs)).ravel()
        self.target = np.asarray(spec.move, dtype=float).copy()
        self.move = constant(ctx.mesh, np.zeros(bs))
        self.k = constant(ctx.mesh, float(spec.stiffness))
        self.bc = fem.dirichletbc(self.move, self.nodes, V) if self.kind == "fixed" else None
        self.factor = 0.0
        self._force_form = None

    def ufl_energy(self, ctx: Context):
        if self.kind != "spring":
            return None
        d = ctx.u - self.move
        self._energy = 0.5 * self.k * ctx.thickness * ufl.inner(d, d) * ctx.ds(self.box)
        return self._energy

    def follow(self, ctx: Context, changed: set) -> bool:
        """The same box and kind, and the same boundary facets in it after the nodes moved."""
        if touched(changed, f"pins.{self.name}", "pins.#order"):
            return False
        return np.array_equal(np.sort(ctx.boundary_facets(self.spec.region)), self.facets)

    def has_ufl_energy(self) -> bool:
        return self.kind == "spring"

    def dirichlet(self) -> list:
        return [(self.bc, self.dofs)] if self.bc is not None else []

    def set_factor(self, a: float) -> None:
        self.factor = float(a)
        self.move.value[:] = a * self.target

    def parameters(self) -> dict:
        out: dict = {f"pins.{self.name}.move": self.target.copy()}
        if self.kind == "spring":
            out[f"pins.{self.name}.stiffness"] = float(self.k.value)
        return out

    def set_parameter(self, key: str, value) -> None:
        which = key.rsplit(".", 1)[1]
        if which == "move":
            self.target = np.asarray(value, dtype=float).reshape(self.target.shape).copy()
            self.set_factor(self.factor)
        elif which == "stiffness" and self.kind == "spring":
            self.k.value = float(value)
        else:
            raise KeyError(key)

    def readout(self, model) -> dict:
        bs = self.ctx.bs
        if self.kind == "fixed":
            full = model.full_gradient()
        else:
            if self._force_form is None:
                self._force_form = fem.form(ufl.derivative(self._energy, self.ctx.u,
                                                           ufl.TestFunction(self.ctx.V)))
            b = fem_petsc.assemble_vector(self._force_form)
            b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            full = b.array_r.copy()
            b.destroy()
        owned = self.dofs[self.dofs < len(full)]
        r = -full[owned].reshape(-1, bs).sum(axis=0) if self.kind == "spring" else \
            full[owned].reshape(-1, bs).sum(axis=0)
        reaction = self.ctx.comm.allreduce(np.asarray(r, float))
        return {self.name: {"reaction": reaction}}


def build(ctx: Context) -> list[Term]:
    return [Pin(ctx, spec) for spec in ctx.design.pins]
