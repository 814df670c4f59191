"""skelfem optimize-design: the task file checked before meshing, and a short run that writes its files."""
import json

import pytest

from skelfem.cli.main import main

FINGER = "geometry/finger.toml"
GOOD = """
[[variables]]
key = "bones.distal.offset.x"
bounds = [-1.5, 1.5]

[[variables]]
key = "cables.flexor.path[2].x"
bounds = [8.0, 10.0]

[[objectives]]
kind = "reach"
marker = "tip"
targets = [{ set = { "cables.flexor.contraction" = 8.0 }, at = [-30.0, 80.0] }]

[[objectives]]
kind = "tension"
cable = "flexor"
weight = 0.01

[optimizer]
max_evaluations = 6
"""


def _run(tmp_path, task_text, design=FINGER):
    task = tmp_path / "task.toml"
    task.write_text(task_text)
    out = tmp_path / "out"
    return main(["optimize-design", design, "--task", str(task), "--out", str(out), "-q"]), out


@pytest.mark.parametrize("edit, message", [
    (("bones.distal.offset.x", "bones.nope.offset.x"), "variables[0].key: bones.nope.offset.x: no bone 'nope'"),
    (("cables.flexor.path[2].x", "cables.flexor.path[7].x"), "variables[1].key: cables.flexor.path[7].x: no such vertex"),
    (("bounds = [8.0, 10.0]", "bounds = [10.0, 12.0]"), "variables[1].bounds: [10, 12] exclude the start value 9"),
    (("bounds = [-1.5, 1.5]", "bounds = [1.5, -1.5]"), "variables[0].bounds: lower 1.5 must be below upper -1.5"),
    (('marker = "tip"', 'marker = "nail"'), "objectives[0].marker: 'nail' not in the design"),
    (('"cables.flexor.contraction" = 8.0', '"cables.flexor.colour" = 8.0'), "objectives[0].targets[0].set.cables.flexor.colour"),
    (('"cables.flexor.contraction" = 8.0', '"cables.nope.contraction" = 8.0'), "objectives[0].targets[0].set.cables.nope.contraction"),
    (('"cables.flexor.contraction" = 8.0', '"bones.distal.outline" = [[6, 74], [14, 74], [14, 90]]'), "a target sets loads only"),
    (('set = { "cables.flexor.contraction" = 8.0 }', 'set = 8.0'), "objectives[0].targets[0].set: expected a table"),
    (("max_evaluations = 6", "max_evaluations = 0"), "optimizer.max_evaluations: expected an integer from 1"),
    (("[optimizer]", "[constraints]\nmin_wall = 1.0\n[optimizer]\nmethod = 1"), "optimizer.method: unknown key"),
])
def test_bad_task_is_one_error_line_before_meshing(tmp_path, capsys, edit, message):
    rc, out = _run(tmp_path, GOOD.replace(*edit))
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1
    assert len(err) == 1 and err[0].startswith("error: ") and message in err[0], err
    assert not out.exists()


def test_a_task_with_no_objective_is_refused(tmp_path, capsys):
    rc, out = _run(tmp_path, GOOD.split("[[objectives]]")[0])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1 and "objectives: missing" in err[0]
    assert not out.exists()


def test_a_design_the_gradient_does_not_cover_is_refused(tmp_path, capsys):
    rc, out = _run(tmp_path, GOOD, design="geometry/finger_friction.toml")
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1 and "friction" in err[0], err
    assert not out.exists()


@pytest.mark.slow
def test_short_run_improves_and_writes_a_valid_design(tmp_path):
    from skelfem.design.parse import load_design
    rc, out = _run(tmp_path, GOOD)
    assert rc == 0
    res = json.loads((out / "optimize_design.json").read_text())
    assert res["optimum"] <= res["start"]
    assert 1 <= res["evaluations"] <= 6
    assert res["fresh"] == pytest.approx(res["optimum"], rel=0.05)      # a moved mesh against a fresh one
    best = load_design(out / "optimized.toml")
    final = {v["key"]: v["final"] for v in res["variables"]}
    assert best.cable("flexor").path[2][0] == pytest.approx(final["cables.flexor.path[2].x"]
                                                             + final["bones.distal.offset.x"])
    assert "# A cable-driven finger" in (out / "optimized.toml").read_text()     # the file's comments kept
    assert (out / "history.csv").read_text().splitlines()[0] == "solves,objective,gradient_norm,constraint_violation"


def test_a_turned_pin_is_refused_before_meshing(tmp_path, capsys):
    """A turned pin's displacement depends on where its nodes are, which the design gradient does not follow."""
    task = tmp_path / "task.toml"
    task.write_text(GOOD)
    out = tmp_path / "out"
    rc = main(["optimize-design", FINGER, "--task", str(task), "--out", str(out), "-q",
               "--set", "pins.base.rotate={angle = 5.0, centre = [10.0, 0.0]}"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1 and "pins.base.rotate: design gradients do not cover turned pins" in err[0], err
    assert not out.exists()


@pytest.mark.slow
def test_trial_designs_the_rules_refuse_send_the_line_search_back(tmp_path, capsys):
    """Wide bounds: L-BFGS-B's first step pushes the distal bone through the outline (a design the rules
    refuse); the run steps back and improves instead of stopping at the start."""
    task = GOOD.split("[[variables]]")[0] + """
[[variables]]
key = "bones.distal.offset.x"
bounds = [-20.0, 20.0]

[[objectives]]
kind = "reach"
marker = "tip"
targets = [{ set = { "cables.flexor.contraction" = 8.0 }, at = [-60.0, 60.0] }]

[optimizer]
max_evaluations = 8
"""
    rc, out = _run(tmp_path, task)
    assert rc == 0
    res = json.loads((out / "optimize_design.json").read_text())
    assert res["optimum"] < 0.95 * res["start"], res
    assert res["variables"][0]["final"] != 0.0


def test_a_refused_move_leaves_the_session_on_its_mesh():
    """A design value the morph or the rules refuse raises ValueError before the session is edited: the
    mesh stays the start mesh moved (no re-mesh behind the gradient's back) and the next gradient works."""
    import numpy as np

    from skelfem.analysis.design_gradient import DesignGradient, MarkerTarget
    from skelfem.session import Session
    with Session(FINGER) as session:
        dg = DesignGradient(session, ["bones.distal.offset.x"])
        dg.solve()
        x = session.model.mesh.geometry.x.copy()
        with pytest.raises(ValueError):
            dg.solve(np.array([15.0]))
        assert np.array_equal(session.model.mesh.geometry.x, x)
        dg.check_mesh()
        J, g = dg.gradient(MarkerTarget("tip", (-20.0, 80.0)))
        assert np.isfinite(g).all()
