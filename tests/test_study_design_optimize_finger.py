"""studies/design_optimize_finger.py at a tiny size: gradient and gradient-free runs of one task."""
import pytest

from _studies import load_study


@pytest.mark.slow
def test_design_optimize_finger_tiny(tmp_path):
    res = load_study("design_optimize_finger").run(max_gradient_free=8, out=tmp_path, max_evaluations=4)
    assert (tmp_path / "design_optimize_finger.json").exists() and (tmp_path / "optimized.toml").exists()
    g, f = res["gradient"], res["gradient_free"]
    assert g["objective"] < res["start"] and g["improvement"] > 0.3       # two evaluations of both contractions
    assert g["solves"] == 4 and g["evaluations"] == 2
    assert min(g["clearances"].values()) >= -1e-4 and g["fabricate"]["ok"], g
    assert abs(g["fresh"] - g["objective"]) <= g["fresh_error_estimate"]     # the moved mesh against a fresh one
    assert f["evaluations"] <= 8 and f["solves"] == 2 * f["evaluations"]
    assert f["solves_to_reach_gradient_optimum"] is None      # 8 evaluations of COBYLA do not get there
