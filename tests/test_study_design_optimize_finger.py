"""studies/design_optimize_finger.py at a tiny size: gradient and gradient-free runs of one task."""
import pytest

from _studies import load_study


@pytest.mark.slow
def test_design_optimize_finger_tiny(tmp_path):
    res = load_study("design_optimize_finger").run(max_gradient_free=8, out=tmp_path)
    assert (tmp_path / "design_optimize_finger.json").exists()
    g, f = res["gradient"], res["gradient_free"]
    assert g["objective"] < res["start"] and g["improvement"] > 0.1
    assert f["solves"] >= 8                                   # every evaluation solves each target
    assert f["solves_to_reach_gradient_optimum"] is None      # 8 evaluations of Nelder-Mead do not get there
