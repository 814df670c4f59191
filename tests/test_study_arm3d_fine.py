"""studies/arm3d_fine.py on a coarse mesh: the run converges with the iterative solver, its peak memory
is the sum of each rank's own, and one and two ranks reach the same tensions."""
import json

import pytest
from _studies import load_study

pytestmark = pytest.mark.slow


def _check(r: dict, ranks: int) -> None:
    assert r["status"] == "converged" and r["linear_solver"] == "iterative" and r["ranks"] == ranks
    assert len(r["peak_per_rank_gb"]) == ranks
    assert r["peak_gb"] == pytest.approx(sum(r["peak_per_rank_gb"]))
    assert r["kb_per_dof"] == pytest.approx(r["peak_gb"] * 2**20 / r["dofs"])
    assert r["wall_s"] > r["timings"]["solve"] > 0.0
    assert len(r["krylov_per_newton"]) >= r["newton_iterations"] > 0
    assert max(r["tensions"].values()) > 0.0


def test_arm3d_fine_tiny(tmp_path):
    study = load_study("arm3d_fine")
    r = study.main(["--size", "9", "--out", str(tmp_path)])
    _check(r, 1)
    assert json.loads((tmp_path / "arm3d_fine.json").read_text())["dofs"] == r["dofs"]
    assert not (tmp_path / "run").exists()            # the run's own folder is not kept


@pytest.mark.mpi
def test_arm3d_fine_tiny_on_two_ranks(tmp_path, mpirun):
    study = load_study("arm3d_fine")
    serial = study.run(9.0, 1, tmp_path / "s")
    parallel = study.run(9.0, 2, tmp_path / "p")
    _check(parallel, 2)
    assert parallel["dofs"] == serial["dofs"]
    for name, t in serial["tensions"].items():
        assert parallel["tensions"][name] == pytest.approx(t, rel=1e-6)
