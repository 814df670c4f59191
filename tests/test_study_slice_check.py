"""studies/slice_check.py on finger.toml: Debian's PrusaSlicer slices every part (manifold, one part, no
warning, the STL's volume), both mould halves print without support in the orientation written, and the
single-process 3MF slices on two extruders without support."""
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
    # the single-process print: one 3MF on two extruders, body and its three bones, no support needed
    (p,) = r["prints"]
    assert p["design"] == "finger" and p["manifold"] and r["prints_sliced"]
    assert p["volume"] == pytest.approx(p["volume_3mf"], rel=1e-3)
    a = p["plate"]
    assert a["returncode"] == 0 and not a["warnings"] and a["layers"] > 10
    assert len(a["filament_cm3"]) == 2 and min(a["filament_cm3"]) > 0          # both extruders print
    assert a["filament_cm3"][0] > a["filament_cm3"][1]                          # the body outweighs the bones
    assert a["support_sections"] == 0
