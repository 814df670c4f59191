"""studies/tol_check.py on one design and one tolerance: the command meets it against a finer reference."""
import json
import shutil
from pathlib import Path

import pytest
from _studies import load_study

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def thumb(tmp_path_factory):
    """The thumb's P2 reference at 0.7 mm (the module's costliest solve, done once) and its --tol 2 row:
    (study, rows, out). Tests that run more write into their own folders or only overwrite the tol run."""
    study = load_study("tol_check")
    out = tmp_path_factory.mktemp("tol_check")
    rows = study.run(designs=("thumb",), tols=(2.0,), ref_size=0.7, out=out)
    return study, rows, out


def test_tol_check_tiny_and_its_table(thumb, capsys):
    study, rows, out = thumb
    tol = 2.0
    assert len(rows) == 1
    r = rows[0]
    assert r["design"] == "thumb" and r["tol"] == tol and r["degree"] == 2 and r["meshes"] >= 3
    assert r["reported_met"] and r["met"] and r["error_vs_reference"] <= tol
    assert 0 < r["estimated_error"] <= tol / 2                 # met: twice the estimate within the tolerance
    assert r["effectivity"] == pytest.approx(r["estimated_error"] / r["error_vs_reference"])
    assert r["dofs"] < r["reference_dofs"] and 0 < r["time"] and 0 < r["reference_time"]
    assert 0 <= r["reference_uncertainty"] < r["estimated_error"]       # the reference's twin: its own scatter
    assert r["measurable"] == (r["error_vs_reference"] > 2 * r["reference_uncertainty"])
    levels = json.loads((out / "thumb" / "tol_2" / "result.json").read_text())["accuracy"]["levels"]
    assert levels[-1]["twin"] and levels[-1]["scatter"] >= 0 and r["size"] == levels[-1]["size"]
    assert r["bones"] == "rigid" and 0 < r["bones_difference"] <= 0.1 * tol / 2   # PLA in silicone: rigid
    assert not (out / "thumb" / "tol_2" / "deformed.png").exists()     # --no-picture
    # the command line with --reuse-references: the same reference read back (its time and DOFs, not a
    # new solve's), the table written
    capsys.readouterr()
    assert study.main(["--designs", "thumb", "--tols", "2", "--ref-size", "0.7", "--out", str(out),
                       "--reuse-references"]) == 0
    lines = (out / "tol_check.csv").read_text().splitlines()
    assert lines[0].startswith("design,tol,degree,size,estimated_error,error_vs_reference,effectivity") and len(lines) == 2
    again = dict(zip(lines[0].split(","), lines[1].split(",")))
    assert float(again["reference_time"]) == r["reference_time"] and int(again["reference_dofs"]) == r["reference_dofs"]
    printed = capsys.readouterr().out
    assert "reference read back" in printed and "1/1 tolerances met" in printed


def test_tol_check_adaptive_runs_the_command_with_adaptive(thumb, tmp_path, capsys):
    """--adaptive in a folder of its own, the module's reference copied in and read back (as the table's
    test checks; solving it again costs the most and checks nothing about --adaptive)."""
    study, _, out = thumb
    shutil.copytree(out / "thumb" / "reference", tmp_path / "thumb" / "reference")
    assert study.main(["--designs", "thumb", "--tols", "2", "--ref-size", "0.7", "--out", str(tmp_path),
                       "--adaptive", "--reuse-references"]) == 0
    lines = (tmp_path / "tol_check_adaptive.csv").read_text().splitlines()
    assert lines[0].endswith(",method") and lines[1].endswith(",adaptive") and len(lines) == 2
    assert not (tmp_path / "tol_check.csv").exists()
    a = json.loads((tmp_path / "thumb" / "tol_2_adaptive" / "result.json").read_text())["accuracy"]
    assert a["adaptive"] and a["met"] and "1/1 tolerances met" in capsys.readouterr().out


def test_a_3d_reference_is_extrapolated_from_three_meshes(tmp_path):
    """3D: P2 at 2, sqrt 2 and 1 x h_ref, the markers extrapolated by Richardson (sizes measured by DOFs).
    h_ref 3 mm (6, 4.2 and 3 mm: 5.8k to 25k DOFs, a third of 2 mm's cost): the rate and the extrapolation's
    checks hold there as at 2 mm."""
    import numpy as np
    study = load_study("tol_check")
    study.solve_reference("post3d", 3.0, tmp_path)
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
