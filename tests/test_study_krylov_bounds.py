"""studies/krylov_bounds.py on coarse meshes, the contrast sweep at P1 (no Poisson's ratio sweep: the
same code as the contrast one): every case converges without falling back, its converged tangent is
solved again to 1e-8 with a fresh multigrid, the sweeps' ratios are their largest mean over their
smallest, and a homogeneous body needs fewer Krylov iterations than one holding bones 1e4 times
stiffer."""
import json

import pytest
from _studies import load_study

pytestmark = pytest.mark.slow


def test_krylov_bounds_tiny(tmp_path):
    study = load_study("krylov_bounds")
    # the contrast sweep on the 10 mm mesh (1.7k DOFs: homogeneous 8 against 15 Krylov iterations a Newton step
    # at 1e4, 6 s for its three solves against 27 s at 6 mm on a loaded host)
    data = study.main(["--sizes", "10", "8", "--contrast-size", "10", "--contrast-degree", "1",
                       "--contrasts", "1", "10000", "--nus", "--out", str(tmp_path / "out"), "--figures", str(tmp_path / "fig")])
    s = data["sweeps"]
    assert [len(s[k]) for k in ("refinement", "refinement_rigid", "contrast", "nu")] == [2, 2, 3, 0]
    for rows in s.values():
        for r in rows:
            assert r["status"] == "converged" and r["fallbacks"] == 0, r
            assert len(r["krylov_per_newton"]) >= r["newton_iterations"] > 0
            assert r["krylov_mean"] == pytest.approx(sum(r["krylov_per_newton"]) / len(r["krylov_per_newton"]))
            assert 0 < r["krylov_fresh"] < 500      # the converged tangent to 1e-8 with a fresh multigrid
    assert s["refinement"][0]["dofs"] < s["refinement"][1]["dofs"]
    means = [r["krylov_mean"] for r in s["refinement"]]
    assert data["ratios"]["refinement"] == pytest.approx(max(means) / min(means))
    fresh = [r["krylov_fresh"] for r in s["refinement"]]
    assert data["fresh_ratios"]["refinement"] == pytest.approx(max(fresh) / min(fresh))
    homogeneous, stiff = s["contrast"][0], s["contrast"][1]
    assert (homogeneous["contrast"], stiff["contrast"]) == (1, 10000)
    assert homogeneous["krylov_mean"] < stiff["krylov_mean"]
    assert json.loads((tmp_path / "out" / "krylov_bounds.json").read_text())["ratios"] == data["ratios"]
    assert (tmp_path / "fig" / "krylov_bounds.png").stat().st_size > 10_000
