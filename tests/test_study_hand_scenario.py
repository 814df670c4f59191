"""studies/hand_scenario.py: the three-finger hand grasps its object, weighs it, lifts it 20 mm, carries it 30 mm
sideways, turns it 30 degrees, puts it down on a ramp and lets go (2D, a coarse mesh); the 3D gripper lifts its
sphere 10 mm. While held the object follows the base's rigid motion; put down, the ramp alone holds it."""
import json
import math

import numpy as np
import pytest
from _studies import load_study
from conftest import ROOT

HAND_STAGES = ["close", "weigh", "lift", "carry", "turn", "put_down", "release", "retreat"]


def _on_the_object(stage: dict) -> np.ndarray:
    """The contacts' forces on the object (the read-outs give them on the pair's first name: minus)."""
    return -np.asarray(stage["normal_force"]) - np.asarray(stage["friction"]) \
        - np.asarray(stage["ground_force"]) - np.asarray(stage["ground_friction"])


def _check_hand(h: dict, floor: float) -> None:
    assert h["converged"], h["status"]
    st = {s["name"]: s for s in h["stages"]}
    assert list(st) == HAND_STAGES and not h["events"]                       # no jump anywhere
    W = np.asarray(st["weigh"]["weight"])
    # weighed: the fingers carry the whole weight, nothing touches the ramp
    assert _on_the_object(st["weigh"]) == pytest.approx(-W, abs=1e-3 * np.linalg.norm(W))
    assert np.linalg.norm(st["weigh"]["ground_force"]) == 0.0
    # lifted 20 mm and carried 30 mm with the base, to 2 % of the object's size (the floor)
    lift = np.asarray(st["lift"]["object"]) - st["weigh"]["object"]
    carry = np.asarray(st["carry"]["object"]) - st["lift"]["object"]
    assert lift == pytest.approx([0.0, 20.0], abs=floor * h["size"])
    assert carry == pytest.approx([30.0, 0.0], abs=floor * h["size"])
    by = h["worst_follow"]["by_stage"]
    assert by["lift"] < floor and by["carry"] < floor
    # turned with the palm (30 degrees within 1.5), held throughout: the soft fingers bend under the weight's
    # share across the hand, the object hardly moves in the fingertips' frame
    assert st["turn"]["object_angle"] - st["weigh"]["object_angle"] == pytest.approx(30.0, abs=1.5)
    assert by["turn"] < 0.1 and h["worst_follow"]["in_grip"] < 0.01 * h["size"]
    assert all(r["normal"] > 0 for r in h["rows"] if r["stage"] in ("weigh", "lift", "carry", "turn"))
    # put down flat on the 30-degree ramp; let go and retreated, the ramp holds it (mu 0.8 > tan 30)
    end = st["retreat"]
    assert end["object_angle"] == pytest.approx(30.0, abs=0.01)
    ramp = np.asarray(end["ground_force"]) + end["ground_friction"]
    assert -ramp == pytest.approx(-W, abs=0.05 * np.linalg.norm(W))        # the ramp carries the weight
    assert end["normal"] < 0.05 * np.linalg.norm(W)                          # the fingers have let go
    assert _on_the_object(end) == pytest.approx(-W, abs=1e-3 * np.linalg.norm(W))
    normal = np.asarray(end["ground_force"])
    assert np.linalg.norm(end["ground_friction"]) < 0.8 * np.linalg.norm(normal)       # inside the cone
    assert math.degrees(math.atan2(normal[0], -normal[1])) == pytest.approx(30.0, abs=0.01)   # normal to the ramp


def _check_gripper3d(g: dict, floor: float) -> None:
    assert g["converged"], g["status"]
    st = {s["name"]: s for s in g["stages"]}
    assert list(st) == ["close", "weigh", "lift"] and not g["events"]
    W = np.asarray(st["weigh"]["weight"])
    assert np.linalg.norm(st["close"]["weight"]) == 0.0 and st["close"]["normal"] > 0     # squeezed, no weight
    assert _on_the_object(st["weigh"]) == pytest.approx(-W, abs=2e-3 * np.linalg.norm(W))
    lift = np.asarray(st["lift"]["object"]) - st["weigh"]["object"]
    assert lift == pytest.approx([0.0, 10.0, 0.0], abs=floor * g["size"])
    assert g["worst_follow"]["by_stage"]["lift"] < floor
    assert _on_the_object(st["lift"]) == pytest.approx(-W, abs=2e-3 * np.linalg.norm(W))


