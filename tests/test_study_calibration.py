"""studies/calibration.py at a tiny size: every part runs, the same-mesh fit is exact, files are written."""
import json

import numpy as np
import pytest
from _studies import load_study


@pytest.mark.slow
def test_calibration_study_tiny(tmp_path, picture):
    study = load_study("calibration")
    out, figs = tmp_path / "out", tmp_path / "figs"
    # one bench timing per parameter count (the study keeps the minimum of five): the test reads only
    # that both counts were timed
    argv = ["--size-data", "4.0", "--size-fit", "5.0", "--rows", "4", "--seeds", "2", "--bench-size", "5.0",
            "--bench-repeats", "1", "--out", str(out), "--figures", str(figs)]
    assert study.main(argv) == 0
    res = json.loads((out / "calibration.json").read_text())
    exact = res["same_mesh_noise_free"]["parameters"]
    assert all(abs(p["bias"]) < 1e-6 for p in exact.values())             # the method itself: no bias
    joint = res["fits"]["all"]
    assert set(joint["parameters"]) == set(study.FIT) and joint["converged"]
    assert all(p["bias"] is not None for p in joint["parameters"].values())
    assert res["fits"]["push"]["parameters"]["materials.ecoflex.E"]["value"] > 0
    cov = json.loads((out / "coverage.json").read_text())
    assert cov["seeds"] == 2 and 0.0 <= cov["inside_fraction"] <= 1.0 and len(cov["spread_over_std"]) == 2
    bench = json.loads((out / "bench.json").read_text())
    assert set(bench["per_iteration"]) == {"2", "20"} and bench["ratio"] > 0
    picture(figs / "calibration.png", 1000, 300)
    data = res["data"]
    assert np.isnan(np.array(data["cables.flexor.tension"], float)[-1]) or data["cables.flexor.tension"][-1] is None


def test_model_error_coverage_counts_and_merges():
    """The coverage numbers of the model-error study (the calibration guide quotes them) from its runs:
    inside counts per parameter, bias against the mean std, and runs over disjoint seeds joined."""
    study = load_study("calibration")

    def part(seeds, values, width):
        runs = [{"seed": s, "values": v, "std": [width / 2, width / 2], "ci95": [[v[0] - width, v[0] + width],
                                                                                [v[1] - width, v[1] + width]],
                 "max_over_sigma": 2.0, "corrections": 1, "iterations": 3, "converged": True}
                for s, v in zip(seeds, values)]
        return {"keys": ["a", "b"], "true": [1.0, 2.0], "modes": {"inflate": {"runs": runs, "seconds": 1.0}}}
    a = part([0, 1], [[1.1, 2.0], [1.5, 2.0]], 0.2)        # a: the first inside, the second not
    b = part([2], [[1.0, 2.3]], 0.2)                       # b: outside in the second parameter
    m = study.merge([b, a])["modes"]["inflate"]
    assert m["seeds"] == 3 and m["inside"] == [2, 2] and [r["seed"] for r in m["runs"]] == [0, 1, 2]
    assert m["mean_bias"] == pytest.approx([0.2, 0.1]) and m["bias_over_std"] == pytest.approx([2.0, 1.0])
