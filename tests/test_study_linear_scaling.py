"""studies/linear_scaling.py at one coarse mesh: both solvers run as simulate would, same answers."""
import json

import pytest
from _studies import load_study

pytestmark = pytest.mark.slow


def test_linear_scaling_tiny(tmp_path):
    study = load_study("linear_scaling")
    data = study.main(["--sizes", "3.0", "--degree", "1", "--out", str(tmp_path / "out"),
                       "--figures", str(tmp_path / "fig")])
    direct, iterative = data["rows"]
    assert (direct["solver"], iterative["solver"]) == ("direct", "iterative")
    for r in (direct, iterative):
        assert r["exit"] == 0 and r["status"] == "converged" and r["peak_mb"] > 50 and r["wall_s"] > 0.5
    assert direct["dofs"] == iterative["dofs"] > 100
    assert direct["krylov_per_newton"] == [] and all(k > 0 for k in iterative["krylov_per_newton"])
    assert len(iterative["krylov_per_newton"]) >= iterative["newton_iterations"]
    assert iterative["marker_difference_mm"] < 1e-6
    assert iterative["time_ratio"] == pytest.approx(iterative["wall_s"] / direct["wall_s"])
    assert json.loads((tmp_path / "out" / "linear_scaling.json").read_text())["rows"][0]["dofs"] == direct["dofs"]
    assert (tmp_path / "fig" / "linear_scaling.png").stat().st_size > 10_000
