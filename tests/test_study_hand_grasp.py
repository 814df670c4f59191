"""studies/hand_grasp.py at small size: the three-finger hand closes on every shape at three contacts,
holds it light, loses it heavy; the limits are the closed grip's forces; writes its JSON and both figures."""
import json
import math

import numpy as np
import pytest
from _studies import load_study

study = load_study("hand_grasp")
MU = 0.8                                      # geometry/hand.toml's contact.friction
DENSITIES = (310.0, 2170.0, 3720.0)           # kg/m^3: light, then near and well beyond the limits


def test_hand_design_parses_with_three_skeleton_fingers():
    from skelfem.design import load_design
    d = load_design(study.DESIGN)
    fingers = {b.name.split("_")[0] for b in d.bones}
    assert fingers == {"left", "centre", "right"} and len(d.bones) == 9
    tendons = sorted(c.name for c in d.cables if c.kind == "tendon")
    assert tendons == ["centre_flexor", "left_flexor", "right_flexor"]
    assert sum(c.kind == "ligament" for c in d.cables) == 12          # palmar and dorsal, two joints each
    (obj,) = d.objects
    assert obj.name == study.OBJECT and obj.rigid and obj.material == "box_pla"
    assert np.allclose(d.gravity, 0.0)                                # the study switches it on
    assert d.friction.default.kinetic == MU


def test_shapes_fit_the_box_and_bad_names_are_refused():
    box = np.array([[27, -9], [73, -9], [73, 37], [27, 37]], float)
    for kind in study.SHAPES:
        p = np.array(study.shape_outline(kind, box))
        assert np.ptp(p[:, 0]) == pytest.approx(46.0) and p[:, 1].max() == pytest.approx(37.0)
        assert np.mean(p[:, 0]) == pytest.approx(50.0)
    assert study.polygon_area(study.shape_outline("square", box)) == pytest.approx(46.0 ** 2)
    assert study.polygon_area(study.shape_outline("hexagon", box)) == pytest.approx(1.5 * math.sqrt(3) * 23.0 ** 2)
    with pytest.raises(ValueError, match="unknown shape 'circle'"):
        study.shape_outline("circle", box)
    with pytest.raises(ValueError, match="unknown shape"):
        study.run(shapes=("circle",))
    with pytest.raises(ValueError, match="density > 0"):
        study.run(shapes=("square",), densities=(-1.0,))


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("hand_grasp")
    res = study.run(mus=(MU,), densities=DENSITIES, out=tmp / "out", figures=tmp / "fig")
    return res, tmp


@pytest.mark.slow
def test_hand_closes_on_every_shape_at_three_fingers(sweep):
    res, _ = sweep
    assert [r["shape"] for r in res["results"]] == list(study.SHAPES)
    for r in res["results"]:
        c = r["close"]
        assert c["converged"], (r["shape"], c["status"])
        assert c["fingers_touching"] == 3 and min(c["fingers"].values()) > 1e-3, (r["shape"], c["fingers"])
        assert sum(c["fingers"].values()) == pytest.approx(c["normal_magnitude"], rel=1e-9)
        assert c["normal_pads"] == pytest.approx(c["fingers"]["left"] + c["fingers"]["right"])
        left, right = c["contact_at"]["left"][0], c["contact_at"]["right"][0]
        assert left < 50.0 < right                                      # the outer fingers press the sides


@pytest.mark.slow
def test_light_objects_held_heavy_ones_lost_against_mu_min(sweep):
    res, _ = sweep
    g, t = 9.81, res["params"]["thickness"]
    for r in res["results"]:
        c, ws = r["close"], r["weighings"]
        area = res["shapes"][r["shape"]]["area"]
        tried = [w for w in ws if "held" in w]
        for w in tried:                                                 # W = rho g A t; mu_min from the closed grip
            assert w["weight"] == pytest.approx(w["density"] * 1e-9 * g * area * t, rel=1e-9)
            assert w["mu_min"] == pytest.approx(w["weight"] / c["normal_magnitude"])
            assert w["mu_min_pads"] == pytest.approx(w["weight"] / c["normal_pads"])
            assert w["margin"] == pytest.approx(MU / w["mu_min"])
            if w["margin"] < 0.9:                                       # clearly beyond the limit: lost
                assert not w["held"], (r["shape"], w)
        light = ws[0]
        assert light["held"] and light["margin"] > 1.5 and light["margin_pads"] > 1.5, (r["shape"], light)
        assert light["moved"]["displacement"][1] < 0 and abs(light["moved"]["displacement"][1]) < 1.0
        lost = [w for w in tried if not w["held"]]
        assert len(lost) == 1 and lost[0] is tried[-1], (r["shape"], [w["status"] for w in ws])
        assert lost[0]["status"] != "converged" and not lost[0]["converged"]
        assert all(w["status"] == "skipped" for w in ws[len(tried):])
        assert lost[0]["margin_pads"] < 0.9, (r["shape"], lost[0])       # beyond the outer fingers' limit


@pytest.mark.slow
def test_hand_grasp_files(sweep, picture):
    res, tmp = sweep
    saved = json.loads((tmp / "out" / "hand_grasp.json").read_text())
    assert {"design", "params", "shapes", "results", "weighings", "agree_with_mu_min",
            "agree_with_mu_min_pads"} <= set(saved)
    assert saved["weighings"] == res["weighings"] == sum("held" in w for r in res["results"] for w in r["weighings"])
    for r in saved["results"]:
        assert {"shape", "mu", "dofs", "close", "weighings"} <= set(r)
        for w in r["weighings"]:
            if "held" in w:
                assert {"density", "weight", "status", "mu_min", "margin", "mu_min_pads", "margin_pads"} <= set(w)
    picture(tmp / "fig" / "hand_grasp.png", 700, 700)
    picture(tmp / "fig" / "hand_grasp_margin.png", 600, 300, min_ink=0.02, min_colour=0.0005)
