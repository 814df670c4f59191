"""studies/scatter.py, tiny: one design on three nearby sizes, the spread of its markers."""
import numpy as np
import pytest
from _studies import load_study

from conftest import GEOMETRY

pytestmark = pytest.mark.slow


def test_scatter_study_tiny(tmp_path):
    study = load_study("scatter")
    res = study.run(GEOMETRY / "finger_bones.toml", sizes=(3.0, 2.9, 2.8), sets=("cables.flexor.contraction=2",))
    rows = res["rows"]
    assert [r["size"] for r in rows] == [3.0, 2.9, 2.8] and all(r["dofs"] > 0 for r in rows)
    x = np.array([r["markers"]["tip"] for r in rows])
    assert np.allclose(res["std"], x.std(axis=0)) and np.allclose(res["range"], np.ptp(x, axis=0))
    assert 0 < max(res["range"]) < 0.5                     # different meshes, nearly one answer
    assert len({r["dofs"] for r in rows}) == 3
    assert study.main(["--design", str(GEOMETRY / "finger_bones.toml"), "--sizes", "3", "2.9",
                       "--out", str(tmp_path)]) == 0
    assert (tmp_path / "scatter.json").exists()
