"""studies/friction_stability.py tiny: each family solves, the block slides below tan(theta) and sticks
above, strategies agree, and the outputs are written."""
import json
import math

import pytest
from _studies import load_study


@pytest.mark.slow
def test_friction_stability_tiny(tmp_path, picture):
    study = load_study("friction_stability")
    res = study.run(cases=("block on a slope", "pinch", "finger on a wall"), strategies=("energy", "curved"),
                    mus=(0.0, 1.0), stiffnesses=(100.0, 1e3), out=tmp_path / "out", figures=tmp_path / "fig",
                    progress=None)
    rows = {(r["case"], r["mu"], r["strategy"]): r for r in res["rows"]}
    assert all(r["converged"] for r in res["rows"]), [r["status"] for r in res["rows"]]
    # the spring pin: a block that slides stretches it by W (sin - 0 cos) / kp; one that sticks stays
    slid = 10.0 - rows[("block on a slope", 0.0, "energy")]["marker_x"]
    stuck = 10.0 - rows[("block on a slope", 1.0, "energy")]["marker_x"]
    W = 1e4 * 1e-9 * 9.81 * 20 * 5 * 10
    assert slid == pytest.approx(W * math.sin(math.radians(20.0)) / 1e-3, rel=0.02)
    assert abs(stuck) < 1e-2
    assert all(r["off_energy"] < res["agree_mm"] for r in res["rows"] if r["strategy"] == "curved")
    assert ("pinch", 0.0, "energy") not in rows                  # the pinch starts at mu = 0.25
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["strategies"]["energy"]["successes"] == summary["strategies"]["energy"]["cases"] == 5
    assert (tmp_path / "out" / "cases.csv").read_text().count("\n") == len(res["rows"]) + 1
    picture(tmp_path / "fig" / "friction_stability.png", 900, 300, min_ink=0.02)   # thin lines on white
