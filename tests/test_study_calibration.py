"""studies/calibration.py at a tiny size: every part runs, the same-mesh fit is exact, files are written."""
import json

import numpy as np
import pytest
from _studies import load_study


@pytest.mark.slow
def test_calibration_study_tiny(tmp_path, picture):
    study = load_study("calibration")
    out, figs = tmp_path / "out", tmp_path / "figs"
    argv = ["--size-data", "3.0", "--size-fit", "4.0", "--rows", "5", "--seeds", "3", "--bench-size", "4.0",
            "--out", str(out), "--figures", str(figs)]
    assert study.main(argv) == 0
    res = json.loads((out / "calibration.json").read_text())
    exact = res["same_mesh_noise_free"]["parameters"]
    assert all(abs(p["bias"]) < 1e-6 for p in exact.values())             # the method itself: no bias
    joint = res["fits"]["all"]
    assert set(joint["parameters"]) == set(study.FIT) and joint["converged"]
    assert all(p["bias"] is not None for p in joint["parameters"].values())
    assert res["fits"]["push"]["parameters"]["materials.ecoflex.E"]["value"] > 0
    cov = json.loads((out / "coverage.json").read_text())
    assert cov["seeds"] == 3 and 0.0 <= cov["inside_fraction"] <= 1.0 and len(cov["spread_over_std"]) == 2
    bench = json.loads((out / "bench.json").read_text())
    assert set(bench["per_iteration"]) == {"2", "20"} and bench["ratio"] > 0
    picture(figs / "calibration.png", 1000, 300)
    data = res["data"]
    assert np.isnan(np.array(data["cables.flexor.tension"], float)[-1]) or data["cables.flexor.tension"][-1] is None
