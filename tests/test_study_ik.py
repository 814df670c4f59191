"""studies/ik_trajectories.py at a coarse size: it runs, tracks both lines, writes its files."""
import csv
import json

import numpy as np
import pytest
from _studies import load_study


def _load():
    return load_study("ik_trajectories")


@pytest.mark.slow
def test_ik_trajectories_tiny(tmp_path, picture):
    study = _load()
    res = study.run(size=4.0, targets=3, random=1, out=tmp_path)
    assert res["body_extent"] == 100.0 and res["tol"] == 0.1
    h = res["horizontal"]
    assert h["targets"] == 3 and h["reached"] >= 2 and h["max_error_reached"] < res["tol"]
    assert res["vertical"]["reached"] >= 1 and res["vertical"]["reachable_from"] == [10.0, 97.0]
    assert res["random"]["targets"] == 1 and res["random"]["reached"] == 1
    assert res["random"]["forward_solves"]["max"] <= 15
    with open(tmp_path / "horizontal.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 3
    assert np.allclose([float(r["target_y"]) for r in rows], 88.0)
    errors = [float(r["error"]) for r in rows]
    assert h["max_error"] > 0 and abs(max(errors) - h["max_error"]) < 1e-9
    assert json.loads((tmp_path / "summary.json").read_text())["horizontal"]["reached"] == h["reached"]
    picture(tmp_path / "paths.png", 1200, 750)
    picture(tmp_path / "contractions.png", 1200, 380)
    with open(tmp_path / "random.csv") as f:
        random_rows = list(csv.DictReader(f))
    assert len(random_rows) == 1 and int(random_rows[0]["reached"]) == 1
    assert float(random_rows[0]["error"]) < res["tol"]
    with open(tmp_path / "vertical.csv") as f:
        assert np.allclose([float(r["target_x"]) for r in csv.DictReader(f)], 10.0)
    assert not list(tmp_path.glob(".*"))

