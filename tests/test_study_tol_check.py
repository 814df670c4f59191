"""studies/tol_check.py on one design and one tolerance: the command meets it against a finer reference."""
import pytest
from _studies import load_study

pytestmark = pytest.mark.slow


def test_tol_check_tiny(tmp_path):
    study = load_study("tol_check")
    rows = study.run(designs=("finger_bones",), tols=(2.0,), ref_size=2.0, out=tmp_path)
    assert len(rows) == 1
    r = rows[0]
    assert r["design"] == "finger_bones" and r["tol"] == 2.0 and r["degree"] in (1, 2)
    assert r["met"] and r["error_vs_reference"] <= 2.0
    assert 0 < r["estimated_error"] <= 2.0 / 2                 # the safety factor 2 of skelfem.accuracy
    assert r["dofs"] < r["reference_dofs"] and 0 < r["time"] and 0 < r["reference_time"]
    assert (tmp_path / "finger_bones" / "tol_2" / "result.json").exists()
    assert not (tmp_path / "finger_bones" / "tol_2" / "deformed.png").exists()     # --no-picture


def test_tol_check_main_writes_its_table(tmp_path, capsys):
    study = load_study("tol_check")
    assert study.main(["--designs", "finger_bones", "--tols", "3", "--ref-size", "2.5", "--out", str(tmp_path)]) == 0
    lines = (tmp_path / "tol_check.csv").read_text().splitlines()
    assert lines[0].startswith("design,tol,degree,size,estimated_error,error_vs_reference,met") and len(lines) == 2
    assert "1/1 tolerances met" in capsys.readouterr().out
