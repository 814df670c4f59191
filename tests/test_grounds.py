"""Grounds: finite-difference checks of the penalty's derivatives, the reported force, convergence in k."""
from types import SimpleNamespace

import numpy as np
import pytest
import ufl
from dolfinx import fem
from dolfinx import mesh as dmesh
from dolfinx.fem import petsc as fem_petsc
from mpi4py import MPI

from _designs import strip
from skelfem import Session
from skelfem.mesh.geometry import TaggedMesh
from skelfem.terms import Context
from skelfem.terms.grounds import Ground


def _ground_forms(degree, k=7.0, t=3.0):
    """Two ground terms (floor and a slanted wall) on a 10 x 6 rectangle, forms of Pi_g and derivatives."""
    mesh = dmesh.create_rectangle(MPI.COMM_WORLD, [[0.0, 0.0], [10.0, 6.0]], [7, 5])
    V = fem.VectorFunctionSpace(mesh, ("Lagrange", degree))
    u = fem.Function(V)
    ctx = Context(None, TaggedMesh(mesh, None, {}), V, u, fem.Constant(mesh, t))    # no design: specs below
    n_wall = np.array([-1.0, -0.3]) / np.hypot(1.0, 0.3)
    specs = [SimpleNamespace(name="floor", point=np.array([0.0, 0.2]), normal=np.array([0.0, 1.0]), stiffness=k),
             SimpleNamespace(name="wall", point=np.array([9.7, 3.0]), normal=n_wall, stiffness=2 * k)]
    grounds = [Ground(ctx, spec) for spec in specs]
    E = sum((g.ufl_energy(ctx) for g in grounds[1:]), grounds[0].ufl_energy(ctx))
    v, du = ufl.TestFunction(V), ufl.TrialFunction(V)
    forms = (fem.form(E), fem.form(ufl.derivative(E, u, v)), fem.form(ufl.derivative(ufl.derivative(E, u, v), u, du)))
    return u, grounds, forms


def _gaps(u, grounds):
    X = u.function_space.tabulate_dof_coordinates()[:, :2]
    y = X + u.x.array.reshape(-1, 2)
    return np.concatenate([(y - g.point) @ g.normal for g in grounds])


@pytest.mark.parametrize("degree", [1, 2])
def test_ground_gradient_and_hessian_match_central_differences(degree):
    u, grounds, (E, R, J) = _ground_forms(degree)
    rng = np.random.default_rng(5)
    u.x.array[:] = 0.25 * rng.normal(size=u.x.array.shape)
    assert np.min(np.abs(_gaps(u, grounds))) > 1e-3          # no node sits on a kink of min(gap, 0)
    assert np.sum(_gaps(u, grounds) < 0) >= 4                # both grounds are pressed

    def energy(a):
        u.x.array[:] = a
        return fem.assemble_scalar(E)

    def grad(a):
        u.x.array[:] = a
        return fem.assemble_vector(R).array.copy()

    u0 = u.x.array.copy()
    g0 = grad(u0)
    u.x.array[:] = u0
    A = fem_petsc.assemble_matrix(J)
    A.assemble()
    H = A.convert("dense").getDenseArray()
    h = 1e-6
    for _ in range(3):                                       # directional checks
        d = rng.normal(size=u0.shape)
        fd = (energy(u0 + h * d) - energy(u0 - h * d)) / (2 * h)
        assert fd == pytest.approx(g0 @ d, rel=1e-7)
        Hd_fd = (grad(u0 + h * d) - grad(u0 - h * d)) / (2 * h)
        assert np.linalg.norm(Hd_fd - H @ d) <= 1e-7 * np.linalg.norm(H @ d)
    # component-wise on the DOFs that touch a pressed node (test-only loop)
    active = np.flatnonzero(np.abs(g0) > 0)
    g_fd = np.array([(energy(u0 + h * e) - energy(u0 - h * e)) / (2 * h)
                     for e in np.eye(len(u0))[active]])
    assert np.linalg.norm(g_fd - g0[active]) <= 1e-7 * np.linalg.norm(g0)
    # a wrong sign or factor would be caught: the gradient is not tiny
    assert np.linalg.norm(g0) > 1.0


def test_reported_force_is_the_net_push_of_the_penalty():
    """F_g = k t int min(gap, 0) ds n equals minus the sum of the residual over a translation."""
    u, grounds, (E, R, J) = _ground_forms(1)
    rng = np.random.default_rng(2)
    u.x.array[:] = 0.25 * rng.normal(size=u.x.array.shape)
    forces = [g.force() for g in grounds]
    total = sum(forces)
    r = fem.assemble_vector(R).array.reshape(-1, 2).sum(axis=0)   # d Pi_g / d(rigid translation)
    assert np.allclose(total, r, rtol=1e-12, atol=1e-12)
    for f, g in zip(forces, grounds):
        assert np.allclose(f, (f @ g.normal) * g.normal)          # along the plane's normal
        assert f @ g.normal < 0                                    # pressed: into the plane


def _pressed_strip(k, travel=0.2, degree=1):
    """A 20 mm strip whose base is driven `travel` mm beyond first contact with a plane over its top."""
    d = strip(length=20.0, width=10.0, size=2.0, degree=degree, contraction=0.0)
    d["cables"] = []
    d["pins"][0]["move"] = [0.0, travel]
    d["grounds"] = [{"name": "top", "point": [0.0, 20.0], "normal": [0.0, -1.0], "stiffness": k}]
    session = Session(d)
    result = session.solve(2)
    assert result.converged, result.status
    return session, result


@pytest.mark.parametrize("degree", [1, 2])
def test_ground_force_balances_the_pin_reaction(degree):
    session, result = _pressed_strip(10.0, degree=degree)
    F = np.asarray(result.grounds["top"]["force"])
    R = np.asarray(result.pins["base"]["reaction"])
    assert F[1] > 0.05                           # the strip pushes the plane up (+y, into it)
    assert np.allclose(R, F, atol=1e-8 * abs(F[1]) + 1e-12)   # pin pushes the body as hard as the plane does
    assert np.allclose(session.model.term("grounds", "top").force(), F, rtol=1e-14)   # the read-out is the term's


def test_ground_force_converges_as_the_penalty_stiffness_grows():
    ks = [1.0, 10.0, 100.0, 1000.0, 10000.0]
    forces = [_pressed_strip(k)[1].grounds["top"]["force"][1] for k in ks]
    print("\nground force vs penalty stiffness k [N/mm^3]:")
    for k, f in zip(ks, forces):
        print(f"  k = {k:8.0f}   F = {f:.8f} N")
    diffs = np.abs(np.diff(forces))
    ratios = diffs[1:] / diffs[:-1]
    print("  successive differences", diffs, "ratios", ratios)
    assert np.all(np.diff(forces) > 0)                    # stiffer plane, less penetration, more force
    assert np.all((ratios > 0.05) & (ratios < 0.2))       # error ~ 1/k: a tenfold k cuts it tenfold
    assert diffs[-1] / forces[-1] < 1e-3                  # converged to 0.1 %
