"""Domain decomposition: `mpirun -n 2` and serial runs agree, for every ingredient that couples ranks."""
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from _designs import toml_text

ROOT = Path(__file__).resolve().parents[1]

pytestmark = [pytest.mark.mpi, pytest.mark.slow]


def _simulate(mpirun, design, out, ranks, *sets):
    args = [mpirun.skelfem, "simulate", design, "--out", out, "-q", *sum((["--set", s] for s in sets), [])]
    res = mpirun.run(args, ranks)
    assert res.returncode == 0, res.stdout + res.stderr
    return json.loads((out / "result.json").read_text())


def _close(a, b, rel=1e-6, scale=0.0):
    """|a - b| <= rel * max(|a|, scale): forces that vanish are compared on a force scale."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return np.linalg.norm(a - b) <= rel * max(np.linalg.norm(a), scale, 1e-12)


def _agree(serial, parallel):
    assert parallel["converged"] and parallel["dofs"] == serial["dofs"]
    assert parallel["newton_iterations"] == serial["newton_iterations"]
    for name, m in serial["markers"].items():
        assert _close(m["displacement"], parallel["markers"][name]["displacement"]), name
    for name, c in serial["cables"].items():
        assert _close([c["tension"]], [parallel["cables"][name]["tension"]]), name
        assert _close(c["tensions"], parallel["cables"][name]["tensions"]), name
        assert c["slipping"] == parallel["cables"][name]["slipping"], name
    force = max(c["tension"] for c in serial["cables"].values())
    for name, p in serial["pins"].items():
        assert _close(p["reaction"], parallel["pins"][name]["reaction"], 1e-6, force), name
    for name, g in serial["grounds"].items():
        assert _close(g["force"], parallel["grounds"][name]["force"], 1e-6, force), name


def test_arm3d_two_ranks_match_serial(tmp_path, mpirun, picture):
    serial = _simulate(mpirun, ROOT / "geometry" / "arm3d.toml", tmp_path / "s", 1, "mesh.size=9")
    parallel = _simulate(mpirun, ROOT / "geometry" / "arm3d.toml", tmp_path / "p", 2, "mesh.size=9")
    _agree(serial, parallel)
    import meshio
    m = meshio.read(tmp_path / "p" / "solution.xdmf")        # gathered to rank 0
    assert m.point_data["displacement"].shape[1] == 3
    assert {"tetra", "line"} <= {c.type for c in m.cells}
    picture(tmp_path / "p" / "deformed.png", 600, 600)


@pytest.mark.parametrize("friction", [0.0, 0.3])
def test_every_ingredient_agrees_across_ranks(tmp_path, mpirun, strip_design, friction):
    """Bones, tendon, pretensioned ligament, spring pin, moved pin, point load and a ground, P2; with and
    without cable friction."""
    d = strip_design(length=40.0, size=2.0, degree=2, contraction=0.4)
    d["bones"] = [{"name": "b", "outline": [[3, 10], [7, 10], [7, 25], [3, 25]], "material": "hard"}]
    d["cables"].append({"name": "lig", "kind": "ligament", "path": [[2, 5], [4, 20], [2, 35]],
                        "stiffness": 2.0, "pretension": 1.0})
    d["pins"][0]["move"] = [0.2, 0.0]
    d["pins"].append({"name": "side", "region": [[-1, 30], [0.5, 40]], "kind": "spring", "stiffness": 5.0})
    d["loads"] = [{"name": "push", "at": [5, 38], "force": [0.3, -0.02]}]
    d["grounds"] = [{"name": "wall", "point": [10.1, 0], "normal": [-1, 0], "stiffness": 10.0}]
    d["markers"]["mid"] = [5, 20]
    d["solver"] = {"steps": 2}
    for c in d["cables"]:
        c["friction"] = friction
    path = tmp_path / "all.toml"
    path.write_text(toml_text(d))
    serial = _simulate(mpirun, path, tmp_path / "s", 1)
    assert np.linalg.norm(serial["grounds"]["wall"]["force"]) > 0      # the ground is engaged
    assert all(c["tension"] > 0 for c in serial["cables"].values())    # both cables taut: low-rank parts
    if friction:
        assert any(np.ptp(c["tensions"]) > 1e-3 * c["tension"] for c in serial["cables"].values())
    _agree(serial, _simulate(mpirun, path, tmp_path / "p", 2))


def test_pull_study_under_mpirun_matches_serial(tmp_path, mpirun):
    """A study runs unchanged on a partitioned mesh (markers, loads, pins across ranks)."""
    study = [sys.executable, ROOT / "studies" / "pull_test.py", "--size", "3", "--loads", "2", "6"]
    for name, ranks in (("serial", 1), ("mpi", 2)):
        res = mpirun.run(study + ["--out", tmp_path / name], ranks)
        assert res.returncode == 0, res.stdout + res.stderr
    rows = [(tmp_path / n / "pull_test.csv").read_text().splitlines() for n in ("serial", "mpi")]
    assert len(rows[0]) == 7 and rows[0] == rows[1]
