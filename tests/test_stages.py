"""[[stages]]: a static scenario from the command line (close the gripper, then weigh the box), a stage that
fails (exit 2, naming it, the completed stages kept), bad stages refused before meshing, and the live keys a
stage may change are the ones the model changes live."""
import copy
import json
import subprocess
import tomllib

import pytest
from conftest import GEOMETRY, MPI_ENV, SKELFEM

from skelfem.design import DesignError, parse_design
from skelfem.design.stages import live_keys

from _designs import toml_text

STAGED = GEOMETRY / "gripper_stages.toml"


def _simulate(design, out, *extra):
    return subprocess.run([SKELFEM, "simulate", str(design), "--out", str(out), "--no-picture", *extra],
                          capture_output=True, text=True, env=MPI_ENV, timeout=600)


def _staged(*stages) -> dict:
    """The bundled gripper with these [[stages]] instead of its own."""
    d = tomllib.loads(STAGED.read_text())
    d["stages"] = [copy.deepcopy(s) for s in stages]
    return d


CLOSE = {"name": "close", "set": {"cables.left_flexor.contraction": 4.0, "cables.right_flexor.contraction": 4.0}}


@pytest.mark.slow
def test_the_gripper_closes_then_weighs_and_holds_the_box_from_the_command_line(tmp_path):
    """geometry/gripper_stages.toml: close (both flexors 4 mm, no gravity), then weigh (gravity on), lift and
    turn. Ramped together from rest the grip and the weight lose the box; stage by stage the box is held,
    sinking by less than a millimetre when it is weighed, and result.json and stages.xdmf hold one entry and
    one frame per stage (the lift and the turn: tests/test_pin_rotation.py)."""
    run = _simulate(STAGED, tmp_path / "out")
    assert run.returncode == 0, run.stderr[-2000:]
    assert "stage close: converged" in run.stdout and "stage weigh: converged" in run.stdout
    d = json.loads((tmp_path / "out" / "result.json").read_text())
    assert d["converged"] and [s["name"] for s in d["stages"]] == ["close", "weigh", "lift", "turn"]
    close, weigh, _, turn = d["stages"]
    assert all(s["converged"] for s in d["stages"]) and turn["load_steps"] == 8       # its steps = 8
    assert close["objects"]["box"]["weight"] == [0.0, 0.0] and weigh["objects"]["box"]["weight"][1] < 0
    assert -1.0 < weigh["objects"]["box"]["displacement"][1] < close["objects"]["box"]["displacement"][1]
    assert d["objects"] == turn["objects"] and d["markers"] == turn["markers"]      # the last stage's read-outs
    assert d["newton_iterations"] == sum(s["newton_iterations"] for s in d["stages"])
    # On the body: the contact carries the box's weight, and friction carries what the weight added. The
    # grip squeezes the box's corners, so the closed grip already holds a self-balanced pair (normal and
    # friction, 4e-4 N up and down, about 0.15 % of the weight: where the contacts formed sets it) that the
    # weighed state keeps.
    W = weigh["objects"]["box"]["weight"][1]
    pair = next(c for c in weigh["contacts"] if c["between"] == ["body", "box"])
    grip = next(c for c in close["contacts"] if c["between"] == ["body", "box"])
    assert pair["friction_force"][1] + pair["normal_force"][1] == pytest.approx(W, rel=1e-6)
    assert grip["friction_force"][1] + grip["normal_force"][1] == pytest.approx(0.0, abs=1e-6 * abs(W))
    assert pair["friction_force"][1] - grip["friction_force"][1] == pytest.approx(W, rel=1e-3)
    xdmf = (tmp_path / "out" / "stages.xdmf").read_text()
    assert xdmf.count('<Time Value="') == 4 and (tmp_path / "out" / "solution.xdmf").exists()


