"""studies/rigid_bones.py, tiny: rigid against elastic bones on a coarse finger."""
from _studies import load_study

from conftest import GEOMETRY


def test_rigid_bones_study_tiny():
    study = load_study("rigid_bones")
    # size 2: at size 4 (450 DOFs) the border's rows (dense over each bone's neighbours) outweigh its cells
    r = study.run(GEOMETRY / "finger.toml", size=2.0, exponents=(0, 1), repeats=1)
    rg = r["rigid"]
    assert rg["converged"] and all(e["converged"] for e in r["elastic"])
    assert rg["unknowns"] < rg["dofs"] and rg["nnz"] < r["elastic"][0]["nnz"]
    assert rg["assembled_cells"] < r["elastic"][0]["assembled_cells"]
    d0, d1 = (e["marker_difference"] for e in r["elastic"])
    assert 0 < d1 < d0 and -1.3 < r["slope"] < -0.7
    for case in [rg] + r["elastic"]:              # warm re-solves after a 5 % contraction change, up and back
        assert len(case["warm_iterations"]) == 2 and min(case["warm_iterations"]) >= 1 and case["warm_time"] > 0
    assert set(rg["bones"]) == {"proximal", "middle", "distal"}
