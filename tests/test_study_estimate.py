"""studies/estimate_effectivity.py, estimate_cost.py and goal_oriented.py, tiny (tol_targets.py: its own file)."""
import json

import pytest
from _studies import load_study

pytestmark = pytest.mark.slow


def test_estimate_effectivity_tiny(tmp_path, monkeypatch):
    study = load_study("estimate_effectivity")
    monkeypatch.setattr(study, "CASES", {"tiny": (lambda: study.strip(size=5.0, contraction=1.0), 2)})
    assert study.main(["--cases", "tiny", "--out", str(tmp_path)]) == 0
    d = json.loads((tmp_path / "estimate_effectivity.json").read_text())
    rows = {r["observable"]: r for r in d["rows"]}
    assert rows["cables.flexor.tension"]["estimate"] > 0 and rows["markers.tip.x"]["true_error"] > 0
    assert not rows["pins.base.reaction.x"]["measurable"]            # round-off: never counted
    assert d["summary"]["cost"]["tiny"]["ratio"] > 0 and d["summary"]["rows"] == len(d["rows"])


def test_estimate_effectivity_sweep_tiny(tmp_path, monkeypatch):
    study = load_study("estimate_effectivity")
    build = lambda h, p: study.strip(size=h, degree=p, contraction=1.0)     # noqa: E731
    monkeypatch.setattr(study, "SWEEP", {"tiny": (build, (8.0, 6.0), (6.0, 4.0))})
    assert study.main(["--sweep", "tiny", "--out", str(tmp_path)]) == 0
    rows = json.loads((tmp_path / "estimate_effectivity_h.json").read_text())
    assert {r["h"] for r in rows} == {8.0, 6.0} and all(r["estimate"] > 0 for r in rows)
    assert all((r["effectivity"] is None) == (not r["measurable"]) for r in rows)


def test_estimate_cost_tiny(tmp_path):
    study = load_study("estimate_cost")
    assert study.main(["--cases", "strip:8", "--out", str(tmp_path)]) == 0
    (row,) = json.loads((tmp_path / "estimate_cost.json").read_text())
    assert row["case"] == "strip:8" and row["dofs"] > 0 and row["richer_dofs"] > row["dofs"]
    assert row["solve_cpu_s"] > 0 and row["ratio_cpu"] > 0 and row["status"] == "converged"


def test_goal_oriented_tiny(tmp_path, monkeypatch):
    study = load_study("goal_oriented")
    monkeypatch.setattr(study, "CASES", {"tiny": (study.strip2d, 8.0, 2.0, 2, (2.0, 1.5), 8.0)})
    assert study.main(["--cases", "tiny", "--rounds", "1", "--out", str(tmp_path)]) == 0
    (res,) = json.loads((tmp_path / "goal_oriented.json").read_text())
    assert len(res["uniform"]) == 2 and len(res["goal"]) >= 3
    assert all(r["error"] >= 0 and r["dofs"] > 0 for r in res["uniform"] + res["goal"])
    assert study.dofs_to_reach([{"dofs": 100, "error": 1.0}, {"dofs": 400, "error": 0.01}], 0.1) == pytest.approx(200)


# tol_targets.py: its checks (rows of a marker --tol and a tension --tol, exit 0, errors >= 0) are asserted on
# the run of tests/test_study_tol_targets.py, which checks more of the same rows; a second run here cost 25 s
