"""studies/readme_figures.py at a coarse size: it runs, orders the skeletons, writes its PNGs."""
from _studies import load_study


def _load():
    return load_study("readme_figures")


def test_readme_figures_tiny(tmp_path, picture):
    study = _load()
    res = study.run(size=4.0, contraction=6.0, out=tmp_path)
    assert set(res) == {"finger", "finger_bones", "finger_soft"}
    # every finger curls toward its flexor (-x); the soft one carries less tendon tension
    assert all(r["tip"][0] < 0 for r in res.values())
    assert res["finger_soft"]["tension"] < res["finger"]["tension"]
    picture(tmp_path / "finger.png", 700, 800)
    picture(tmp_path / "skeletons.png", 1300, 550)
    picture(tmp_path / "newton.png", 600, 380)
    assert all(r["newton_iterations"] > 0 and r["residual_history"] for r in res.values())
    assert not list(tmp_path.glob(".*"))


def test_readme_fabrication_figure(tmp_path, picture):
    res = _load()._fabrication(tmp_path)
    assert set(res) == {"bone_proximal", "bone_middle", "bone_distal", "mould_bottom", "mould_top"}
    assert all(v > 0 for v in res.values())
    picture(tmp_path / "fabrication.png", 900, 700)