@pytest.mark.slow
def test_a_failing_stage_stops_the_run_with_exit_2_naming_it_and_keeps_the_completed_ones(tmp_path):
    """Gravity with friction 0.01: the box slips out (not held). The close stage's state is kept."""
    path = tmp_path / "slip.toml"
    path.write_text(toml_text(_staged(CLOSE, {"name": "slip", "set": {"gravity.acceleration": [0.0, -9.81],
                                                                         "contact.friction": 0.01}})))
    run = _simulate(path, tmp_path / "out")
    assert run.returncode == 2, run.stderr[-2000:]
    assert "stage slip failed (no equilibrium: object box is not held)" in run.stderr
    assert "Traceback" not in run.stderr
    d = json.loads((tmp_path / "out" / "result.json").read_text())
    assert d["converged"] is False and d["failed_stage"] == "slip"
    assert [(s["name"], s["converged"]) for s in d["stages"]] == [("close", True), ("slip", False)]
    assert d["stages"][0]["objects"]["box"]["position"] is not None
    assert (tmp_path / "out" / "stages.xdmf").read_text().count('<Time Value="') == 1
    assert not (tmp_path / "out" / "solution.xdmf").exists()        # no equilibrium at the end


BAD = [
    ({"name": "s", "set": {"cables.nope.contraction": 1.0}}, "stages.s.set.cables.nope.contraction: not a parameter"),
    ({"name": "s", "set": {"mesh.size": 1.0}}, "stages.s.set.mesh.size: not a parameter a stage can change"),
    ({"name": "s", "set": {"cables.left_lig1_palmar.contraction": 1.0}}, "stages.s.set.cables.left_lig1_palmar"),
    ({"name": "s", "set": {}}, "stages.s.set: a stage changes at least one live parameter"),
    ({"name": "s", "set": {"cables.left_flexor.contraction": 4.0}}, "stages.s.set: changes nothing"),
    ({"name": "s", "set": {"gravity.acceleration": [0.0]}}, "stages.s: gravity.acceleration: must be 2 numbers"),
    ({"name": "s", "set": {"cables.left_flexor.contraction": -1e300}}, "stages.s: cables.left_flexor.contraction"),
    ({"name": "s", "set": {"cables.left_flexor.friction": {"pla": 0.2}}}, "left_flexor.friction.pla: not a parameter"),
    ({"name": "s", "set": {"cables.left_flexor.friction": True}}, "left_flexor.friction: must be a number to change"),
    ({"name": "s", "set": {"pins.palm.move": "up"}}, "stages.s.set.pins.palm.move: must be a list of numbers"),
    ({"name": "s", "set": {"pins.hand.move": [0, 1]}}, "stages.s.set.pins.hand.move: not a parameter"),
    ({"name": "s", "set": {"contact.friction": 0.5}, "steps": 0}, "stages.s.steps: must be 1 to 10000"),
    ({"name": "s", "set": {"contact.friction": 0.5}, "sets": 1}, "stages.s.sets: unknown key"),
    ({"name": "a/b", "set": {"contact.friction": 0.5}}, "stages.a/b.name"),
    ({"set": {"contact.friction": 0.5}}, "stages.1.name: missing"),
]


@pytest.mark.parametrize("stage, message", BAD, ids=[m for _, m in BAD])
def test_a_bad_stage_is_one_design_error_naming_it(stage, message):
    with pytest.raises(DesignError) as e:
        parse_design(_staged(CLOSE, stage), "g.toml")
    assert str(e.value).startswith("g.toml: ") and message in str(e.value) and "\n" not in str(e.value)


def test_duplicate_stage_names_too_many_stages_and_stages_in_a_run_in_time_are_refused():
    with pytest.raises(DesignError, match=r"stages\.close\.name: duplicate name 'close' in stages"):
        parse_design(_staged(CLOSE, CLOSE), "g.toml")
    d = _staged(CLOSE)
    d["dynamics"] = {"dt": 0.01, "duration": 0.1}
    with pytest.raises(DesignError, match=r"g\.toml: stages: stages are a static scenario"):
        parse_design(d, "g.toml")
    many = _staged(*({"name": f"s{i}", "set": {"contact.friction": 0.1 + i / 1000}} for i in range(101)))
    with pytest.raises(DesignError, match=r"g\.toml: stages: at most 100 stages, got 101"):
        parse_design(many, "g.toml")
    d = _staged({"name": "weigh", "set": {"gravity.acceleration": [0, -9.81]}})
    del d["gravity"]                               # no [gravity]: a stage cannot switch it on live
    with pytest.raises(DesignError, match=r"stages\.weigh\.set\.gravity\.acceleration: not a parameter"):
        parse_design(d, "g.toml")


