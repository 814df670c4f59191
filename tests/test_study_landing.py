"""studies/landing.py tiny: a box above a 20-degree slope lands and sticks, above a 35-degree one it is not
held, and landing.json holds the rows the guide's table is built from."""
import json
import math

from _studies import load_study


def test_landing_study_tiny(tmp_path):
    study = load_study("landing")
    res = study.run(cases=[("slope", 20.0, 0.05, 0.5, 1), ("slope", 35.0, 0.05, 0.5, 1)], out=tmp_path,
                    progress=None)
    held, lost = res["rows"]
    assert held["held"] and held["along_slope"] < 0.05 * math.tan(math.radians(20.0)) + 1e-3
    assert not lost["held"] and lost["status"] == "no equilibrium: object box is not held"
    assert held["newton_iterations"] > 0 and held["dofs"] > 0 and held["time"] > 0
    assert json.loads((tmp_path / "landing.json").read_text())["rows"] == res["rows"]
