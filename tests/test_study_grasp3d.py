"""studies/grasp3d.py at a coarse mesh: the 3D gripper closes on the sphere, holds it at half its friction
limit and loses it at 1.5 times; writes its JSON and picture."""
import json

import pytest
from _studies import load_study


@pytest.mark.slow
def test_grasp3d_study_coarse_holds_below_the_friction_limit_and_loses_above(tmp_path, picture):
    study = load_study("grasp3d")
    res = study.run(mu=0.8, ratios=(0.5, 1.5), contraction=3.0, size=4.0, out=tmp_path / "out",
                    figures=tmp_path / "fig")
    assert res["close"]["converged"], res["close"]["status"]
    assert res["close"]["normal_magnitude"] > 0.05 and res["close"]["min_distance"] > 0
    held, lost = res["weighings"]
    assert held["held"] and held["margin"] == pytest.approx(2.0)
    assert held["friction_force"][1] < -0.3 * held["weight"]     # on the body: friction carries the sphere
    assert held["min_distance"] > 0
    assert not lost["held"] and lost["status"] == "no equilibrium: object ball is not held"
    assert res["agree_with_mu_min"] == res["weighed"] == 2
    assert json.loads((tmp_path / "out" / "grasp3d.json").read_text())["weighed"] == 2
    picture(tmp_path / "fig" / "grasp3d.png", 500, 500)
