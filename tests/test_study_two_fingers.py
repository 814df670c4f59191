"""studies/two_fingers.py at small size: the fingers press harder as they curl, each stays in balance."""
import json

from _studies import load_study


def test_two_fingers_tiny(tmp_path):
    study = load_study("two_fingers")
    r = study.run(contraction=5.0, steps=2, size=4.0, out=tmp_path, figures=tmp_path)
    rows = r["rows"]
    assert [row["touching"] for row in rows] == [True, True]
    assert rows[1]["normal"] > rows[0]["normal"] > 0
    assert r["max_balance"] < 1e-6 * max(1.0, r["max_reaction"])
    assert json.loads((tmp_path / "two_fingers.json").read_text())["rows"] == rows
    assert (tmp_path / "two_fingers.png").stat().st_size > 10_000
    assert (tmp_path / "two_fingers_forces.png").stat().st_size > 5_000
