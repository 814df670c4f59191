"""--tol: the error model's choices, and a run that meets its tolerance against a finer reference."""
import json
from pathlib import Path

import numpy as np
import pytest

from skelfem import accuracy
from skelfem.cli import main

GEOMETRY = Path(__file__).resolve().parents[1] / "geometry"


def test_tighter_tolerance_never_coarsens_and_locking_forces_p2():
    sizes = [accuracy.choose(tol, 46.3, 0.45) for tol in (4.0, 1.0, 0.3, 0.1)]
    est = [c.estimate for c in sizes]
    assert all(c.met for c in sizes) and est == sorted(est, reverse=True)
    for c, tol in zip(sizes, (4.0, 1.0, 0.3, 0.1)):
        assert accuracy.SAFETY * c.estimate <= tol * (1 + 1e-9)
    assert accuracy.choose(5.0, 46.3, 0.499).degree == 2          # P1 locks: never chosen
    assert not accuracy.choose(1e-4, 46.3, 0.45).met              # beyond the finest size: said so
    # a design that barely moves needs a much coarser mesh for the same tolerance
    assert accuracy.choose(0.2, 2.0, 0.45).size > accuracy.choose(0.2, 46.3, 0.45).size


@pytest.mark.slow
def test_tol_run_meets_its_tolerance_against_a_finer_reference(tmp_path, capsys):
    design = str(GEOMETRY / "finger_bones.toml")       # tendon anchored in a bone: a converging answer
    assert main(["simulate", design, "--out", str(tmp_path / "tol"), "--no-picture", "--tol", "0.3"]) == 0
    res = json.loads((tmp_path / "tol" / "result.json").read_text())
    a = res["accuracy"]
    assert a["met"] and a["estimated_error"] <= 0.3 / accuracy.SAFETY * (1 + 1e-9) and a["motion_estimate"] > 10.0
    assert res["degree"] == a["degree"] and a["size"] < accuracy.H_MAX      # the tolerance, not a clamp, decided
    assert "--tol 0.3 mm: P" in capsys.readouterr().out
    assert main(["simulate", design, "--out", str(tmp_path / "ref"), "-q", "--no-picture",
                 "--set", "mesh.degree=2", "--set", "mesh.size=1.0"]) == 0
    ref = json.loads((tmp_path / "ref" / "result.json").read_text())
    err = np.linalg.norm(np.subtract(res["markers"]["tip"]["position"], ref["markers"]["tip"]["position"]))
    assert err < 0.3


def test_tol_needs_a_marker_and_a_positive_value(tmp_path, capsys):
    design = str(GEOMETRY / "finger_soft.toml")
    assert main(["simulate", design, "--out", str(tmp_path / "a"), "--tol", "0"]) == 1
    assert main(["simulate", design, "--out", str(tmp_path / "b"), "--tol", "1", "--set", "markers={}"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("error: ") for line in err)
    assert err[0].startswith("error: --tol: must be") and "> 0" in err[0] and err[0].endswith("got 0")
    assert "needs at least one marker" in err[1]
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
