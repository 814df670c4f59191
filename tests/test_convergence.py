"""Manufactured Neo-Hookean solution through skelfem's Model and NewtonSolver: L2 slopes ~2 (P1), ~3 (P2).

u* = a (sin(pi y) x, cos(pi x) y^2) on the unit square. The body force
b = -div P(F(u*)), P = d psi / dF the first Piola-Kirchhoff stress of
skelfem.terms.elasticity.psi, enters the model as one extra energy term
(Pi_b = -t int b . u dx) through a custom builder list; u* is prescribed on
the boundary by a Dirichlet condition of the same term (the design's fixed pin
holds the bottom edge, where u* = 0). Everything else -- the elasticity term,
the compiled forms, the Newton matrix, the energy line search, the load ramp
-- is skelfem's own, so the slopes check the energy and solver the simulator
uses.
"""
import numpy as np
import pytest
import ufl
from dolfinx import fem
from dolfinx import mesh as dmesh
from mpi4py import MPI

from skelfem.design import parse_design
from skelfem.mesh.geometry import BODY, TaggedMesh
from skelfem.fem.model import Model
from skelfem.fem.newton import NewtonSolver
from skelfem.terms import BUILDERS, Term
from skelfem.terms.elasticity import lame, psi
from skelfem.terms.capabilities import Constraints

E, NU = 1.0, 0.3


def _exact(x, a=0.08):
    return ufl.as_vector([a * ufl.sin(ufl.pi * x[1]) * x[0], a * ufl.cos(ufl.pi * x[0]) * x[1] ** 2])


def _design(degree: int):
    """The unit square as a design: one material, the bottom edge pinned (u* = 0 there), no cables."""
    return parse_design({
        "format": 1, "name": "mms", "dim": 2, "thickness": 1.0,
        "mesh": {"size": 0.25, "degree": degree},
        "materials": {"soft": {"E": E, "nu": NU}},
        "body": {"outline": [[0, 0], [1, 0], [1, 1], [0, 1]], "material": "soft"},
        "pins": [{"name": "bottom", "region": [[-1, -1], [2, 1e-9]], "kind": "fixed"}],
        "solver": {"steps": 2, "rtol": 1e-14, "atol": 1e-11},
    })


def _unit_square(n: int) -> TaggedMesh:
    """A structured (crossed) mesh of the unit square, every cell tagged as the body."""
    mesh = dmesh.create_unit_square(MPI.COMM_WORLD, n, n, diagonal=dmesh.DiagonalType.crossed)
    cells = np.arange(mesh.topology.index_map(2).size_local, dtype=np.int32)
    return TaggedMesh(mesh, dmesh.meshtags(mesh, 2, cells, np.ones_like(cells)), {BODY: 1})


class Manufactured(Term, Constraints):
    """Body force b = -div P(F(u*)) and u = u* on the boundary, both ramped by the load factor."""

    section, name = "manufactured", "mms"

    def __init__(self, ctx):
        mesh, V = ctx.mesh, ctx.V
        x = ufl.SpatialCoordinate(mesh)
        self.u_exact = _exact(x)
        F = ufl.variable(ufl.Identity(2) + ufl.grad(self.u_exact))
        mu, lam = lame(E, NU)
        self.b = -ufl.div(ufl.diff(psi(F, mu, lam), F))
        self.a = fem.Constant(mesh, 0.0)
        self.g_full = fem.Function(V)
        self.g_full.interpolate(fem.Expression(self.u_exact, V.element.interpolation_points()))
        self.g = fem.Function(V)
        mesh.topology.create_connectivity(1, 2)
        nodes = fem.locate_dofs_topological(V, 1, dmesh.exterior_facet_indices(mesh.topology))
        self.dofs = (nodes[:, None] * ctx.bs + np.arange(ctx.bs)).ravel()
        self.bc = fem.dirichletbc(self.g, nodes)

    def ufl_energy(self, ctx):
        dx = ufl.dx(metadata={"quadrature_degree": 2 * ctx.V.ufl_element().degree() + 4})
        return -ctx.thickness * self.a * ufl.inner(self.b, ctx.u) * dx

    def dirichlet(self):
        return [(self.bc, self.dofs)]

    def set_factor(self, a: float) -> None:
        self.a.value = a
        self.g.x.array[:] = a * self.g_full.x.array


def _solve(n: int, degree: int):
    """(L2 error of skelfem's equilibrium against u*, its solve report)."""
    model = Model(_design(degree), _unit_square(n), builders=[*BUILDERS, lambda ctx: [Manufactured(ctx)]])
    solver = NewtonSolver(model)
    report = solver.solve(model.design.solver.steps)
    solver.destroy()
    assert report.converged, report.status
    term = model.term("manufactured")
    assert term.a.value == 1.0
    x = ufl.SpatialCoordinate(model.mesh)
    err = fem.form(ufl.inner(model.u - _exact(x), model.u - _exact(x)) * ufl.dx(metadata={"quadrature_degree": 8}))
    return float(np.sqrt(model.comm.allreduce(fem.assemble_scalar(err), op=MPI.SUM))), report


@pytest.mark.parametrize("degree, expected", [(1, 2.0), (2, 3.0)])
def test_l2_error_slope(degree, expected):
    ns = [4, 8, 16]
    runs = [_solve(n, degree) for n in ns]
    errors = [e for e, _ in runs]
    slope = np.polyfit(np.log(1.0 / np.array(ns)), np.log(errors), 1)[0]
    print(f"P{degree}: L2 errors {errors}, fitted slope {slope:.3f}, "
          f"Newton iterations {[r.newton_iterations for _, r in runs]}")
    assert abs(slope - expected) < 0.2, (errors, slope)
    assert errors[-1] < errors[0] / 2 ** (expected * 2 - 1)
    for _, report in runs:                        # skelfem's Newton: converged to its tolerance, quadratically
        last = report.residual_history[-1]
        assert last[-1] <= 1e-11 and len(last) <= 8, last


def test_the_manufactured_term_is_what_moves_the_body():
    """Without the extra term the pinned, unloaded square stays at rest: the slopes measure that term."""
    model = Model(_design(1), _unit_square(4))
    solver = NewtonSolver(model)
    report = solver.solve(1)
    solver.destroy()
    assert report.converged and report.newton_iterations == 0
    assert not model.terms_in("manufactured") and np.abs(model.u.x.array).max() == 0.0
