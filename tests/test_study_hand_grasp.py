"""studies/hand_grasp.py tiny: the three-finger hand (the paper's Fig. 10 in 2D) closes on the square,
holds it at twice its friction limit and loses it below; writes its JSON and both figures."""
import json

import numpy as np
import pytest
from _studies import load_study


@pytest.mark.slow
def test_hand_grasp_tiny_holds_the_square_above_mu_min_and_loses_it_below(tmp_path, picture):
    study = load_study("hand_grasp")
    res = study.run(shapes=("square",), mus=(0.6,), densities=(310.0, 930.0), out=tmp_path / "out",
                    figures=tmp_path / "fig", say=lambda *a, **k: None)
    (g,) = res["results"]
    assert g["close"]["converged"], g["close"]["status"]
    assert min(g["close"]["fingers"]["left"], g["close"]["fingers"]["right"]) > 0     # the outer fingers squeeze it
    held, lost = g["weighings"]
    assert held["held"] and held["margin"] > 2.0, held
    # W = mu_min sum N (the read-out's own normal force): the margin is mu / mu_min
    assert held["weight"] == pytest.approx(held["mu_min"] * g["close"]["normal_magnitude"], rel=1e-9)
    assert held["margin"] == pytest.approx(0.6 / held["mu_min"], rel=1e-9)
    f = np.asarray(held["friction_force"])          # on the body: the object's weight goes up the fingers
    assert abs(f[1]) <= 0.6 * held["normal_magnitude"] * (1 + 1e-6)                 # Coulomb's bound
    assert not lost["held"] and lost["status"] == "no equilibrium: object box is not held"
    assert lost["margin"] < 1.0
    assert res["agree_with_mu_min"] == res["weighings"] == 2
    saved = json.loads((tmp_path / "out" / "hand_grasp.json").read_text())
    assert saved["weighings"] == 2
    picture(tmp_path / "fig" / "hand_grasp.png", 400, 400)
    picture(tmp_path / "fig" / "hand_grasp_margin.png", 400, 200, min_colour=0.0005)
