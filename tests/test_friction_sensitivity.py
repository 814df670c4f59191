"""Sensitivities through frictional contact: the Jacobian of the lagged-friction equilibrium.

Friction's normal forces N (and, on objects, the anchor edges' tangents)
are lagged: Newton holds them while it solves and the solver iterates them
to their fixed point N = N(x). The equilibrium is therefore
G(x) = grad Pi(x; N(x)) = 0, and its Jacobian is J = H + C, H the Hessian
with N held and C the coupling through N(x)
(skelfem.analysis.sensitivity.Linearization.solve_many). Checked here
against central differences of G itself (the lags measured at the perturbed
states, the stick/slip branch and the anchors held), on a box resting on
the body by friction and on the body resting on a ground; and a marker on
a grasped object as a Soft IK target.
"""
import math

import numpy as np
import pytest

from skelfem import Session
from skelfem.analysis.sensitivity import Linearization

from test_friction import block
from test_objects import _base, _box


def _box_on_block():
    d = _base([_box(2, 10.3, 8, 13.3)], contact={"dhat": 0.2, "friction": 0.5}, markers={"b": [5.0, 12.0]})
    d["materials"]["pla"]["density"] = 5000.0
    return d


def _jacobian_errors(session, lin, seed=0):
    """max |J v - (G(x + e v) - G(x - e v)) / 2e| / max |...| over the free rows of the deformable body,
    for J = H + C and for H alone (v random on those rows)."""
    m = session.model
    x0 = m.u.x.array.copy()
    rows = np.ones(len(x0), bool)
    rows[m.fixed] = False
    for t in m.terms_in("objects"):
        if hasattr(t, "dofs"):
            rows[t.dofs.ravel()] = False          # rigid objects' rows hold their rigid projection
    v = np.random.default_rng(seed).standard_normal(len(x0)) * rows
    vv, Av = m.u.vector.duplicate(), m.u.vector.duplicate()
    vv.array_w[:] = v
    session.solver.A.mult(vv, Av)
    Hv = Av.array_r.copy()
    Jv = Hv + lin._coupling(v)

    def G(x):
        saved = [t.lags() for t in lin.lagged]
        try:
            for t in lin.lagged:
                t.set_lags(t.lags_at(x))
            m.u.x.array[:] = x
            return m.full_gradient()
        finally:
            for t, lags in zip(lin.lagged, saved):
                t.set_lags(lags)
            m.u.x.array[:] = x0
    e = 1e-7
    fd = (G(x0 + e * v) - G(x0 - e * v)) / (2 * e)
    scale = np.abs(fd[rows]).max()
    return np.abs(fd - Jv)[rows].max() / scale, np.abs(fd - Hv)[rows].max() / scale


def test_the_jacobian_through_object_friction_matches_central_differences():
    with Session(_box_on_block()) as s:
        assert s.solve().converged
        s.set({"gravity.acceleration": [2.0, -9.81]})         # pushed sideways, held by friction
        r = s.solve()
        assert r.converged, r.status
        assert r.to_dict()["contacts"][0]["friction_force"][0] > 0.0
        lin = Linearization(s.model, s.solver)
        assert [type(t).__name__ for t in lin.lagged] == ["ObjectFriction"]
        exact, lagged_only = _jacobian_errors(s, lin)
    assert exact < 1e-6, exact
    assert lagged_only > 1e-2, lagged_only             # the coupling through N(x) matters


def test_the_jacobian_through_ground_friction_matches_central_differences():
    th = math.degrees(math.atan(0.8 * 0.5))
    with Session(block(mu=0.5, theta=th, kp=1e-4, size=2.5, steps=1)) as s:
        r = s.solve()
        assert r.converged, r.status
        lin = Linearization(s.model, s.solver)
        assert [type(t).__name__ for t in lin.lagged] == ["GroundFriction"]
        exact, lagged_only = _jacobian_errors(s, lin)
    assert exact < 1e-6, exact
    assert lagged_only > 1e-2, lagged_only


def test_without_friction_nothing_is_lagged_and_h_is_the_jacobian():
    d = _box_on_block()
    d["contact"] = {"dhat": 0.2}
    with Session(d) as s:
        assert s.solve().converged
        assert Linearization(s.model, s.solver).lagged == []


@pytest.mark.slow
def test_soft_ik_moves_a_grasped_object_to_a_target():
    """'Move the box here': the gripper holds the box by friction under gravity; a target for a marker on
    the box, reached by other contractions along the same path, is reached by Soft IK from the grasp."""
    import tomllib

    from skelfem.analysis.control import SoftIK
    from skelfem.design import parse_design
    from conftest import GEOMETRY
    with open(GEOMETRY / "gripper.toml", "rb") as f:
        d = tomllib.load(f)
    d["markers"]["box_centre"] = [50.0, 2.0]
    d["mesh"]["size"] = 3.0
    flexors = ["cables.left_flexor.contraction", "cables.right_flexor.contraction"]

    def grasp(then=None):
        s = Session(parse_design(d, "gripper.toml"))
        s.set({flexors[0]: 4.0, flexors[1]: 4.0})
        assert s.solve().converged
        s.set({"gravity.acceleration": [0.0, -9.81], "materials.box_pla.density": 620.0})
        r = s.solve()
        if then:
            s.set(then)
            r = s.solve()
        assert r.converged, r.status
        return s, np.array(r.markers["box_centre"]["position"])
    s, goal = grasp({flexors[0]: 4.5, flexors[1]: 3.7})
    s.close()
    s, start = grasp()
    with s:
        assert np.linalg.norm(goal - start) > 1.0
        res = SoftIK(s, "box_centre", max_solves=20).solve(goal)
        assert res.reached and res.error < 0.2 * np.linalg.norm(goal - start), res
        assert res.contractions == pytest.approx([4.5, 3.7], abs=0.1)
        assert s.model.term("objects", "box").failure(s.model) is None        # still held


