"""studies/in_hand_roll.py at small size: Soft IK turns the disk through contact, target after target."""
import json

import pytest

from _studies import load_study

pytestmark = pytest.mark.slow


def test_in_hand_roll_tiny(tmp_path):
    study = load_study("in_hand_roll")
    r = study.run(to=10.0, step=5.0, size=2.0, max_solves=20, out=tmp_path, figures=tmp_path)
    rows = r["rows"]
    assert [row["target_deg"] for row in rows] == [5.0, 10.0]
    assert all(row["status"] == "reached" for row in rows)
    turned = [-row["rotation_deg"] for row in rows]          # clockwise: the rim marker's arc
    assert 3.0 < turned[0] < turned[1] and turned[1] > 8.0
    assert r["min_distance"] > 0
    assert json.loads((tmp_path / "in_hand_roll.json").read_text())["rows"] == rows
    assert (tmp_path / "in_hand_roll.png").stat().st_size > 20_000
    assert (tmp_path / "in_hand_roll.gif").stat().st_size > 20_000
