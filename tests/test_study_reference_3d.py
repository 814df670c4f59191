"""studies/reference_3d.py at a coarse h (3 mm: 6, 4.2 and 3 mm, 24.5k DOFs, about 0.6 of 2.5 mm's time; at 4 mm
Gmsh aborts while grading post3d): the accuracy studies' 3D reference by both linear solvers, each in its own
process, the same tip."""
import json

import pytest
from _studies import load_study

pytestmark = pytest.mark.slow


def test_reference_3d_tiny(tmp_path):
    data = load_study("reference_3d").main(["--h-ref", "3.0", "--out", str(tmp_path)])
    direct, iterative = data["rows"]
    assert (direct["solver"], iterative["solver"]) == ("direct", "iterative")
    for r in data["rows"]:
        assert r["exit"] == 0 and r["status"] == "converged" and r["fallbacks"] == 0 and r["peak_gb"] > 0.05
    assert direct["dofs"] == iterative["dofs"] > 1000
    assert data["tip_difference_mm"] < 1e-7
    assert data["speedup"] == pytest.approx(direct["wall_s"] / iterative["wall_s"])
    assert json.loads((tmp_path / "reference_3d.json").read_text())["rows"][1]["solver"] == "iterative"