def _same(a, b) -> bool:
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, np.ndarray):
        return np.array_equal(a, b)
    return a == b


def test_a_refused_ik_trial_leaves_no_friction_history():
    """Soft IK tries contractions and may refuse them: the trial's slips (moved anchors, slip states) must
    not stay behind, or the next trial starts from a history no accepted state had."""
    from skelfem.analysis.control import SoftIK
    d = _box_on_block()
    d["cables"] = [{"name": "flexor", "kind": "tendon", "path": [[8.5, 0], [8.5, 9.5]], "stiffness": 2.0}]
    with Session(d) as s:
        assert s.solve().converged
        s.set({"gravity.acceleration": [1.0, -9.81]})       # well inside mu: 2.0 m/s^2 sideways nearly loses it
        assert s.solve().converged
        ik = SoftIK(s, "b")
        before = s.model.history()
        x = s.model.u.x.array.copy()
        assert ik.trial(np.array([0.05]))                     # the block bends: the box slides on it
        assert not _same(s.model.history(), before)         # the trial moved anchors
        ik.restore()
        assert _same(s.model.history(), before)
        assert np.array_equal(s.model.u.x.array, x)
        assert ik.trial(np.array([0.05]))
        ik.accept(np.array([0.05]))
        after = s.model.history()
        ik.restore()
        assert _same(s.model.history(), after)             # accepted: its history is the new one


def _ik_errors(s, marker: str, h: float) -> float:
    """max |J - central differences| / max |J| of a marker's Soft IK Jacobian, the differences taken by
    whole warm solves from the accepted state (its friction history put back after each)."""
    from skelfem.analysis.control import SoftIK
    ik = SoftIK(s, marker)
    J = ik.jacobian()
    fd = np.zeros_like(J)
    for i in range(J.shape[1]):
        for sign in (1.0, -1.0):
            u = ik.u.copy()
            u[i] += sign * h
            assert ik.trial(u)
            fd[:, i] += sign * ik.position() / (2 * h)
            ik.restore()
    return float(np.abs(fd - J).max() / np.abs(J).max())


def test_ik_through_a_sticking_pinch_matches_central_differences():
    """Two soft prongs pinch a box under gravity; a tendon in one prong lifts it. Loaded along a path that
    ends with a small release, every contact node sticks; the Jacobian of the box's marker with respect
    to the contraction (implicit function theorem at the frictional state) matches whole-solve central
    differences to 1e-5."""
    from test_objects import _pinch_design
    d = _pinch_design(1.0)
    d["cables"] = [{"name": "flexor", "kind": "tendon", "path": [[4.5, 36], [4.5, 1]], "stiffness": 0.05}]
    d["markers"] = {"box": [20.0, 12.0]}
    d["solver"] = {"rtol": 1e-12}
    with Session(d) as s:
        assert s.solve().converged
        for u in (0.3, 0.28):                         # the release leaves every node inside its sticking zone
            s.set({"cables.flexor.contraction": u})
            r = s.solve()
            assert r.converged, r.status
        (pair,) = r.contacts
        assert pair["sticking"] == 1.0
        assert _ik_errors(s, "box", 1e-3) < 1e-5


@pytest.mark.slow
def test_ik_through_the_grippers_sticking_grasp_matches_central_differences():
    """The gripper holds its box by friction; gravity eased from 9.81 to 9 and 8.5 m/s^2 leaves every
    contact node sticking (at 9: 97 % of the normal force; the box's contacts hold from where they
    formed as the fingers closed on it). Both flexors' columns of the box marker's Jacobian match whole-solve central
    differences to 1e-5 (h = 1e-4 mm: at 1e-3 mm some nodes near their limit slip)."""
    import tomllib

    from skelfem.design import parse_design
    from conftest import GEOMETRY
    with open(GEOMETRY / "gripper.toml", "rb") as f:
        d = tomllib.load(f)
    d["markers"]["box_centre"] = [50.0, 2.0]
    d["mesh"]["size"] = 3.0
    d["solver"] = {"rtol": 1e-12}
    with Session(parse_design(d, "gripper.toml")) as s:
        s.set({"cables.left_flexor.contraction": 4.0, "cables.right_flexor.contraction": 4.0})
        assert s.solve().converged
        for g in (9.81, 9.0, 8.5):
            s.set({"gravity.acceleration": [0.0, -g], "materials.box_pla.density": 620.0})
            r = s.solve()
            assert r.converged, r.status
        (pair,) = r.contacts
        assert pair["sticking"] == 1.0
        assert _ik_errors(s, "box_centre", 1e-4) < 1e-5


def test_the_exact_solve_returns_its_start_when_it_already_solves_the_system():
    """A right-hand side along which the coupling vanishes is solved by GMRES's start: SciPy 1.10's GMRES
    returned NaN from there (seen on a 3D cube carried in time)."""
    from skelfem.analysis.sensitivity import _gmres
    b = np.array([1.0, -2.0, 3.0])
    assert np.array_equal(_gmres(lambda v: v, b, 1e-12, restart=3, maxiter=5, what="test"), b)
    y = _gmres(lambda v: v + np.array([0.0, 0.0, 0.5]) * v, b, 1e-12, restart=3, maxiter=5, what="test")
    assert np.allclose(y, [1.0, -2.0, 2.0])
