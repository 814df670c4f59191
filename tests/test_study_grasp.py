"""studies/grasp.py tiny: the gripper closes, holds a light box with a clear margin and loses it below
mu_min; writes its JSON and both figures."""
import json

import pytest
from _studies import load_study


@pytest.mark.slow
def test_grasp_study_tiny_holds_above_mu_min_and_loses_below(tmp_path, picture):
    study = load_study("grasp")
    res = study.run(mus=(0.15, 0.9), densities=(620.0,), out=tmp_path / "out", figures=tmp_path / "fig")
    low, high = res["results"]
    for r in res["results"]:
        assert r["close"]["converged"], r["close"]["status"]
        assert r["close"]["normal_magnitude"] > 0.3           # the pads press the box (N)
    (w,) = high["weighings"]
    assert w["held"] and w["margin"] > 2.0
    assert w["friction_force"][1] + w["weight"] == pytest.approx(0.0, abs=0.02 * w["weight"])  # carried by friction
    (w,) = low["weighings"]
    assert not w["held"] and w["status"] == "no equilibrium: object box is not held" and w["margin"] < 1.0
    assert res["agree_with_mu_min"] == res["weighings"] == 2
    saved = json.loads((tmp_path / "out" / "grasp.json").read_text())
    assert saved["weighings"] == 2
    picture(tmp_path / "fig" / "grasp.png", 500, 500)
    picture(tmp_path / "fig" / "grasp_margin.png", 400, 300, min_colour=0.0005)   # two dots and the shading
