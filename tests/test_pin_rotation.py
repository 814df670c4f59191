"""A base that moves: a pin's boundary moved and turned about a centre (pins.P.rotate), in 2D and 3D, fixed and
spring pins, from the design or a stage; a rotation without its centre (or, in 3D, its axis) refused."""
import tomllib

import numpy as np
import pytest
from conftest import GEOMETRY

from skelfem import Session
from skelfem.design import DesignError, parse_design
from skelfem.terms.pins import rotation


def _block(kind: str, rotate: dict) -> dict:
    """A 10 x 30 mm block held by its top edge, nothing else on it: the pin's motion moves it rigidly."""
    pin = {"name": "top", "region": [[-1, 29.99], [11, 31]], "kind": kind, "rotate": rotate, "move": [1.0, -2.0]}
    if kind == "spring":
        pin["stiffness"] = 1000.0
    return {"format": 1, "name": "turn", "dim": 2, "thickness": 10.0, "mesh": {"size": 1.5},
            "materials": {"soft": {"E": 1.0, "nu": 0.3}},
            "body": {"outline": [[0, 0], [10, 0], [10, 30], [0, 30]], "material": "soft"},
            "pins": [pin], "markers": {"tip": [5, 0], "corner": [10, 0]}}


@pytest.mark.parametrize("kind", ["fixed", "spring"])
def test_a_turned_pin_carries_a_free_block_rigidly_in_2d(kind):
    """x = c + move + R (X - c) for every marker, to 1e-6 mm (spring pins: 1e-4 mm, Newton's tolerance on
    springs that carry no load)."""
    c, th = np.array([5.0, 30.0]), np.radians(20.0)
    with Session(_block(kind, {"angle": 20.0, "centre": c.tolist()})) as s:
        r = s.solve()
    assert r.converged, r.status
    R = rotation(th, None)
    for name, X in (("tip", [5, 0]), ("corner", [10, 0])):
        expected = c + np.array([1.0, -2.0]) + R @ (np.asarray(X, float) - c)
        assert np.allclose(r.markers[name]["position"], expected, atol=1e-6 if kind == "fixed" else 1e-4)


def test_a_turned_pin_carries_a_free_block_rigidly_in_3d():
    c, axis = np.array([2.0, 2.0, 12.0]), np.array([1.0, 1.0, 0.0]) / np.sqrt(2)
    d = {"format": 1, "name": "turn3d", "dim": 3, "mesh": {"size": 2.0}, "materials": {"soft": {"E": 1.0, "nu": 0.3}},
         "body": {"solids": [{"box": {"min": [0, 0, 0], "max": [4, 4, 12]}}], "material": "soft"},
         "pins": [{"name": "top", "region": [[-1, -1, 11.99], [5, 5, 13]], "kind": "fixed",
                   "rotate": {"angle": -15.0, "centre": c.tolist(), "axis": [2.0, 2.0, 0.0]}}],
         "markers": {"tip": [2.0, 2.0, 0.0], "edge": [4.0, 0.0, 0.0]}}
    with Session(d) as s:
        r = s.solve()
    assert r.converged, r.status
    R = rotation(np.radians(-15.0), axis)
    for name in ("tip", "edge"):
        X = np.asarray(d["markers"][name], float)
        assert np.allclose(r.markers[name]["position"], c + R @ (X - c), atol=1e-6)


@pytest.mark.slow
def test_the_gripper_lifts_and_turns_the_box_it_holds():
    """geometry/gripper_stages.toml's stages close, weigh, lift (the palm up 10 mm) and turn (10 degrees about
    the palm's centre): held throughout, the box rises with the palm within 2 % of its size (it is 53.7 mm
    across) and turns with it by 10 +- 1 degrees, hanging back from the base's rigid motion by less than 10 %
    of its size (2.5 mm measured: the soft fingers bend under its weight as the palm turns)."""
    c = np.array([50.0, 115.0])
    with Session(GEOMETRY / "gripper_stages.toml") as s:
        r = s.run_stages()
    assert r.converged, r.status
    box = {e["name"]: np.array(e["objects"]["box"]["position"]) for e in r.to_dict()["stages"]}
    size = np.hypot(48.0, 24.0)
    assert np.linalg.norm(box["lift"] - box["weigh"] - [0.0, 10.0]) < 0.02 * size
    moved = c + np.array([0.0, 10.0]) + rotation(np.radians(10.0), None) @ (box["weigh"] - c)
    assert np.linalg.norm(box["turn"] - moved) < 0.1 * size
    turned = r.objects["box"]["rotation"] - r.to_dict()["stages"][2]["objects"]["box"]["rotation"]
    assert turned == pytest.approx(np.radians(10.0), abs=np.radians(1.0))


