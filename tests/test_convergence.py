"""Manufactured Neo-Hookean solution: L2 error slopes ~2 (P1) and ~3 (P2).

u* = a (sin(pi y) x, cos(pi x) y^2) on the unit square; the body force is
b = -div P(F(u*)) with P = d psi / dF the first Piola-Kirchhoff stress from
skelfem.materials.psi (so the test checks the energy the simulator uses).
"""
import numpy as np
import pytest
import ufl
from dolfinx import fem, nls
from dolfinx import mesh as dmesh
from mpi4py import MPI
from petsc4py import PETSc

from skelfem.materials import deformation_gradient, lame, psi


def _exact(x, a=0.08):
    return ufl.as_vector([a * ufl.sin(ufl.pi * x[1]) * x[0], a * ufl.cos(ufl.pi * x[0]) * x[1] ** 2])


def _l2_error(n: int, degree: int) -> float:
    mesh = dmesh.create_unit_square(MPI.COMM_WORLD, n, n, diagonal=dmesh.DiagonalType.crossed)
    V = fem.VectorFunctionSpace(mesh, ("Lagrange", degree))
    mu, lam = lame(1.0, 0.3)
    x = ufl.SpatialCoordinate(mesh)
    u_ex = _exact(x)
    F_ex = ufl.variable(ufl.Identity(2) + ufl.grad(u_ex))
    P_ex = ufl.diff(psi(F_ex, mu, lam), F_ex)
    b = -ufl.div(P_ex)
    u = fem.Function(V)
    dx = ufl.dx(metadata={"quadrature_degree": 2 * degree + 4})
    Pi = psi(deformation_gradient(u), mu, lam) * dx - ufl.dot(b, u) * dx
    R = ufl.derivative(Pi, u, ufl.TestFunction(V))
    g = fem.Function(V)
    g.interpolate(fem.Expression(u_ex, V.element.interpolation_points()))
    mesh.topology.create_connectivity(1, 2)
    facets = dmesh.exterior_facet_indices(mesh.topology)
    bc = fem.dirichletbc(g, fem.locate_dofs_topological(V, 1, facets))
    problem = fem.petsc.NonlinearProblem(R, u, [bc])
    solver = nls.petsc.NewtonSolver(MPI.COMM_WORLD, problem)
    solver.rtol, solver.atol = 1e-12, 1e-13
    n_it, converged = solver.solve(u)
    assert converged
    err = fem.form(ufl.inner(u - u_ex, u - u_ex) * ufl.dx(metadata={"quadrature_degree": 8}))
    return float(np.sqrt(MPI.COMM_WORLD.allreduce(fem.assemble_scalar(err), op=MPI.SUM)))


@pytest.mark.parametrize("degree, expected", [(1, 2.0), (2, 3.0)])
def test_l2_error_slope(degree, expected):
    ns = [4, 8, 16]
    errors = [_l2_error(n, degree) for n in ns]
    slope = np.polyfit(np.log(1.0 / np.array(ns)), np.log(errors), 1)[0]
    print(f"P{degree}: L2 errors {errors}, fitted slope {slope:.3f}")
    assert abs(slope - expected) < 0.2, (errors, slope)
    assert errors[-1] < errors[0] / 2 ** (expected * 2 - 1)
