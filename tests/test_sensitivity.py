"""dx*/du and dO/du at a converged equilibrium of finger4 against central finite differences."""
import numpy as np
import pytest

from skelfem.analysis.sensitivity import Linearization, contractions, marker_objective, set_contractions, stretch, tendons
from skelfem.fem.newton import NewtonSolver

U0 = np.array([6.0, 3.0, 2.0, 4.0])          # every tendon taut here (checked below)
TARGET = np.array([0.0, 80.0])


@pytest.fixture(scope="module")
def finger(finger4):
    """finger4 at U0, solved tightly: (model, solver, the equilibrium x0)."""
    model, solver = finger4.model, finger4.solver
    solver.rtol, solver.atol = 0.0, 1e-11        # tight equilibria for the differences
    set_contractions(model, U0)
    assert finger4.solve().converged
    return model, solver, model.u.vector.copy()


def _tip(model):
    return model.term("markers").positions(model.u.x.array)[0].copy()


def _objective(model, solver, x0, u):
    """O(u) and y(u) at the equilibrium reached from x0 (a warm start at load factor 1)."""
    x0.copy(model.u.vector)
    set_contractions(model, u)
    assert solver.solve(1).converged
    return marker_objective(model, 0, TARGET)[0], _tip(model)


def _finite_differences(model, solver, x0, h=1e-3):
    dO, dy = [], []
    for c in range(len(U0)):
        e = np.zeros(len(U0))
        e[c] = h
        (Op, yp), (Om, ym) = _objective(model, solver, x0, U0 + e), _objective(model, solver, x0, U0 - e)
        dO.append((Op - Om) / (2 * h))
        dy.append((yp - ym) / (2 * h))
    x0.copy(model.u.vector)
    set_contractions(model, U0)
    assert solver.solve(1).converged
    return np.array(dO), np.array(dy).T


def test_tendons_are_the_controls_and_taut(finger):
    model, _, _ = finger
    assert [t.name for t in tendons(model)] == [
        "flexor_distal", "flexor_middle", "extensor_distal", "extensor_middle"]
    assert all(t.kind == "tendon" for t in tendons(model))
    assert len(model.terms_in("cables")) > len(tendons(model))      # the ligaments are no controls
    assert np.allclose(contractions(model), U0)
    u = model.u.x.array
    s = [stretch(t, u) for t in tendons(model)]
    assert min(s) > 1e-2


def test_forward_and_adjoint_gradients_match_central_differences(finger):
    model, solver, x0 = finger
    lin = Linearization(model, solver)
    O, dO_dx = marker_objective(model, 0, TARGET)
    adjoint, forward = lin.adjoint(dO_dx), lin.forward(dO_dx)
    J_adj, J_fwd = lin.marker_jacobian(0), lin.marker_jacobian(0, mode="forward")
    lin.destroy()
    fd_O, fd_J = _finite_differences(model, solver, x0)
    rel = lambda a, b: np.linalg.norm(a - b) / np.linalg.norm(b)   # noqa: E731
    assert O > 1.0 and np.linalg.norm(fd_O) > 1.0                   # a non-trivial objective
    assert rel(adjoint, fd_O) < 1e-5
    assert rel(forward, fd_O) < 1e-5
    assert rel(J_adj, fd_J) < 1e-5 and rel(J_fwd, fd_J) < 1e-5
    assert np.allclose(adjoint, forward, rtol=1e-10, atol=1e-10 * np.abs(forward).max())


def test_state_sensitivity_vanishes_on_pins_and_follows_the_flexor(finger):
    model, solver, _ = finger
    lin = Linearization(model, solver)
    dxs = lin.state_sensitivities()
    J = lin.marker_jacobian(0)
    lin.destroy()
    for dx in dxs:
        assert np.all(dx.array_r[model.fixed[:len(dx.array_r)]] == 0.0)
        assert np.linalg.norm(dx.array_r) > 0
    # pulling a flexor moves the tip towards -x, pulling an extensor towards +x
    assert J[0, 0] < 0 and J[0, 1] < 0 and J[0, 2] > 0 and J[0, 3] > 0


def test_one_numeric_factorisation_serves_every_solve_and_the_analysis_is_reused(finger):
    from petsc4py import PETSc
    model, solver, _ = finger
    PETSc.Log.begin()
    numeric = [PETSc.Log.Event(n) for n in ("MatLUFactorNum", "MatCholFctrNum")]     # LU or LDL^T
    symbolic = [PETSc.Log.Event(n) for n in ("MatLUFactorSym", "MatCholFctrSym")]

    def counts():
        return (sum(e.getPerfInfo()["count"] for e in numeric), sum(e.getPerfInfo()["count"] for e in symbolic))
    n0, s0 = counts()
    lin = Linearization(model, solver)
    _, dO_dx = marker_objective(model, 0, TARGET)
    lin.adjoint(dO_dx), lin.forward(dO_dx), lin.marker_jacobian(0), lin.marker_jacobian(0, mode="forward")
    lin.destroy()
    assert counts() == (n0 + 1, s0)          # 12 solves, one refactorisation, no new analysis
    own_solver = NewtonSolver(model)         # another matrix and factorisation of the same H
    own = Linearization(model, own_solver)
    J_own = own.marker_jacobian(0)
    own.destroy()
    own_solver.destroy()
    lin = Linearization(model, solver)
    assert np.allclose(J_own, lin.marker_jacobian(0), rtol=1e-10, atol=1e-12)
    lin.destroy()


def test_needs_the_contractions_fully_applied(finger):
    model, solver, _ = finger
    model.set_factor(0.5)
    try:
        with pytest.raises(ValueError, match="load factor"):
            Linearization(model, solver)
    finally:
        model.set_factor(1.0)


def test_unactuated_finger_has_a_taut_branch_jacobian(finger):
    """At rest every tendon sits at the kink s = 0; the taut branch gives J != 0 (IK can start)."""
    model, solver, x0 = finger
    saved = model.u.vector.copy()
    model.u.x.array[:] = 0.0
    set_contractions(model, np.zeros(4))
    model.set_factor(1.0)
    lin = Linearization(model, solver)
    J = lin.marker_jacobian(0)
    assert sorted(lin.kinked) == list(range(len(tendons(model))))
    lin.destroy()
    # one-sided difference for the flexor pair pulled together (both stay taut)
    h = 1e-3
    set_contractions(model, [h, h, 0.0, 0.0])
    assert solver.solve(1).converged
    dy = (_tip(model) - np.array([10.0, 99.0])) / h
    assert np.linalg.norm(J[:, 0] + J[:, 1] - dy) < 2e-3 * np.linalg.norm(dy)   # O(h) remainder
    saved.copy(model.u.vector)
    set_contractions(model, U0)
    assert solver.solve(1).converged
