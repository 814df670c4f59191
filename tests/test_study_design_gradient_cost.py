"""studies/design_gradient_cost.py at a tiny size: the design gradient against one Newton solve."""
import pytest

from _studies import load_study


@pytest.mark.slow
def test_design_gradient_cost_tiny(tmp_path):
    res = load_study("design_gradient_cost").run(counts=(4, 40), repeats=1, out=tmp_path)
    assert (tmp_path / "design_gradient_cost.json").exists()
    rows = {r["variables"]: r for r in res["rows"]}
    assert set(rows) == {4, 40}
    for r in rows.values():
        assert r["solve_cold_s"] > 0 and r["gradient_s"] > 0
        assert r["gradient_over_cold_solve"] < 3.0, r       # the floor: at most 3 Newton solves, whatever n
