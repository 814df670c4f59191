"""studies/grasp3d.py at one weight: the 3D gripper closes on the sphere (gravity off), then holds it at
0.9 of mu sum N; the contact carries exactly the sphere's weight, within Coulomb's bound, clear of it."""
import json

import numpy as np
import pytest
from _studies import load_study
from conftest import ROOT


@pytest.mark.slow
def test_grasp3d_study_holds_the_sphere_below_its_friction_limit(tmp_path, picture):
    study = load_study("grasp3d")
    # at 5 mm (2,430 DOFs, the sphere's contact on a few triangles a finger): 20 s instead of 137 s at the
    # design's 2.5 mm; every check below is an equilibrium or Coulomb identity, true at any mesh
    res = study.run(mu=0.8, ratios=(0.9,), size=5.0, out=tmp_path / "out", figures=tmp_path / "fig")
    close = res["close"]
    assert close["converged"], close["status"]
    assert close["normal_magnitude"] > 0.1 and close["min_distance"] > 0       # squeezed, not pierced
    (w,) = res["weighings"]
    assert w["held"], w["status"]
    assert w["margin"] == pytest.approx(1 / 0.9) and res["agree_with_mu_min"] == 1
    # forces on the body (the pair's first name): the sphere's weight, all of it, straight down
    f = np.asarray(w["friction_force"]) + np.asarray(w["normal_force"])
    assert f == pytest.approx([0.0, -w["weight"], 0.0], abs=2e-3 * w["weight"])
    assert np.linalg.norm(w["friction_force"]) <= 0.8 * w["normal_magnitude"] * (1 + 1e-9)   # Coulomb
    assert w["min_distance"] > 0
    assert json.loads((tmp_path / "out" / "grasp3d.json").read_text())["weighed"] == 1
    picture(tmp_path / "fig" / "grasp3d.png", 400, 400)


def test_the_committed_grasp3d_study_holds_the_sphere_below_its_limit_on_the_designs_mesh():
    """The study's committed output (the design's 2.5 mm mesh, ratios 0.5, 0.9, 1.1): closed with the
    sphere squeezed and clear, held at every ratio below 1, each weight carried by the contact within
    Coulomb's bound (the run above checks the same on a coarse mesh)."""
    out = json.loads((ROOT / "studies" / "output" / "grasp3d" / "grasp3d.json").read_text())
    assert out["design"] == "geometry/gripper3d.toml" and out["mu"] == 0.8
    assert out["close"]["converged"] and out["close"]["normal_magnitude"] > 0.1 and out["close"]["min_distance"] > 0
    below = [w for w in out["weighings"] if w["ratio"] <= 1.0]
    assert [w["ratio"] for w in below] == [0.5, 0.9]
    for w in out["weighings"]:
        assert w["margin"] == pytest.approx(1 / w["ratio"])
        f = np.asarray(w["friction_force"]) + np.asarray(w["normal_force"])
        if w["held"]:
            assert f == pytest.approx([0.0, -w["weight"], 0.0], abs=2e-3 * w["weight"])
            assert np.linalg.norm(w["friction_force"]) <= out["mu"] * w["normal_magnitude"] * (1 + 1e-9)
            assert w["min_distance"] > 0
    assert all(w["held"] for w in below) and out["agree_with_mu_min"] >= len(below)
