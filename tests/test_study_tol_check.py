"""studies/tol_check.py on one design and one tolerance: the command meets it against a finer reference."""
import json
from pathlib import Path

import pytest
from _studies import load_study

pytestmark = pytest.mark.slow


def test_tol_check_tiny_and_its_table(tmp_path, capsys):
    study = load_study("tol_check")
    tol = 2.0
    rows = study.run(designs=("thumb",), tols=(tol,), ref_size=0.7, out=tmp_path)
    assert len(rows) == 1
    r = rows[0]
    assert r["design"] == "thumb" and r["tol"] == tol and r["degree"] == 2 and r["meshes"] >= 3
    assert r["reported_met"] and r["met"] and r["error_vs_reference"] <= tol
    assert 0 < r["estimated_error"] <= tol / 2                 # met: twice the estimate within the tolerance
    assert r["effectivity"] == pytest.approx(r["estimated_error"] / r["error_vs_reference"])
    assert r["dofs"] < r["reference_dofs"] and 0 < r["time"] and 0 < r["reference_time"]
    assert 0 <= r["reference_uncertainty"] < r["estimated_error"]       # the reference's twin: its own scatter
    assert r["measurable"] == (r["error_vs_reference"] > 2 * r["reference_uncertainty"])
    levels = json.loads((tmp_path / "thumb" / "tol_2" / "result.json").read_text())["accuracy"]["levels"]
    assert levels[-1]["twin"] and levels[-1]["scatter"] >= 0 and r["size"] == levels[-1]["size"]
    assert r["bones"] == "rigid" and 0 < r["bones_difference"] <= 0.1 * tol / 2   # PLA in silicone: rigid
    assert not (tmp_path / "thumb" / "tol_2" / "deformed.png").exists()     # --no-picture
    again = study.run(designs=("thumb",), tols=(tol,), ref_size=0.7, out=tmp_path, reuse=True)[0]
    assert again["reference_time"] == r["reference_time"] and again["reference_dofs"] == r["reference_dofs"]
    # the command line: the same reference read back, the table written
    capsys.readouterr()
    assert study.main(["--designs", "thumb", "--tols", "2", "--ref-size", "0.7", "--out", str(tmp_path),
                       "--reuse-references"]) == 0
    lines = (tmp_path / "tol_check.csv").read_text().splitlines()
    assert lines[0].startswith("design,tol,degree,size,estimated_error,error_vs_reference,effectivity") and len(lines) == 2
    assert "1/1 tolerances met" in capsys.readouterr().out


def test_tol_check_adaptive_runs_the_command_with_adaptive(tmp_path, capsys):
    study = load_study("tol_check")
    assert study.main(["--designs", "thumb", "--tols", "2", "--ref-size", "0.7", "--out", str(tmp_path),
                       "--adaptive"]) == 0
    lines = (tmp_path / "tol_check_adaptive.csv").read_text().splitlines()
    assert lines[0].endswith(",method") and lines[1].endswith(",adaptive") and len(lines) == 2
    assert not (tmp_path / "tol_check.csv").exists()
    a = json.loads((tmp_path / "thumb" / "tol_2_adaptive" / "result.json").read_text())["accuracy"]
    assert a["adaptive"] and a["met"] and "1/1 tolerances met" in capsys.readouterr().out


def test_a_3d_reference_is_extrapolated_from_three_meshes(tmp_path):
    """3D: P2 at 2, sqrt 2 and 1 x h_ref, the markers extrapolated by Richardson (sizes measured by DOFs)."""
    import numpy as np
    study = load_study("tol_check")
    study.solve_reference("post3d", 2.0, tmp_path)
    r = json.loads((tmp_path / "result.json").read_text())
    ref = r["reference"]
    assert ref["graded"]                                       # at the clamped edges, as the ladder is
    dofs = ref["extrapolated_from"]
    assert len(dofs) == 3 and dofs[0] < dofs[1] < dofs[2] == r["dofs"] and r["degree"] == 2
    assert 0.5 <= ref["rate"] <= 2.0 and ref["estimate"] > 0
    tip = r["markers"]["tip"]
    assert np.allclose(np.asarray(tip["position"]) - tip["reference"], tip["displacement"])
    moved = np.linalg.norm(np.asarray(tip["position"]) - ref["finest"][0])   # extrapolated from the finest
    assert moved == pytest.approx(ref["estimate"], rel=1e-9) and moved > 0      # by its own estimate


def test_a_failed_tol_run_is_a_row_that_says_why_not_a_crash(tmp_path, monkeypatch, capsys):
    """A --tol run whose solve fails (exit 2, result.json with converged: false) is reported as failed: no
    error against the reference (its state is no equilibrium), not met, and the reason; other exits raise."""
    import subprocess
    study = load_study("tol_check")
    ref = {"dofs": 1000, "markers": {"tip": {"position": [0.0, 0.0]}}, "reference": {"scatter": 1e-4},
           "timings": {"total": 1.0}}
    monkeypatch.setattr(study, "_reference", lambda design, out, h, reuse: (ref, 1.0))
    failed = {"converged": False, "status": "inverted_elements", "dofs": 500, "timings": {"total": 2.0},
              "markers": {"tip": {"position": [9.0, 9.0]}},
              "accuracy": {"met": False, "levels": [{}] * 4, "stop": "the twin solve failed (inverted_elements)"}}

    def fake(code):
        def run(cmd, **kw):
            out = Path(cmd[cmd.index("--out") + 1])
            out.mkdir(parents=True, exist_ok=True)
            (out / "result.json").write_text(json.dumps(failed))
            return subprocess.CompletedProcess(cmd, code, "", "error: solve failed")
        return run
    monkeypatch.setattr(study.subprocess, "run", fake(2))
    r = study.run(designs=("thumb",), tols=(0.1,), out=tmp_path, adaptive=True)[0]
    assert r["failed"] == "the twin solve failed (inverted_elements)" and not r["met"] and not r["reported_met"]
    assert r["error_vs_reference"] != r["error_vs_reference"] and not r["measurable"]        # NaN: no error
    assert r["effectivity"] != r["effectivity"]
    assert "FAILED after 4 meshes" in capsys.readouterr().out
    monkeypatch.setattr(study.subprocess, "run", fake(1))
    with pytest.raises(RuntimeError, match="exit 1"):
        study.run(designs=("thumb",), tols=(0.1,), out=tmp_path)
