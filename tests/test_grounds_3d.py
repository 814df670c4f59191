"""Grounds in 3D: the nodal rule on the boundary's triangles (weights integrate the area; the penalty's
derivatives against central differences at P1 and P2), a pinned block pressed onto a floor (the floor's
force is the pins' reaction), and a cube on a floor with friction that sticks iff tan theta <= mu."""
import math

import numpy as np
import pytest
import ufl
from dolfinx import fem, mesh as dmesh
from mpi4py import MPI

from skelfem import Session
from skelfem.terms.grounds import nodal_ds

from _designs import land_and_tilt

G = 9.81
RHO = 1250.0
SIDE = 4.0


@pytest.mark.parametrize("degree", [1, 2])
def test_the_nodal_rule_integrates_the_boundary_and_sits_on_its_nodes(degree):
    """int 1 ds and int x ds over a box's surface (exact for linear integrands); the nodal weights are
    positive, sum to the area and sit on every boundary node."""
    m = dmesh.create_box(MPI.COMM_WORLD, [[0.0, 0.0, 0.0], [2.0, 3.0, 5.0]], [2, 3, 2])
    V = fem.VectorFunctionSpace(m, ("Lagrange", degree))
    u = fem.Function(V)
    ds = nodal_ds(u)
    X = ufl.SpatialCoordinate(m)
    area = fem.assemble_scalar(fem.form(1.0 * ds))
    assert area == pytest.approx(2 * (2 * 3 + 3 * 5 + 2 * 5), rel=1e-12)
    # int x ds: faces x=0 (0), x=2 (2 * 15), the four others (mean x = 1) of area 6+6+10+10
    assert fem.assemble_scalar(fem.form(X[0] * ds)) == pytest.approx(2 * 15 + 1 * 32, rel=1e-12)
    # the nodal weights: positive, summing to the area, on every boundary node
    v = ufl.TestFunction(V)
    w = fem.petsc.assemble_vector(fem.form(ufl.inner(ufl.as_vector([1.0, 0.0, 0.0]), v) * ds)).array[0::3]
    assert w.min() >= 0.0 and w.sum() == pytest.approx(area, rel=1e-12)
    on = w > 0
    assert on.sum() == len(np.unique(fem.locate_dofs_topological(
        V, 2, dmesh.locate_entities_boundary(m, 2, lambda x: np.full(x.shape[1], True)))))


@pytest.mark.parametrize("degree", [1, 2])
def test_3d_ground_gradient_and_hessian_match_central_differences(degree):
    from types import SimpleNamespace

    from skelfem.mesh.geometry import TaggedMesh
    from skelfem.terms import Context
    from skelfem.terms.grounds import Ground
    m = dmesh.create_box(MPI.COMM_WORLD, [[0.0, 0.0, 0.0], [4.0, 3.0, 2.0]], [3, 2, 2])
    V = fem.VectorFunctionSpace(m, ("Lagrange", degree))
    u = fem.Function(V)
    ctx = Context(None, TaggedMesh(m, None, {}), V, u, fem.Constant(m, 1.0))
    n = np.array([0.2, 1.0, 0.1]) / np.linalg.norm([0.2, 1.0, 0.1])
    g = Ground(ctx, SimpleNamespace(name="floor", point=np.array([0.0, 0.4, 0.0]), normal=n, stiffness=5.0))
    E = g.ufl_energy(ctx)
    v, du = ufl.TestFunction(V), ufl.TrialFunction(V)
    fE, fR, fJ = fem.form(E), fem.form(ufl.derivative(E, u, v)), fem.form(ufl.derivative(ufl.derivative(E, u, v), u, du))
    rng = np.random.default_rng(3)
    u0 = 0.2 * rng.normal(size=u.x.array.shape)
    X = V.tabulate_dof_coordinates()
    gaps = ((X + u0.reshape(-1, 3)) - g.point) @ n
    assert (gaps < 0).sum() >= 4 and np.abs(gaps).min() > 1e-4

    def grad(a):
        u.x.array[:] = a
        return fem.petsc.assemble_vector(fR).array.copy()

    def energy(a):
        u.x.array[:] = a
        return fem.assemble_scalar(fE)
    g0 = grad(u0)
    h = 1e-6
    d = rng.normal(size=u0.shape)
    fd = (energy(u0 + h * d) - energy(u0 - h * d)) / (2 * h)
    assert g0 @ d == pytest.approx(fd, rel=1e-6)
    u.x.array[:] = u0
    J = fem.petsc.assemble_matrix(fJ)
    J.assemble()
    Jd = J.createVecLeft()
    dv = J.createVecRight()
    dv.array[:] = d
    J.mult(dv, Jd)
    fdJ = (grad(u0 + h * d) - grad(u0 - h * d)) / (2 * h)
    assert np.allclose(Jd.array, fdJ, rtol=1e-5, atol=1e-8 * np.abs(fdJ).max())


