"""Pins: the body's boundary inside a box held in place (or moved and turned).

The pinned boundary follows a rigid motion: a point X goes to

    x(X) = c + a move + R(a angle) (X - c),   g(X) = x(X) - X = a move + (R - I)(X - c),

c the rotation's centre, R the rotation by a x angle (2D: in the plane;
3D: about the unit axis), a the load factor (no rotation: g = a move).
``kind = "fixed"``: Dirichlet conditions u = g on every DOF of the boundary
facets inside the box. ``kind = "spring"``: zero-length springs of
stiffness k per area,

    Pi_pin = k t/2 int_{Gamma_pin} |u - g|^2 ds.

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
from .capabilities import Constraints, Follows


class Pin(Term, Constraints, Follows):
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
        self.angle = float(spec.angle)                                      # degrees
        self.centre = np.zeros(bs) if spec.centre is None else np.asarray(spec.centre, float).copy()
        self.axis = None if bs == 2 else (np.array([0.0, 0.0, 1.0]) if spec.axis is None
                                          else np.asarray(spec.axis, float).copy())
        self.move = constant(ctx.mesh, np.zeros(bs))
        self.turn = constant(ctx.mesh, np.zeros((bs, bs)))                 # R - I
        self.c = constant(ctx.mesh, self.centre)
        self.k = constant(ctx.mesh, float(spec.stiffness))
        self.X = V.tabulate_dof_coordinates()[self.nodes, :bs]
        self.g = fem.Function(V) if self.kind == "fixed" else None       # the prescribed displacement
        self.bc = fem.dirichletbc(self.g, self.nodes) if self.g is not None else None
        self.factor = 0.0
        self._force_form = None

    def ufl_energy(self, ctx: Context):
        if self.kind != "spring":
            return None
        d = ctx.u - self.move - ufl.dot(self.turn, ufl.SpatialCoordinate(ctx.mesh) - self.c)
        self._energy = 0.5 * self.k * ctx.thickness * ufl.inner(d, d) * ctx.ds(self.box)
        return self._energy

    def follow(self, ctx: Context, changed: set) -> bool:
        """The same box and kind, and the same boundary facets in it after the nodes moved."""
        if touched(changed, f"pins.{self.name}", "pins.#order"):
            return False
        if not np.array_equal(np.sort(ctx.boundary_facets(self.spec.region)), self.facets):
            return False
        self.X = ctx.V.tabulate_dof_coordinates()[self.nodes, :ctx.bs]     # the nodes may have moved
        self.set_factor(self.factor)
        return True

    def has_ufl_energy(self) -> bool:
        return self.kind == "spring"

    def dirichlet(self) -> list:
        return [(self.bc, self.dofs)] if self.bc is not None else []

    def set_factor(self, a: float) -> None:
        self.factor = float(a)
        self.move.value[:] = a * self.target
        self.turn.value[:] = rotation(a * np.radians(self.angle), self.axis) - np.eye(self.ctx.bs)
        self.c.value[:] = self.centre
        if self.g is not None:
            bs = self.ctx.bs
            self.g.x.array.reshape(-1, bs)[self.nodes] = self.move.value + (self.X - self.centre) @ self.turn.value.T

    def parameters(self) -> dict:
        p = f"pins.{self.name}"
        out: dict = {f"{p}.move": self.target.copy()}
        if self.spec.centre is not None:           # a pin the design turns: its rotation changes live too
            out.update({f"{p}.rotate.angle": self.angle, f"{p}.rotate.centre": self.centre.copy()})
            if self.axis is not None:
                out[f"{p}.rotate.axis"] = self.axis.copy()
        if self.kind == "spring":
            out[f"{p}.stiffness"] = float(self.k.value)
        return out

    def set_parameter(self, key: str, value) -> None:
        which = key.removeprefix(f"pins.{self.name}.")
        if which == "move":
            self.target = np.asarray(value, dtype=float).reshape(self.target.shape).copy()
        elif which == "rotate.angle":
            self.angle = float(value)
        elif which == "rotate.centre":
            self.centre = np.asarray(value, dtype=float).reshape(self.centre.shape).copy()
        elif which == "rotate.axis" and self.axis is not None:
            axis = np.asarray(value, dtype=float).reshape(3)
            self.axis = axis / np.linalg.norm(axis)
        elif which == "stiffness" and self.kind == "spring":
            self.k.value = float(value)
        else:
            raise KeyError(key)
        self.set_factor(self.factor)

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


def rotation(phi: float, axis: np.ndarray | None) -> np.ndarray:
    """The rotation by phi (rad): 2D in the plane (axis None), 3D about the unit axis (Rodrigues)."""
    c, s = np.cos(phi), np.sin(phi)
    if axis is None:
        return np.array([[c, -s], [s, c]])
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + s * K + (1.0 - c) * K @ K


def build(ctx: Context) -> list[Term]:
    return [Pin(ctx, spec) for spec in ctx.design.pins]