BAD = [
    ({"angle": 30.0}, "pins.top.rotate.centre: missing: a rotation turns about a centre"),
    ({"angle": 400.0, "centre": [0, 0]}, "pins.top.rotate.angle: must lie within +-360 degrees"),
    ({"angle": 30.0, "centre": [0, 0], "axis": [0, 0, 1]}, "pins.top.rotate.axis: unknown key"),
    ({"angle": 30.0, "centre": [0]}, "pins.top.rotate.centre: must be a point"),
    ({"centre": [0, 0]}, "pins.top.rotate.angle: missing"),
]


@pytest.mark.parametrize("rotate, message", BAD, ids=[m for _, m in BAD])
def test_a_bad_rotation_is_one_design_error(rotate, message):
    with pytest.raises(DesignError) as e:
        parse_design(_block("fixed", rotate), "t.toml")
    assert str(e.value).startswith("t.toml: ") and message.split(": must be a point")[0] in str(e.value)


def test_a_3d_rotation_needs_an_axis_and_a_stage_turns_only_a_pin_the_design_turns():
    d = {"format": 1, "name": "turn3d", "dim": 3, "mesh": {"size": 2.0}, "materials": {"soft": {"E": 1.0, "nu": 0.3}},
         "body": {"solids": [{"box": {"min": [0, 0, 0], "max": [4, 4, 12]}}], "material": "soft"},
         "pins": [{"name": "top", "region": [[-1, -1, 11.99], [5, 5, 13]], "rotate": {"angle": 5, "centre": [0, 0, 0]}}]}
    with pytest.raises(DesignError, match=r"pins\.top\.rotate\.axis: missing"):
        parse_design(d, "t.toml")
    d["pins"][0]["rotate"]["axis"] = [0, 0, 0]
    with pytest.raises(DesignError, match=r"pins\.top\.rotate\.axis: must not be zero"):
        parse_design(d, "t.toml")
    g = tomllib.loads((GEOMETRY / "gripper.toml").read_text())
    g["stages"] = [{"name": "close", "set": {"cables.left_flexor.contraction": 4.0}}]
    g["stages"].append({"name": "turn", "set": {"pins.palm.rotate.angle": 10.0}})
    with pytest.raises(DesignError, match=r"t\.toml: stages\.turn\.set\.pins\.palm\.rotate\.angle: not a parameter "
                                          r"a stage can change \(a stage turns a pin that the design gives rotate"):
        parse_design(g, "t.toml")
    next(p for p in g["pins"] if p["name"] == "palm")["rotate"] = {"angle": 0.0, "centre": [50.0, 115.0]}
    assert parse_design(g, "t.toml").stages[-1].design.pins[0].angle == 10.0


@pytest.mark.mpi
@pytest.mark.slow
@pytest.mark.parametrize("kind", ["fixed", "spring"])
def test_a_turned_pin_under_a_load_agrees_across_two_ranks(tmp_path, mpirun, kind):
    """The turned block pulled sideways at its tip: `mpirun -n 2` gives the serial tip and reaction to 1e-9."""
    import json

    from _designs import toml_text
    d = _block(kind, {"angle": 20.0, "centre": [5.0, 30.0]})
    d["loads"] = [{"name": "pull", "at": [5, 1], "force": [0.01, 0.0]}]
    path = tmp_path / "turn.toml"
    path.write_text(toml_text(d))
    out = {}
    for ranks in (1, 2):
        res = mpirun.run([mpirun.skelfem, "simulate", str(path), "--out", str(tmp_path / str(ranks)), "-q",
                          "--no-picture"], ranks)
        assert res.returncode == 0, res.stdout + res.stderr
        out[ranks] = json.loads((tmp_path / str(ranks) / "result.json").read_text())
    assert np.allclose(out[1]["markers"]["tip"]["position"], out[2]["markers"]["tip"]["position"], atol=1e-9)
    assert np.allclose(out[1]["pins"]["top"]["reaction"], out[2]["pins"]["top"]["reaction"], atol=1e-9)
    assert out[1]["pins"]["top"]["reaction"][0] == pytest.approx(-0.01, rel=1e-6)
