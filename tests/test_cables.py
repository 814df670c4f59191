"""Cable geometry (via points) and finite-difference checks of the cable derivatives."""
from types import SimpleNamespace

import numpy as np
import pytest
from dolfinx import fem
from dolfinx import mesh as dmesh
from mpi4py import MPI

from skelfem.terms.cables import Cable, via_points
from skelfem.mesh.points import interpolation_matrix


def _spec(path, kind="tendon", k=20.0):
    return SimpleNamespace(name="c", kind=kind, path=np.asarray(path, float), stiffness=k,
                           contraction=1.0 if kind == "tendon" else 0.0, pretension=0.0)


@pytest.fixture(scope="module")
def rect():
    return dmesh.create_rectangle(MPI.COMM_WORLD, [[0.0, 0.0], [20.0, 100.0]], [4, 20])


def test_via_points_sit_on_every_crossed_edge(rect):
    path = np.array([[3.0, 0.0], [3.0, 60.0], [9.0, 96.0]])
    X = via_points(rect, path)
    # the sketch's vertices are kept, in order
    for p in path:
        assert np.min(np.linalg.norm(X - p, axis=1)) < 1e-12
    # consecutive via points lie in one common cell: the midpoint's cell contains both
    x = rect.geometry.x[:, :2]
    nodes = rect.geometry.dofmap.array.reshape(-1, 3)
    from skelfem.mesh.points import locate_cells
    cells = locate_cells(rect, 0.5 * (X[1:] + X[:-1]))
    for a, b, c in zip(X[:-1], X[1:], cells):
        v = x[nodes[c]]
        T = np.column_stack([v[1] - v[0], v[2] - v[0]])
        for p in (a, b):
            lam = np.linalg.solve(T, p - v[0])
            assert min(1 - lam.sum(), *lam) > -1e-9
    # every crossing is counted: the vertical part crosses 12 horizontal and 12 diagonal edges
    assert len(X) > 20
    assert np.isclose(np.linalg.norm(np.diff(X, axis=0), axis=1).sum(),
                      np.linalg.norm(np.diff(path, axis=0), axis=1).sum())


def test_interpolation_matrix_reproduces_polynomials(rect):
    for degree in (1, 2):
        V = fem.VectorFunctionSpace(rect, ("Lagrange", degree))
        u = fem.Function(V)
        f = (lambda x: np.vstack([x[0] ** degree + 0.3 * x[1], x[0] * x[1] ** (degree - 1)]))
        u.interpolate(f)
        P = np.random.default_rng(1).random((40, 2)) * [20, 100]
        S = interpolation_matrix(V, P)
        assert np.allclose((S @ u.x.array).reshape(-1, 2), f(P.T).T, atol=1e-10)


@pytest.mark.parametrize("degree", [1, 2])
def test_cable_gradient_and_hessian_match_finite_differences(rect, degree):
    V = fem.VectorFunctionSpace(rect, ("Lagrange", degree))
    cable = Cable.build(V, _spec([[3, 0], [3, 50], [8, 96]]))
    rng = np.random.default_rng(0)
    u = rng.normal(size=V.dofmap.index_map.size_local * 2) * 0.3
    L = cable.L0 - 4.0                                   # taut
    g, H = cable.gradient(u, L), cable.hessian(u, L)
    h = 1e-5
    g_fd = np.empty_like(g)
    H_fd = np.empty_like(H)
    for j, dof in enumerate(cable.dofs):               # test-only loop over the cable's DOFs
        e = np.zeros_like(u)
        e[dof] = h
        g_fd[j] = (cable.energy(u + e, L) - cable.energy(u - e, L)) / (2 * h)
        H_fd[:, j] = (cable.gradient(u + e, L) - cable.gradient(u - e, L)) / (2 * h)
    assert np.linalg.norm(g - g_fd) / np.linalg.norm(g) < 1e-6
    assert np.linalg.norm(H - H_fd) / np.linalg.norm(H) < 1e-6
    # dropping the curvature term would be caught
    gg = cable.k * np.outer(cable.B.T @ _unit(cable, u), cable.B.T @ _unit(cable, u))
    assert np.linalg.norm(H - gg) / np.linalg.norm(H) > 1e-3


def _unit(cable, u):
    d = cable.segments(u)
    return (d / np.linalg.norm(d, axis=1)[:, None]).ravel()


def test_slack_cable_stores_nothing(rect):
    V = fem.VectorFunctionSpace(rect, ("Lagrange", 1))
    cable = Cable.build(V, _spec([[3, 0], [3, 96]], kind="ligament"))
    u = np.zeros(V.dofmap.index_map.size_local * 2)
    L = cable.L0 + 0.5
    assert cable.energy(u, L) == 0.0 and cable.tension(u, L) == 0.0
    assert not np.any(cable.gradient(u, L)) and not np.any(cable.hessian(u, L))
    # rigid translation keeps the length; a stretch of the strip lengthens the cable
    assert np.isclose(cable.length(np.tile([1.0, 2.0], len(u) // 2)), cable.L0)
    stretch = np.zeros_like(u).reshape(-1, 2)
    stretch[:, 1] = 0.01 * V.tabulate_dof_coordinates()[:, 1]
    assert np.isclose(cable.length(stretch.ravel()), 1.01 * cable.L0)


def test_rest_length_follows_contraction_and_pretension(rect):
    V = fem.VectorFunctionSpace(rect, ("Lagrange", 1))
    tendon = Cable.build(V, _spec([[3, 0], [3, 96]]))
    assert np.isclose(tendon.rest_length(1.0), 96.0 - 1.0)
    assert np.isclose(tendon.rest_length(0.5), 96.0 - 0.5)
    lig = Cable.build(V, SimpleNamespace(name="l", kind="ligament", path=np.array([[3, 0], [3, 96]]),
                                         stiffness=1.0, contraction=0.0, pretension=2.0))
    assert np.isclose(lig.rest_length(1.0), 94.0)


def test_p2_cables_follow_the_bent_cells_not_their_chords(rect, monkeypatch):
    """With P2 a straight sketch bends into a parabola inside each cell: the cable's length is the bent
    curve's (four chords per cell: error / 16), not one chord's per cell, which cuts its corners."""
    import skelfem.terms.cables as cables
    a, lam = 2.0, 6.0                                  # x = X + a sin(Y / lam): a wavy line
    V = fem.VectorFunctionSpace(rect, ("Lagrange", 2))
    u = fem.Function(V)
    u.interpolate(lambda x: np.vstack([a * np.sin(x[1] / lam), 0.0 * x[1]]))
    Y = np.linspace(0.0, 90.0, 200001)
    exact = np.trapz(np.sqrt(1.0 + (a / lam * np.cos(Y / lam)) ** 2), Y)
    errors = {}
    for pieces in (1, 4):
        monkeypatch.setitem(cables.PIECES, 2, pieces)
        cable = Cable.build(V, _spec([[3, 0], [3, 90]]))
        errors[pieces] = abs(cable.length(u.x.array) - exact)
    assert errors[1] > 2e-4 * exact                    # one chord per cell: 0.04 mm short over 92 mm
    assert errors[4] < errors[1] / 10.0
    assert len(via_points(rect, np.array([[3.0, 0.0], [3.0, 90.0]]), 4)) == \
        4 * (len(via_points(rect, np.array([[3.0, 0.0], [3.0, 90.0]]))) - 1) + 1
