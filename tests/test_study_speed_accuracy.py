"""studies/speed_accuracy.py on coarse strips: P2 beats P1, P1 locks at nu = 0.499, Richardson, outputs."""

import numpy as np
import pytest
from _studies import load_study

pytestmark = pytest.mark.slow


def _load():
    return load_study("speed_accuracy")


@pytest.fixture(scope="module")
def study():
    return _load()


@pytest.fixture(scope="module")
def tiny(study, tmp_path_factory):
    out = tmp_path_factory.mktemp("speed_accuracy")
    grid = {1: (4.0, 2.0), 2: (4.0, 2.0, 1.0)}
    return study.run(("strip", "strip_nu0.499"), {"strip": grid, "strip_nu0.499": grid}, out, progress=None), out


def _case(res, problem, degree, size, bones="elastic"):
    return next(r for r in res["cases"]
                if (r["problem"], r["degree"], r["size"], r["bones"]) == (problem, degree, size, bones))


def test_p2_is_more_accurate_than_p1_at_equal_size(tiny):
    res, _ = tiny
    for problem in ("strip", "strip_nu0.499"):
        for h in (4.0, 2.0):
            p1, p2 = _case(res, problem, 1, h), _case(res, problem, 2, h)
            assert p1["converged"] and p2["converged"]
            assert p2["error"] < p1["error"] / 10, (problem, h, p1["error"], p2["error"])


def test_p1_triangles_lock_for_nearly_incompressible_silicone(tiny):
    res, _ = tiny
    p1 = _case(res, "strip_nu0.499", 1, 2.0)
    tip = res["summary"]["strip_nu0.499"]["reference"]["displacement"]
    assert p1["error"] > 0.3 * tip                 # P1 bends far too little
    assert p1["kappa_ratio"] < 0.5                 # against beam theory too
    assert _case(res, "strip", 1, 2.0)["kappa_ratio"] > 0.8


def test_reference_agrees_with_beam_theory_and_has_an_error_estimate(tiny):
    res, _ = tiny
    for problem in ("strip", "strip_nu0.499"):
        s = res["summary"][problem]
        ref = _case(res, problem, 2, s["reference"]["size"])
        assert ref["kappa_ratio"] == pytest.approx(1.0, abs=0.02)
        assert 0 < s["reference_error"]["error"] < 1e-3
        front = s["pareto"]
        assert front and front[0]["time"] == min(r["time"] for r in res["cases"]
                                                 if r["problem"] == problem and np.isfinite(r["error"]))
        assert all(a["error"] > b["error"] for a, b in zip(front, front[1:]))


def test_rigid_bones_are_compared_against_the_elastic_reference(tiny):
    """The strips' cap as a rigid bone: every mesh solved again; its error is against the elastic finest P2,
    within the cap's own strain (E_cap = 1000 E) of the elastic case's on the same mesh."""
    res, _ = tiny
    for problem in ("strip", "strip_nu0.499"):
        s = res["summary"][problem]
        assert not _case(res, problem, 2, s["reference"]["size"], "rigid")["reference"]
        for p, h in ((1, 4.0), (1, 2.0), (2, 4.0), (2, 2.0)):
            e, r = _case(res, problem, p, h), _case(res, problem, p, h, "rigid")
            assert r["converged"] and r["dofs"] == e["dofs"] and r["time"] > 0
            moved = np.hypot(r["x"] - e["x"], r["y"] - e["y"])
            assert 0 < moved < 0.01 * e["displacement"], (problem, p, h, moved)
            assert abs(r["error"] - e["error"]) <= moved + 1e-12
        assert set(s["rigid_models"]) == {1, 2}


def test_outputs_written(tiny, picture):
    _, out = tiny
    for name in ("cases.csv", "summary.json"):
        assert (out / name).stat().st_size > 200
    picture(out / "speed_accuracy.png", 1000, 450)
    assert not list(out.glob(".*"))


def test_richardson_recovers_order_and_error(study):
    h = np.array([4.0, 2.0, 1.0])
    x_star = np.array([3.0, -1.0])
    pts = [x_star + 0.2 * hh ** 2 * np.array([1.0, 0.5]) for hh in h]
    r = study.richardson(h, pts)
    assert r["order"] == pytest.approx(2.0, abs=1e-6)
    assert r["error"] == pytest.approx(np.linalg.norm(pts[-1] - x_star), rel=1e-6)
    assert np.allclose(r["extrapolated"], x_star)
    scatter = study.richardson(h, [x_star, x_star + 0.1, x_star])          # no asymptotic range
    assert scatter["order"] is None and scatter["error"] == pytest.approx(np.hypot(0.1, 0.1))


def test_fit_power(study):
    h = np.array([4.0, 2.0, 1.0])
    fit = study.fit_power(h, 0.3 * h ** 1.5)
    assert fit["C"] == pytest.approx(0.3) and fit["r"] == pytest.approx(1.5)
    assert study.fit_power([1.0], [1.0]) is None
