"""dx*/du and dO/du at a converged equilibrium of finger4 against central finite differences."""
from pathlib import Path

import numpy as np
import pytest

from skelfem.design import load_design
from skelfem.geometry import mesh_design
from skelfem.scene import Scene
from skelfem.sensitivity import (Linearization, contractions, marker_objective, set_contractions, stretch,
                                 tendon_indices)
from skelfem.solver import NewtonSolver

ROOT = Path(__file__).resolve().parents[1]
U0 = np.array([6.0, 3.0, 2.0, 4.0])          # every tendon taut here (checked below)
TARGET = np.array([0.0, 80.0])


@pytest.fixture(scope="module")
def finger():
    design = load_design(ROOT / "geometry" / "finger4.toml", ["mesh.size=3"])
    scene = Scene(design, mesh_design(design))
    solver = NewtonSolver(scene, design.solver)
    solver.rtol, solver.atol = 0.0, 1e-11        # tight equilibria for the differences
    set_contractions(scene, U0)
    assert solver.solve(design.solver.steps).converged
    return scene, solver, scene.u.vector.copy()


def _objective(scene, solver, x0, u):
    """O(u) and y(u) at the equilibrium reached from x0 (a warm start at load factor 1)."""
    x0.copy(scene.u.vector)
    set_contractions(scene, u)
    assert solver.solve(1).converged
    return marker_objective(scene, 0, TARGET)[0], scene.marker_positions()[0].copy()


def _finite_differences(scene, solver, x0, h=1e-3):
    dO, dy = [], []
    for c in range(len(U0)):
        e = np.zeros(len(U0))
        e[c] = h
        (Op, yp), (Om, ym) = _objective(scene, solver, x0, U0 + e), _objective(scene, solver, x0, U0 - e)
        dO.append((Op - Om) / (2 * h))
        dy.append((yp - ym) / (2 * h))
    x0.copy(scene.u.vector)
    set_contractions(scene, U0)
    assert solver.solve(1).converged
    return np.array(dO), np.array(dy).T


def test_tendons_are_the_controls_and_taut(finger):
    scene, _, _ = finger
    assert [scene.cables[i].name for i in tendon_indices(scene)] == [
        "flexor_distal", "flexor_middle", "extensor_distal", "extensor_middle"]
    assert np.allclose(contractions(scene), U0)
    u = scene.u.x.array
    s = [stretch(scene.cables[i], u, scene.cables[i].rest_length(1.0)) for i in tendon_indices(scene)]
    assert min(s) > 1e-2


def test_forward_and_adjoint_gradients_match_central_differences(finger):
    scene, solver, x0 = finger
    lin = Linearization(scene, solver)
    O, dO_dx = marker_objective(scene, 0, TARGET)
    adjoint, forward = lin.adjoint(dO_dx), lin.forward(dO_dx)
    J_adj, J_fwd = lin.marker_jacobian(0), lin.marker_jacobian(0, mode="forward")
    lin.destroy()
    fd_O, fd_J = _finite_differences(scene, solver, x0)
    rel = lambda a, b: np.linalg.norm(a - b) / np.linalg.norm(b)   # noqa: E731
    assert O > 1.0 and np.linalg.norm(fd_O) > 1.0                   # a non-trivial objective
    assert rel(adjoint, fd_O) < 1e-5
    assert rel(forward, fd_O) < 1e-5
    assert rel(J_adj, fd_J) < 1e-5 and rel(J_fwd, fd_J) < 1e-5
    assert np.allclose(adjoint, forward, rtol=1e-10, atol=1e-10 * np.abs(forward).max())


def test_state_sensitivity_vanishes_on_pins_and_follows_the_flexor(finger):
    scene, solver, _ = finger
    lin = Linearization(scene, solver)
    dxs = lin.state_sensitivities()
    J = lin.marker_jacobian(0)
    lin.destroy()
    for dx in dxs:
        assert np.all(dx.array_r[scene.fixed[:len(dx.array_r)]] == 0.0)
        assert np.linalg.norm(dx.array_r) > 0
    # pulling a flexor moves the tip towards -x, pulling an extensor towards +x
    assert J[0, 0] < 0 and J[0, 1] < 0 and J[0, 2] > 0 and J[0, 3] > 0


def test_one_numeric_factorisation_serves_every_solve_and_the_analysis_is_reused(finger):
    from petsc4py import PETSc
    scene, solver, _ = finger
    PETSc.Log.begin()
    numeric = [PETSc.Log.Event(n) for n in ("MatLUFactorNum", "MatCholFctrNum")]     # LU or LDL^T
    symbolic = [PETSc.Log.Event(n) for n in ("MatLUFactorSym", "MatCholFctrSym")]

    def counts():
        return (sum(e.getPerfInfo()["count"] for e in numeric), sum(e.getPerfInfo()["count"] for e in symbolic))
    n0, s0 = counts()
    lin = Linearization(scene, solver)
    _, dO_dx = marker_objective(scene, 0, TARGET)
    lin.adjoint(dO_dx), lin.forward(dO_dx), lin.marker_jacobian(0), lin.marker_jacobian(0, mode="forward")
    lin.destroy()
    assert counts() == (n0 + 1, s0)          # 12 solves, one refactorisation, no new analysis
    own = Linearization(scene)               # without the solver: its own matrix and factorisation
    J_own = own.marker_jacobian(0)
    own.destroy()
    lin = Linearization(scene, solver)
    assert np.allclose(J_own, lin.marker_jacobian(0), rtol=1e-10, atol=1e-12)
    lin.destroy()


def test_needs_the_contractions_fully_applied(finger):
    scene, solver, _ = finger
    scene.set_factor(0.5)
    try:
        with pytest.raises(ValueError, match="load factor"):
            Linearization(scene, solver)
    finally:
        scene.set_factor(1.0)


def test_unactuated_finger_has_a_taut_branch_jacobian(finger):
    """At rest every tendon sits at the kink s = 0; the taut branch gives J != 0 (IK can start)."""
    scene, solver, x0 = finger
    saved = scene.u.vector.copy()
    scene.u.x.array[:] = 0.0
    set_contractions(scene, np.zeros(4))
    scene.set_factor(1.0)
    lin = Linearization(scene, solver)
    J = lin.marker_jacobian(0)
    assert sorted(lin.kinked) == tendon_indices(scene)
    lin.destroy()
    # one-sided difference for the flexor pair pulled together (both stay taut)
    h = 1e-3
    set_contractions(scene, [h, h, 0.0, 0.0])
    assert solver.solve(1).converged
    dy = (scene.marker_positions()[0] - np.array([10.0, 99.0])) / h
    assert np.linalg.norm(J[:, 0] + J[:, 1] - dy) < 2e-3 * np.linalg.norm(dy)   # O(h) remainder
    saved.copy(scene.u.vector)
    set_contractions(scene, U0)
    assert solver.solve(1).converged
