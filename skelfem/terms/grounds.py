"""Grounds: rigid half-spaces (force sensors) pushed by the body's boundary.

A ground is the plane through p with unit normal n; the body stays on the
side n points to. With x = X + u a boundary point and gap = (x - p) . n, the
one-sided quadratic penalty (paper Sec. IV.B, integrated over the boundary so
that it does not depend on the mesh) is

    Pi_g(u) = k t/2 int_dOmega min(gap, 0)^2 ds,

k in N/mm per mm^2 of contact area, t the slab thickness (t = 1 in 3D). Its
first variation is k t int min(gap, 0) n . v ds: the body is pushed along +n
wherever it has crossed the plane. The force the body exerts on the plane
(the sensor's reading) is the opposite of that push,

    F_g = k t int_dOmega min(gap, 0) ds * n,

which points into the plane (-n) when the body presses on it. As k grows the
penetration shrinks like 1/k and F_g converges to the contact force of the
rigid constraint. Pi_g is a UFL form: the residual and Jacobian follow from
ufl.derivative, compiled once with the rest of the model's energy.

Quadrature: the boundary integrals use points at the displacement's nodes on
each facet: Gauss-Lobatto on 2D edges (trapezoidal rule for P1, Simpson for
P2), a nodal rule on 3D triangles (a third of the area at each vertex for P1;
for P2 each node's share of the four triangles the edge midpoints cut a
triangle into, 1/12 at a vertex and 1/4 at a midpoint, the weights the
contact's collision mesh uses too).
So the penalty acts node by node, weighted by each node's share of the
boundary (the paper's per-node penalty, made mesh-independent), the extreme
points of a P1 boundary -- its nodes -- are the ones held back, and energy,
residual, Jacobian and reported force all use the same points. (A Gauss rule
would sample facet interiors only and could miss a node that has crossed the
plane.)
"""
from __future__ import annotations

import numpy as np
import ufl
from dolfinx import fem
import basix
from mpi4py import MPI

from .base import Context, Term, constant, touched
from .capabilities import Follows


# Nodal rules on the reference triangle (area 1/2) for 3D boundaries: P1 its vertices (1/3 of the area
# each); P2 its vertices and edge midpoints, each with its share of the four triangles the midpoints cut it
# into (1/12 of the area at a vertex, 1/4 at a midpoint): positive at every node, exact for linear functions.
_TRIANGLE_NODES = {
    1: ([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]], [1 / 6] * 3),
    2: ([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [0.5, 0.5], [0.0, 0.5], [0.5, 0.0]], [1 / 24] * 3 + [1 / 8] * 3),
}


def _interpolatory(degree: int) -> tuple[np.ndarray, np.ndarray]:
    """The nodes of DOLFINx's P_degree triangle with weights = the integrals of their basis functions
    (all positive from P3 on, unlike P2's vertices): the richer space of the error estimate."""
    element = basix.create_element(basix.ElementFamily.P, basix.CellType.triangle, degree,
                                   basix.LagrangeVariant.gll_warped)
    q, w = basix.make_quadrature(basix.CellType.triangle, 2 * degree + 2)
    weights = w @ element.tabulate(0, q)[0, :, :, 0]
    if np.any(weights <= 0):
        raise ValueError(f"no positive nodal rule of degree {degree} on a ground's triangles")
    return element.points, weights


def nodal_ds(u):
    """Boundary measure with points at the nodes of u's element on each facet: Gauss-Lobatto on the
    edges of a 2D boundary, the nodal rule above on the triangles of a 3D one."""
    degree = u.function_space.ufl_element().degree()
    mesh = u.function_space.mesh
    if mesh.topology.dim == 2:
        metadata = {"quadrature_rule": "GLL", "quadrature_degree": 2 * degree - 1}
    else:
        points, weights = _TRIANGLE_NODES[degree] if degree in _TRIANGLE_NODES else _interpolatory(degree)
        metadata = {"quadrature_rule": "custom", "quadrature_degree": degree,
                    "quadrature_points": np.array(points), "quadrature_weights": np.array(weights)}
    return ufl.Measure("ds", domain=mesh, metadata=metadata)


class Ground(Term, Follows):
    """One half-space. Parameters ``grounds.NAME.point`` and ``.stiffness``; read-out ``force``."""

    section = "grounds"

    def __init__(self, ctx: Context, spec):
        self.ctx, self.name = ctx, spec.name
        self.normal = np.asarray(spec.normal, dtype=float)
        self.point = np.asarray(spec.point, dtype=float).copy()
        self._n, self._p = constant(ctx.mesh, self.normal), constant(ctx.mesh, self.point)
        self._k = constant(ctx.mesh, float(spec.stiffness))
        X = ufl.SpatialCoordinate(ctx.mesh)
        pen = ufl.min_value(ufl.dot(X + ctx.u - self._p, self._n), 0.0)   # min(gap, 0)
        ds = nodal_ds(ctx.u)
        self._energy = 0.5 * self._k * ctx.thickness * pen ** 2 * ds
        self._force_form = fem.form(self._k * ctx.thickness * pen * ds)

    def ufl_energy(self, ctx: Context):
        return self._energy

    def follow(self, ctx: Context, changed: set) -> bool:
        """The plane is in the compiled energy (its point and stiffness are live): the same normal."""
        return not touched(changed, f"grounds.{self.name}", "grounds.#order")

    def move_to(self, point) -> None:
        """Place the plane through a new point (same normal); the compiled forms follow."""
        self.point = np.asarray(point, dtype=float).copy()
        self._p.value[:] = self.point

    def force(self) -> np.ndarray:
        """Net force the body exerts on the plane, N (at the current u)."""
        return self.normal * self.ctx.comm.allreduce(fem.assemble_scalar(self._force_form), op=MPI.SUM)

    def parameters(self) -> dict:
        return {f"grounds.{self.name}.point": self.point.copy(),
                f"grounds.{self.name}.stiffness": float(self._k.value)}

    def set_parameter(self, key: str, value) -> None:
        which = key.rsplit(".", 1)[1]
        if which == "point":
            self.move_to(value)
        elif which == "stiffness":
            self._k.value = float(value)
        else:
            raise KeyError(key)

    def readout(self, model) -> dict:
        return {self.name: {"force": self.force()}}


def build(ctx: Context) -> list[Term]:
    return [Ground(ctx, spec) for spec in ctx.design.grounds]
