"""studies/edit_memory.py at a few edits: it runs, solves every edit and reports the growth."""
from _studies import load_study


def test_edit_memory_study_small(tmp_path):
    res = load_study("edit_memory").main(["--edits", "6", "--every", "3", "--out", str(tmp_path)])
    assert [r["edits"] for r in res["rows"]] == [3, 6]
    assert abs(res["growth_mb"]) < 50 and (tmp_path / "edit_memory.json").exists()
