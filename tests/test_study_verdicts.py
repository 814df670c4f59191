"""studies/verdicts.py tiny: the gripper closed by 2 mm loses its box when weighed, with the verdict as the box
falls past its own size (52 Newton iterations before Term.verdict), and verdicts.json keeps each label."""
import json

import pytest
from _studies import load_study


@pytest.mark.slow
def test_verdicts_study_tiny(tmp_path):
    study = load_study("verdicts")
    study.run(cases=(), label="before", out=tmp_path)                 # another label, kept beside
    res = study.run(cases=("gripper_2mm_mu0.8_lost",), label="after", out=tmp_path)
    (row,) = res["after"]
    assert row["verdict"] == row["expected"] == "lost" and row["status"] == "no equilibrium: object box is not held"
    assert row["close"]["status"] == "converged" and row["dofs"] > 0 and row["time"] > 0
    assert row["newton_iterations"] <= 20, row["newton_iterations"]
    assert json.loads((tmp_path / "verdicts.json").read_text()).keys() == {"before", "after"}
