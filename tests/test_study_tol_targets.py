"""studies/tol_targets.py at a tiny size: --tol on markers and on a tension, each met against a finer reference."""
import pytest
from _studies import load_study

pytestmark = pytest.mark.slow


def test_tol_targets_tiny(tmp_path):
    study = load_study("tol_targets")
    res = study.run("thumb", ("cables.flexor.contraction=4", "mesh.size=2"), h_ref=0.8, out=tmp_path,
                    tols=("1.0",), tension_share=0.05)
    ref = res["reference"]
    assert ref["size"] == 0.8 and ref["dofs"] > 0 and ref["tension"] > 0
    assert 0 <= ref["tip_scatter"] < 0.05 and 0 <= ref["tension_scatter"] < 0.05 * ref["tension"]
    marker, tension = res["rows"]
    assert marker["tol"] == "1.0" and tension["tol"].startswith("cables.flexor.tension=")
    for row in (marker, tension):
        assert row["exit"] == 0 and row["met"] and 0 < row["dofs"] < ref["dofs"]
        assert row["tip_error"] >= 0 and row["tension_error"] >= 0     # both read on each row (not NaN)
    assert marker["tip_error"] <= 1.0 and 0 < marker["estimate"] <= 0.5        # met: twice the estimate within it
    T_tol = float(tension["tol"].split("=")[1])
    assert T_tol == pytest.approx(0.05 * ref["tension"], abs=1e-4)
    assert tension["tension_error"] <= T_tol
    bound = tension["targets"]["cables.flexor.tension"]
    assert bound["tol"] == T_tol and 0 < bound["estimated_error"] <= T_tol
