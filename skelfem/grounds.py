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
ufl.derivative, compiled once with the rest of the scene's energy.

Quadrature: the boundary integrals use Gauss-Lobatto points, which are the
displacement's nodes on each facet (trapezoidal rule for P1, Simpson for P2).
So the penalty acts node by node, weighted by each node's share of the
boundary (the paper's per-node penalty, made mesh-independent), the extreme
points of a P1 boundary -- its nodes -- are the ones held back, and energy,
residual, Jacobian and reported force all use the same points. (A Gauss rule
would sample facet interiors only and could miss a node that has crossed the
plane.)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import ufl
from dolfinx import fem
from petsc4py import PETSc


@dataclass(eq=False)
class Ground:
    """One half-space with its compiled force form."""

    name: str
    normal: np.ndarray        # unit n, (gdim,)
    point: np.ndarray         # p, (gdim,)
    stiffness: float          # k, N/mm per mm^2
    energy: object            # UFL integrand of Pi_g (a ds-form)
    force_form: object        # compiled k t int min(gap, 0) ds
    _p: fem.Constant          # p as seen by the forms

    def move_to(self, point) -> None:
        """Place the plane through a new point (same normal); the compiled forms follow."""
        self.point = np.asarray(point, dtype=float).copy()
        self._p.value[:] = self.point


def _penetration(u, point, normal):
    """min(gap, 0) with gap = (X + u - p) . n, as a UFL expression."""
    X = ufl.SpatialCoordinate(u.function_space.mesh)
    return ufl.min_value(ufl.dot(X + u - point, normal), 0.0)


def nodal_ds(u):
    """Boundary measure with Gauss-Lobatto points at the nodes of u's element on each facet."""
    degree = u.function_space.ufl_element().degree()
    return ufl.Measure("ds", domain=u.function_space.mesh,
                       metadata={"quadrature_rule": "GLL", "quadrature_degree": 2 * degree - 1})


def build_grounds(specs, u: fem.Function, thickness) -> list[Ground]:
    """One Ground per design spec; `thickness` is t (a number or fem.Constant)."""
    mesh = u.function_space.mesh
    ds = nodal_ds(u)
    out = []
    for g in specs:
        n = fem.Constant(mesh, np.asarray(g.normal, dtype=PETSc.ScalarType))
        p = fem.Constant(mesh, np.asarray(g.point, dtype=PETSc.ScalarType))
        k = fem.Constant(mesh, PETSc.ScalarType(g.stiffness))
        pen = _penetration(u, p, n)
        out.append(Ground(g.name, np.asarray(g.normal, float), np.asarray(g.point, float),
                          float(g.stiffness), 0.5 * k * thickness * pen ** 2 * ds,
                          fem.form(k * thickness * pen * ds), p))
    return out


def ground_energy(grounds: list[Ground]):
    """Sum of the grounds' UFL energies, or None when there are none."""
    if not grounds:
        return None
    energy = grounds[0].energy
    for g in grounds[1:]:
        energy = energy + g.energy
    return energy


def ground_forces(grounds: list[Ground], comm) -> list[np.ndarray]:
    """Net force the body exerts on each plane, N (evaluated at the current u)."""
    from mpi4py import MPI
    return [g.normal * comm.allreduce(fem.assemble_scalar(g.force_form), op=MPI.SUM)
            for g in grounds]
