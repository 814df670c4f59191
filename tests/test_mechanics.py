"""The assembled energy, its derivatives and the static solver on small models."""
import numpy as np
import pytest

from _designs import strip, variant
from _taylor import hessian_error, taylor_rates
from skelfem import Session
from skelfem.mesh.points import interpolation_matrix


def _full_model_dict(degree):
    """Bones, a tendon, a taut ligament, a spring pin, a point load and a ground."""
    d = strip(length=40.0, size=2.5, degree=degree, bones=False)
    d["materials"]["hard"]["E"] = 50.0
    d["bones"] = [{"name": "b", "outline": [[3, 10], [7, 10], [7, 25], [3, 25]], "material": "hard"}]
    d["cables"].append({"name": "lig", "kind": "ligament", "path": [[2, 5], [4, 20], [2, 35]],
                        "stiffness": 2.0, "pretension": 1.0})
    d["pins"].append({"name": "side", "region": [[-1, 30], [0.5, 40]], "kind": "spring", "stiffness": 5.0})
    d["loads"] = [{"name": "push", "at": [5, 38], "force": [0.3, -0.2]}]
    d["grounds"] = [{"name": "wall", "point": [10.5, 0], "normal": [-1, 0], "stiffness": 10.0}]
    return d


@pytest.mark.parametrize("degree", [1, 2])
def test_taylor_remainders_of_total_energy_and_gradient(degree):
    """Pi(x + h d) - Pi(x) - h R.d = O(h^2) and R(x + h d) - R(x) - h J d = O(h^2), J = K + low-rank parts."""
    sc = Session(_full_model_dict(degree)).model
    sc.set_factor(1.0)
    rng = np.random.default_rng(3)
    x = sc.u.vector.copy()
    X = sc.V.tabulate_dof_coordinates()[:, :2]
    x.array[:] = 0.02 * rng.normal(size=x.array.shape)
    x.array[0::2] += 0.15 * X[:, 1] / 40.0 * 4  # push into the wall so the ground is active
    sc.apply_bcs(x)
    assert sc.admissible(x)
    assert any(t.cable.tension(x.array, t.rest_length) > 0 for t in sc.terms_in("cables"))
    assert sc.low_rank(x)                       # a taut cable: the rank-one parts take part in J d
    d = x.duplicate()
    d.array[:] = rng.normal(size=d.array.shape)
    d.array[sc.fixed] = 0.0
    for rates in taylor_rates(sc, x, d, [1e-2, 5e-3, 2.5e-3, 1.25e-3]):
        assert np.all(rates > 1.9), rates
    assert hessian_error(sc, x, d) < 1e-8         # the rank-one parts are ~1e-4 of J d here


def test_no_load_gives_zero_displacement(strip_design):
    s = Session(strip_design(contraction=0.0, size=3.0))
    report = s.solve(1).report
    assert report.converged
    assert report.newton_iterations == 0
    assert np.abs(s.model.u.x.array).max() == 0.0
    assert report.min_jacobian == pytest.approx(1.0)


def test_tendon_bends_strip_into_beam_theory_arc(strip_design):
    """Curvature of the mid-length neutral axis vs kappa = T d / (E' I), plane strain."""
    E, nu, t, w, d_off = 1.0, 0.3, 10.0, 10.0, 3.0
    s = Session(strip_design(length=100.0, width=w, size=1.0, degree=2, tendon_offset=d_off,
                      contraction=0.2, k=1.0, E=E, nu=nu, thickness=t))
    result = s.solve(1)
    assert result.converged
    sc = s.model
    ys = np.linspace(30.0, 70.0, 41)
    P = np.column_stack([np.full_like(ys, w / 2), ys])
    ux = (interpolation_matrix(sc.V, P) @ sc.u.x.array).reshape(-1, 2)[:, 0]
    kappa = 2.0 * np.polyfit(ys, ux, 2)[0]
    tendon = sc.term("cables", "flexor")
    T = tendon.cable.tension(sc.u.x.array, tendon.rest_length)
    assert T == result.cables["flexor"]["tension"]
    kappa_beam = T * d_off / (E / (1 - nu ** 2) * t * w ** 3 / 12)
    assert T > 0
    assert kappa == pytest.approx(kappa_beam, rel=0.03)


def test_failed_solve_reports_status_and_keeps_last_equilibrium(strip_design):
    d = variant(strip_design(size=3.0, contraction=3.0, k=20.0), **{"solver.max_iterations": 1})
    s = Session(d)
    s.solver.stepper.max_cuts = 1
    result = s.solve(1)
    assert not result.converged
    assert result.status == "max_iterations" == result.report.status
    assert np.abs(s.model.u.x.array).max() == 0.0   # the last accepted equilibrium (rest), not a half-step
    assert result.markers is None and result.cables is None   # no read-outs of a state that is no equilibrium


@pytest.mark.parametrize("kind", ["fixed", "spring"])
def test_pin_reactions_balance_the_applied_load(kind, strip_design):
    d = strip_design(size=3.0, contraction=0.0)
    d["pins"][0].update(kind=kind, stiffness=50.0)
    d["loads"] = [{"name": "tip", "at": [5, 59], "force": [0.02, -0.05]}]
    result = Session(d).solve(1)
    assert result.converged
    reaction = np.asarray(result.pins["base"]["reaction"])
    assert np.allclose(reaction + np.array([0.02, -0.05]), 0.0, atol=1e-8)


@pytest.mark.parametrize("kind", ["fixed", "spring"])
def test_moved_pin_translates_a_free_body_rigidly(kind, strip_design):
    d = strip_design(size=3.0, contraction=0.0)
    d["pins"][0].update(kind=kind, stiffness=50.0, move=[1.5, -0.5])
    s = Session(d)
    result = s.solve(2)
    assert result.converged
    u = s.model.u.x.array.reshape(-1, 2)
    assert np.allclose(u, [1.5, -0.5], atol=1e-7)
    assert np.allclose(result.pins["base"]["reaction"], 0.0, atol=1e-8)