def _cube_on_floor(gravity, mu=0.5, **extra):
    d = {"format": 1, "name": "floor3d", "dim": 3, "mesh": {"size": 2.0, "degree": 1},
         "materials": {"soft": {"E": 1.0, "nu": 0.3, "density": 1000.0},
                       "pla": {"E": 1000.0, "nu": 0.35, "density": RHO}},
         "body": {"solids": [{"box": {"min": [0, 0, 0], "max": [4, 4, 4]}}], "material": "soft"},
         "pins": [{"name": "base", "region": [[-1, -1, -1], [5, 1e-6, 5]], "kind": "fixed"}],
         "objects": [{"name": "cube", "solids": [{"box": {"min": [10, 0.05, 0], "max": [10 + SIDE, 0.05 + SIDE, SIDE]}}],
                      "material": "pla"}],
         "grounds": [{"name": "floor", "point": [0, 0, 0], "normal": [0, 1, 0], "stiffness": 100.0, "friction": mu}],
         "gravity": {"acceleration": gravity}}
    d.update(extra)
    return d


@pytest.mark.slow
def test_a_pinned_block_pressed_onto_a_3d_floor_pushes_it_with_the_pins_reaction():
    d = {"format": 1, "name": "press3d", "dim": 3, "mesh": {"size": 1.5, "degree": 2},
         "materials": {"soft": {"E": 0.5, "nu": 0.45}},
         "body": {"solids": [{"box": {"min": [0, 0.0, 0], "max": [6, 4, 5]}}], "material": "soft"},
         "pins": [{"name": "top", "region": [[-1, 3.999, -1], [7, 5, 6]], "kind": "fixed", "move": [0, -0.3, 0]}],
         "grounds": [{"name": "floor", "point": [0, -0.1, 0], "normal": [0, 1, 0], "stiffness": 50.0}]}
    with Session(d) as s:
        r = s.solve()
        assert r.converged, r.status
        out = r.to_dict()
    F = np.array(out["grounds"]["floor"]["force"])
    R = np.array(out["pins"]["top"]["reaction"])
    assert F[1] < -0.1                                              # pressed: into the floor
    assert np.allclose(F, R, rtol=1e-6, atol=1e-9 * abs(F[1]))      # the pins push the block onto the floor
    assert abs(F[0]) < 1e-9 and abs(F[2]) < 1e-9


@pytest.mark.slow
@pytest.mark.parametrize("theta, held", [(26.2, True), (27.0, False)])
def test_a_cube_on_a_3d_floor_sticks_iff_tan_theta_below_mu(theta, held):
    """mu = 0.5 (atan 0.5 = 26.57 deg) on the floor: gravity tilts after the cube has landed; at 26.2 deg
    the floor's friction carries W sin theta, at 27.0 deg nothing holds the cube."""
    th = math.radians(theta)
    landed, r = land_and_tilt(_cube_on_floor([0.0, -G, 0.0]), theta, G)
    W = RHO * 1e-9 * G * SIDE ** 3
    floor = landed.to_dict()["grounds"]["floor"]
    assert floor["force"] == pytest.approx([0.0, -W, 0.0], rel=1e-5, abs=1e-6 * W)   # the cube's weight
    if not held:
        assert r.status == "no equilibrium: object cube is not held"
        return
    assert r.converged, r.status
    out = r.to_dict()
    pair = next(p for p in out["contacts"] if p["between"] == ["floor", "cube"])
    assert pair["normal_force"][1] == pytest.approx(-W * math.cos(th), rel=1e-3)
    assert pair["friction_force"][0] == pytest.approx(W * math.sin(th), rel=1e-3)
    assert abs(pair["friction_force"][2]) < 1e-3 * W
    assert abs(out["objects"]["cube"]["displacement"][0]) < 1e-3
