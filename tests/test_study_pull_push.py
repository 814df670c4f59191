"""studies/pull_test.py and studies/push_test.py at a coarse size: they run, order the skeletons, write files."""

import numpy as np
import pytest
from _studies import load_study



def _load(name):
    return load_study(name)


@pytest.mark.slow
def test_pull_test_tiny_orders_the_skeletons(tmp_path, picture):
    study = _load("pull_test")
    res = study.run(size=3.0, loads=(1.0, 4.0), out=tmp_path)
    c = res["conditions"]
    assert all(r["status"] == "converged" and len(r["tip_displacement"]) == 2 for r in c.values())
    soft, bones, full = (np.array(c[k]["tip_displacement"]) for k in ("neither", "bones", "bones_ligaments"))
    assert np.all(full > 0)                                   # pulled along +y, the tip follows
    assert np.all(soft > bones) and np.all(bones > full)      # neither > bones only > bones + ligaments
    assert np.all(soft > 2 * bones)                           # the bones carry most of the load
    assert np.all(np.diff(soft) > 0)
    picture(tmp_path / "pull_test.png", 600, 400)
    picture(tmp_path / "pull_shapes.png", 1000, 500)
    rows = (tmp_path / "pull_test.csv").read_text().splitlines()
    assert rows[0].startswith("condition,load_N") and len(rows) == 1 + 3 * 2
    assert not list(tmp_path.glob(".*"))


@pytest.mark.slow
def test_push_test_tiny_orders_the_peak_forces(tmp_path, picture):
    study = _load("push_test")
    res = study.run(size=3.0, travel=6.0, steps=8, out=tmp_path)
    c = res["conditions"]
    assert all(r["status"] == "converged" and len(r["force"]) == 8 for r in c.values())
    peak = {k: r["normalised_peak"] for k, r in c.items()}
    assert peak["neither"] == pytest.approx(1.0)
    assert peak["bones"] > 1.3                                   # bones push harder than no bones
    assert abs(peak["bones_ligaments"] / peak["bones"] - 1) < 0.10   # slack ligaments add little
    assert peak["pretensioned"] > peak["bones_ligaments"] * 1.01     # pretensioned ones add more
    for r in c.values():                                          # force rises to a peak, then falls
        f = np.array(r["force"])
        assert f[0] >= 0 and f.max() > f[-1] and np.argmax(f) > 0
    rows = (tmp_path / "push_test.csv").read_text().splitlines()
    assert rows[0] == "condition,travel_mm,force_N,tip_x_mm,tip_y_mm" and len(rows) == 1 + 4 * 8 + 2 + 4
    picture(tmp_path / "push_test.png", 1000, 400)
    picture(tmp_path / "push_shapes.png", 1200, 500)
    assert not list(tmp_path.glob(".*"))


def test_pull_main_writes_into_out(tmp_path, capsys, picture):
    assert _load("pull_test").main(["--out", str(tmp_path), "--size", "4", "--loads", "2"]) == 0
    assert "bones + ligaments" in capsys.readouterr().out
    assert len((tmp_path / "pull_test.csv").read_text().splitlines()) == 1 + 3
    picture(tmp_path / "pull_shapes.png", 1000, 500)