def test_a_bad_stage_from_the_command_line_is_one_error_line_and_nothing_written(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text(toml_text(_staged(CLOSE, {"name": "lift", "set": {"pins.wrist.move": [0.0, 20.0]}})))
    run = _simulate(path, tmp_path / "out")
    assert run.returncode == 1
    assert run.stderr.strip().splitlines() == [run.stderr.strip()]
    assert run.stderr.startswith(f"error: {path}: stages.lift.set.pins.wrist.move: not a parameter")
    assert not (tmp_path / "out").exists()


def test_stages_accept_nested_and_quoted_keys_and_values_are_absolute():
    nested = _staged({"name": "close", "set": {"cables": {"left_flexor": {"contraction": 4.0}}}},
                     {"name": "open", "set": {"cables.left_flexor.contraction": 1.0}, "steps": 3})
    d = parse_design(nested, "g.toml")
    assert [(s.name, s.changes, s.steps) for s in d.stages] == [
        ("close", {"cables.left_flexor.contraction": 4.0}, None), ("open", {"cables.left_flexor.contraction": 1.0}, 3)]
    assert d.cable("left_flexor").contraction == 0.0                          # the design itself is unchanged
    assert [s.design.cable("left_flexor").contraction for s in d.stages] == [4.0, 1.0]
    assert d.stages[1].design.stages == ()
    again = parse_design(d.raw, "g.toml", ["stages.open.steps=5"])          # a stage's key by --set
    assert again.stages[1].steps == 5


@pytest.mark.slow
@pytest.mark.parametrize("name", ["gripper.toml", "finger_friction.toml", "two_fingers.toml"])
def test_every_key_a_stage_may_change_is_a_live_parameter_of_the_model(name):
    """skelfem.design.stages.live_keys (known before meshing) against the built model's parameters."""
    from skelfem import Session
    from skelfem.design import load_design
    design = load_design(GEOMETRY / name, ["mesh.size=4"])
    with Session(design) as s:
        model_keys = set(s.model.parameters())
    assert set(live_keys(design)) <= model_keys, sorted(set(live_keys(design)) - model_keys)


def test_run_stages_starts_from_rest_whatever_the_session_solved_before():
    """A Session that solved the first stage's values already still runs that stage from rest (as skelfem
    simulate does), not as a re-solve with nothing changed (0 iterations); a stage's steps = 3 takes 3."""
    from skelfem import Session

    from _designs import strip
    d = strip(contraction=0.0)
    d["stages"] = [{"name": "pull", "set": {"cables.flexor.contraction": 1.0}},
                   {"name": "more", "set": {"cables.flexor.contraction": 2.0}, "steps": 3}]
    with Session(d) as s:
        s.set({"cables.flexor.contraction": 1.0})
        assert s.solve().converged
        r = s.run_stages()
    pull, more = r.stages
    assert pull["newton_iterations"] > 0 and pull["load_steps"] == 1 and more["load_steps"] == 3
    assert r.converged and r.cables["flexor"]["contraction"] == 2.0


@pytest.mark.slow
def test_a_command_that_does_not_run_stages_says_so_once(tmp_path):
    """skelfem ik on a staged design works on the design as written and says so in one warning line."""
    from _designs import strip
    d = strip(contraction=0.0)
    d["stages"] = [{"name": "pull", "set": {"cables.flexor.contraction": 1.0}}]
    path = tmp_path / "staged.toml"
    path.write_text(toml_text(d))
    run = subprocess.run([SKELFEM, "ik", str(path), "--marker", "tip", "--target", "3", "59", "--out",
                          str(tmp_path / "ik"), "-q"], capture_output=True, text=True, env=MPI_ENV, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stderr.count("skelfem ik works on the design as written, before its [[stages]]") == 1
