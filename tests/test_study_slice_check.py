"""studies/slice_check.py on finger.toml: Debian's PrusaSlicer slices every part (manifold, one part, no
warning, the STL's volume), and both mould halves print without support in the orientation written."""
import pytest

from _studies import load_study

pytestmark = pytest.mark.slow


def test_slice_check_of_the_finger(tmp_path):
    r = load_study("slice_check").run(designs=("finger",), out=tmp_path)
    rows = r["rows"]
    assert {row["part"] for row in rows} == {"bone_proximal", "bone_middle", "bone_distal", "mould_bottom", "mould_top"}
    for row in rows:
        assert row["returncode"] == 0 and not row["warnings"], row
        assert row["manifold"] and row["parts"] == 1, row
        assert row["volume"] == pytest.approx(row["stl_volume"], rel=1e-4), row
        assert row["layers"] > 10
    assert r["all_sliced"] and r["moulds_without_support"]
    top = next(row for row in rows if row["part"] == "mould_top")
    assert top["down"] == "+z" and top["support_sections"] == 0       # flipped: its pegs no longer hang in air
    assert (tmp_path / "slice_check.json").exists()