@pytest.mark.slow
def test_hand_scenario_tiny_grasps_lifts_carries_turns_and_puts_down(tmp_path, picture):
    """A 6 mm mesh (1,018 DOFs): 25-45 s with the pictures, on a loaded machine."""
    study = load_study("hand_scenario")
    res = study.run(size=6.0, three_d=False, weightless=False, out=tmp_path / "out", figures=tmp_path / "fig",
                    say=lambda *a: None)
    _check_hand(res["hand"], study.FOLLOW_SHARE)
    saved = json.loads((tmp_path / "out" / "hand_scenario.json").read_text())
    assert saved["hand"]["stages"] == json.loads(json.dumps(res["hand"]["stages"]))
    lines = (tmp_path / "out" / "hand_scenario.csv").read_text().splitlines()
    assert len(lines) == 1 + len(res["hand"]["rows"]) == 1 + res["hand"]["load_steps"]
    assert all(line.startswith("hand,") for line in lines[1:])
    assert (tmp_path / "out" / "hand.toml").exists()
    picture(tmp_path / "fig" / "hand_scenario.png", 800, 400)
    assert 20_000 < (tmp_path / "fig" / "hand_scenario.gif").stat().st_size < 2_000_000


@pytest.mark.slow
def test_gripper3d_tiny_lifts_its_sphere_with_the_palm(tmp_path, picture):
    """A 6 mm mesh (1,725 DOFs): 20-30 s, on a loaded machine."""
    study = load_study("hand_scenario")
    res, _ = study.scenario(study.gripper3d_design(6.0), frames=False, picture=tmp_path / "3d.png")
    _check_gripper3d(res, study.FOLLOW_SHARE)
    picture(tmp_path / "3d.png", 400, 400)


def test_the_committed_hand_scenario_meets_the_floor_on_the_designs_meshes():
    """The study's committed output (hand.toml's 2 mm mesh, gripper3d.toml's): the hand's scenario completes, and
    the 3D gripper lifts its sphere 10 mm, following the base within 2 % of the sphere's size."""
    out = json.loads((ROOT / "studies" / "output" / "hand_scenario" / "hand_scenario.json").read_text())
    assert out["params"]["size"] is None and out["params"]["size3d"] is None
    _check_hand(out["hand"], 0.02)
    _check_gripper3d(out["gripper3d"], 0.02)


def _pad_on_a_box(lift: list, theta: float = 30.0) -> dict:
    """A 6 x 3 mm PLA box resting on a floor under gravity tilted by theta (friction 0.8 > tan 30 deg), a soft
    pad above it: weigh, press the pad 0.3 mm onto the box, move it by lift (mm) off it."""
    th = math.radians(theta)
    return {"format": 1, "name": "pad", "dim": 2, "thickness": 10.0, "mesh": {"size": 0.5, "degree": 1},
            "materials": {"soft": {"E": 0.1, "nu": 0.45, "density": 1000.0},
                          "pla": {"E": 1000.0, "nu": 0.35, "density": 1250.0}},
            "body": {"outline": [[19, 3.3], [27, 3.3], [27, 8], [19, 8]], "material": "soft"},
            "pins": [{"name": "top", "region": [[18, 7.99], [28, 9]], "kind": "fixed"}],
            "objects": [{"name": "box", "outline": [[20, 0], [26, 0], [26, 3], [20, 3]], "material": "pla"}],
            "grounds": [{"name": "floor", "point": [0, -0.01], "normal": [0, 1], "stiffness": 100.0,
                         "friction": 0.8}],
            "gravity": {"acceleration": [0.0, 0.0]}, "contact": {"dhat": 0.1, "friction": 0.8},
            "stages": [{"name": "weigh", "set": {"gravity.acceleration": [9.81 * math.sin(th), -9.81 * math.cos(th)]}},
                       {"name": "press", "set": {"pins.top.move": [0.0, -0.3]}},
                       {"name": "lift", "set": {"pins.top.move": lift}}]}


DIAGONAL = pytest.mark.xfail(strict=True, reason="lifted 1 mm and moved 0.5 mm down the slope, the pad takes the box "
                             "up with it in the step's first solve, the next one leaves it tilted 4 degrees just off "
                             "the floor, and the step ends 'object box is not held'")


@pytest.mark.parametrize("lift", [[0.0, 1.0], pytest.param([0.5, 1.0], marks=DIAGONAL)], ids=["up", "diagonal"])
def test_a_pad_lifted_off_a_box_on_a_slope_leaves_it_there(lift):
    """Lifted off, the pad leaves the box where the floor holds it (held there before the pad pressed it). The
    step's first solve takes the box up 1.2 mm with the pad (the contacts a step starts with are held stuck at
    any force: here the pad's sides' friction); the lag update finds the floor's normal force 0, and the next
    solves must bring it back down. Lifted straight up they do (the floor's anchors pull it back to 1e-4 mm); they
    stalled ("object box is not held" after 114 Newton iterations) until the curved line search stopped taking
    relaxed steps for models that bound their steps (free objects). Moved diagonally they still do not: the hand
    scenario's retreat backs the palm away along the ramp's normal."""
    from skelfem import Session
    with Session(_pad_on_a_box(lift)) as s:
        r = s.run_stages()
    stages = {st["name"]: st for st in r.to_dict()["stages"]}
    assert stages["press"]["converged"]                       # held by the floor, then pressed: fine
    assert r.converged, r.status
    moved = np.subtract(stages["lift"]["objects"]["box"]["position"], stages["weigh"]["objects"]["box"]["position"])
    assert np.linalg.norm(moved) < 0.05
