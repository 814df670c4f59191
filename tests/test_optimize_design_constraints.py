"""optimize-design's fabrication constraints (skelfem.design.clearances) and its resumable runs."""
import json
import os
import signal
import subprocess
import time

import numpy as np
import pytest

from _hardening import ENV, ROOT, SKELFEM
from skelfem.cli.main import main

FINGER = str(ROOT / "geometry" / "finger.toml")
CONSTRAINTS = {"min_wall": 3.5, "min_gap": 5.0, "min_cable_wall": 1.5, "min_cable_gap": 2.0, "min_entry_angle": 30.0}
# one variable the reach wants well past the silicone skin's limit: the distal bone to the dorsal side,
# where min_wall = 3.5 mm (of the 6 the hand-made finger keeps) stops it at +2.5 mm
PUSH = """
[[variables]]
key = "bones.distal.offset.x"
bounds = [-6.0, 6.0]

[[objectives]]
kind = "reach"
marker = "tip"
targets = [{ set = { "cables.flexor.contraction" = 8.0 }, at = [-30.0, 80.0] }]

[constraints]
min_wall = 3.5

[optimizer]
max_evaluations = 12
"""


def _design():
    from skelfem.design.parse import load_design
    return load_design(FINGER)


def test_clearances_are_exact_derivatives_of_their_distances():
    """Every point-segment distance's Jacobian against central differences at a design off the symmetric
    places (where a nearest point changes from a segment's inside to its end, d is C1, not C2): the
    difference falls as h^2."""
    from skelfem.design.clearances import Clearances, start_points
    d = _design()
    c = Clearances(d, CONSTRAINTS)
    rng = np.random.default_rng(1)
    X = start_points(d) + 0.05 * rng.normal(size=start_points(d).shape)
    dX = rng.normal(size=X.shape)
    exact = np.einsum("mij,ij->m", c.jacobian(X), dX)
    errors = [np.abs((c.values(X + h * dX) - c.values(X - h * dX)) / (2 * h) - exact).max() for h in (1e-3, 1e-4)]
    assert errors[1] < 1e-6 and errors[1] < errors[0] / 50, errors
    assert {g.key for g in c.groups} == {*CONSTRAINTS, "end_wall", "entry_corners"}


def test_constraint_jacobian_in_the_design_variables_matches_finite_differences():
    """Through the handles (a bone's turn moves its points nonlinearly) and the scaling to the bounds."""
    from skelfem.analysis.design_optimize import DesignConstraints
    from skelfem.analysis.handles import DesignHandles
    from skelfem.design.design_task import parse_task
    d = _design()
    keys = ["bones.middle.angle", "bones.distal.offset.x", "bones.distal.angle", "cables.flexor.path[1].y",
            "cables.flexor.path[2].x", "bones.proximal.outline[1].x"]
    data = {"variables": [{"key": k, "bounds": [-40.0, 100.0]} for k in keys],
            "objectives": [{"kind": "reach", "marker": "tip", "targets": [{"at": [0.0, 0.0]}]}],
            "constraints": CONSTRAINTS}
    data["variables"][-1]["bounds"] = [10.0, 16.0]
    task = parse_task(data, "task.toml", d)
    width = np.array([v.upper - v.lower for v in task.variables])
    con = DesignConstraints(task, DesignHandles(d, keys), width)
    rng = np.random.default_rng(2)
    x = 0.01 * rng.normal(size=len(keys))
    dx = rng.normal(size=len(keys))
    exact = con.jacobian(x) @ dx
    h = 1e-5
    fd = (con.values(x + h * dx) - con.values(x - h * dx)) / (2 * h)
    assert np.abs(fd - exact).max() < 1e-5 * (1 + np.abs(exact).max()), np.abs(fd - exact).max()


@pytest.mark.parametrize("constraints, message", [
    ("min_wall = 6.5", "constraints.min_wall: bone 'proximal' and the body's outline are 6 mm apart in the start "
                       "design, less than the 6.5 mm needed"),
    ("min_gap = 6.5", "constraints.min_gap: bones 'proximal' and 'middle' are 6 mm apart"),
    ("min_cable_wall = 3.5", "constraints.min_cable_wall: cables.flexor.path[1] and the body's outline are 3 mm apart"),
    ("min_cable_gap = 1.0", "constraints.min_cable_gap: 1 mm is less than the 1.9 mm skelfem fabricate needs"),
    ("min_wall = -1.0", "constraints.min_wall: expected a length in (0, 100] mm"),
    ("min_wall = nan", "constraints.min_wall: expected a finite number"),
    ("min_entry_angle = 95", "constraints.min_entry_angle: expected an angle in (0, 90) degrees, got 95"),
    ("thickness = 1.0", "constraints.thickness: unknown key"),
])
def test_constraints_the_start_cannot_meet_are_one_error_line(tmp_path, capsys, constraints, message):
    task = tmp_path / "task.toml"
    task.write_text(PUSH.replace("min_wall = 3.5", constraints))
    out = tmp_path / "out"
    rc = main(["optimize-design", FINGER, "--task", str(task), "--out", str(out), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1 and err[0].startswith("error: ") and message in err[0], err
    assert not out.exists() and os.listdir(tmp_path) == ["task.toml"]


def _run(tmp_path, text, out="out", *extra):
    task = tmp_path / "task.toml"
    task.write_text(text)
    return main(["optimize-design", FINGER, "--task", str(task), "--out", str(tmp_path / out), "-q", *extra])


@pytest.mark.slow
def test_the_fabrication_constraint_is_what_stops_the_optimiser(tmp_path):
    """Without [constraints] the reach pushes the distal bone past +2.5 mm (the bound is 6); with min_wall
    = 3.5 SLSQP stops it on the constraint, and the result keeps every clearance. The free run needs 8 of the
    12 evaluations to pass +2.6 (3.09; 3.11 after 12)."""
    free_task = PUSH.replace("min_wall = 3.5", "").replace("max_evaluations = 12", "max_evaluations = 8")
    assert _run(tmp_path, free_task, "free") == 0
    free = json.loads((tmp_path / "free" / "optimize_design.json").read_text())
    assert free["variables"][0]["final"] > 2.6 and free["clearances"] == {}
    assert _run(tmp_path, PUSH) == 0
    res = json.loads((tmp_path / "out" / "optimize_design.json").read_text())
    assert res["variables"][0]["final"] == pytest.approx(2.5, abs=1e-4)
    assert -1e-6 <= res["clearances"]["min_wall"] < 1e-4          # on the constraint, to SLSQP's precision
    assert res["optimum"] < res["start"]


@pytest.mark.slow
def test_an_interrupted_run_resumes_from_its_checkpoint(tmp_path):
    """SIGINT after two evaluations: exit 130, no output folder, the checkpoint beside it; the rerun reads the
    evaluations back without solving them, goes on, publishes, and removes the checkpoint."""
    task = tmp_path / "task.toml"
    task.write_text(PUSH)
    out = tmp_path / "out"
    args = [SKELFEM, "optimize-design", FINGER, "--task", str(task), "--out", str(out), "-q"]
    checkpoint = tmp_path / ".out.optimize-design-partial.json"
    proc = subprocess.Popen(args, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None:
        try:
            if len(json.loads(checkpoint.read_text())["entries"]) >= 2:
                break
        except (OSError, ValueError, KeyError):
            pass
        time.sleep(0.02)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    if proc.returncode == 0:
        pytest.skip("the run finished before it could be interrupted")
    assert proc.returncode == 130 and err.strip().splitlines() == ["error: interrupted"], err
    assert not out.exists()
    done = json.loads(checkpoint.read_text())["entries"]
    assert len(done) >= 2
    res = subprocess.run(args[:-1], env=ENV, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert f"resuming: {len(done)} evaluations of an interrupted run are read back" in res.stdout
    summary = json.loads((out / "optimize_design.json").read_text())
    assert summary["resumed_after"] == len(done)
    assert summary["variables"][0]["final"] == pytest.approx(2.5, abs=1e-4)
    assert not checkpoint.exists()
    history = (out / "history.csv").read_text().splitlines()
    assert [float(v) for v in history[1].split(",")[:2]] == [1.0, pytest.approx(done[0]["J"], rel=1e-12)]


def test_a_checkpoint_of_another_task_or_a_broken_one_is_ignored(tmp_path):
    from skelfem.cli.optimize_design import Checkpoint
    from skelfem.design.design_task import parse_task
    from skelfem.design.parse import read_toml
    task_file = tmp_path / "task.toml"
    task_file.write_text(PUSH)
    d = _design()
    task = parse_task(read_toml(task_file, "task file"), str(task_file), d)
    out = tmp_path / "out"
    first = Checkpoint(out, d, task)
    assert first.entries == [] and first.path == tmp_path / ".out.optimize-design-partial.json"
    entry = {"x": [0.125], "J": 3.0, "g": [1.5], "refused": None, "solves": 1}
    first.add(entry)
    first.add({"x": [0.25], "J": None, "g": None, "refused": "the morph refused it", "solves": 0})
    assert Checkpoint(out, d, task).resumed == 2 and Checkpoint(out, d, task).entries[0] == entry
    other = parse_task(read_toml(task_file, "task file"), str(task_file), d)
    other = other.__class__(other.source, other.variables, other.objectives, 99, (("min_wall", 3.0),))
    assert Checkpoint(out, d, other).entries == []                    # other constraints: start afresh
    assert Checkpoint(out, d, task.__class__(task.source, task.variables, task.objectives, 99,
                                             task.constraints)).resumed == 2     # a larger budget goes on
    for broken in ("{", '{"key": 1}', json.dumps({"key": first.key, "entries": [{"x": [1.0, 2.0]}]})):
        first.path.write_text(broken)
        assert Checkpoint(out, d, task).entries == [], broken
    first.remove()
    assert not first.path.exists()


def test_a_grazing_channel_at_the_start_is_refused_at_fabricates_angle(tmp_path, capsys):
    """The flexor entering the distal bone at 17 degrees (fabricate would print a sheath): one error line."""
    import math

    from skelfem.design.clearances import GRAZING_ANGLE
    from skelfem.fabricate.surfaces import GRAZING
    assert math.sin(math.radians(GRAZING_ANGLE)) == pytest.approx(GRAZING)
    rc = _run(tmp_path, PUSH.replace("min_wall = 3.5", "min_wall = 3.5\nmin_entry_angle = 30.0"), "out",
              "--set", "cables.flexor.path=[[3, 0], [2, 70], [7, 86]]")
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1, err
    assert "constraints.min_entry_angle: the channel of cables.flexor enters bone 'distal' at 17.4 degrees in the " \
           "start design, less than the 30 needed" in err[0], err
    assert not (tmp_path / "out").exists()


CROSSED = ["cables.lig1_palmar.path=[[7.5, 34], [12.5, 48]]", "cables.lig1_dorsal.path=[[12.5, 34], [7.5, 48]]"]


def test_crossing_cables_break_the_cable_gap_whatever_their_vertices_distances():
    """Two ligaments crossed as an X: every vertex lies 4.7 mm from the other sketch, so the point-segment
    distances alone would pass a 2 mm gap; the crossing counts as a negative distance, whose Jacobian is the
    exact derivative of the signed value while the sketches stay crossed (central differences)."""
    from skelfem.design.clearances import Clearances, start_points
    from skelfem.design.parse import load_design
    d = load_design(FINGER, CROSSED)
    for constraints, key in (({"min_cable_gap": 2.0}, "min_cable_gap"), ({"min_wall": 3.5}, "cable_apart")):
        c = Clearances(d, constraints)
        X = start_points(d)
        (group, least), *_ = c.worst(X)
        assert group.key == key and least == pytest.approx(-5.0 * 14.0 / np.hypot(5.0, 14.0)), (group, least)
        assert "cables 'lig1_palmar' and 'lig1_dorsal'" in group.what and group.shortfall(least).endswith(
            "cross in the start design")
        rng = np.random.default_rng(3)
        X = X + 0.05 * rng.normal(size=X.shape)          # off the X's symmetry, where the four distances tie
        dX = rng.normal(size=X.shape)
        exact = np.einsum("mij,ij->m", c.jacobian(X), dX)
        h = 1e-6
        fd = (c.values(X + h * dX) - c.values(X - h * dX)) / (2 * h)
        assert np.abs(fd - exact).max() < 1e-6, np.abs(fd - exact).max()
    # uncrossed (the same two ligaments side by side, the finger's own), nothing is short
    assert Clearances(_design(), {"min_cable_gap": 2.0}).worst(start_points(_design())) == []


@pytest.mark.parametrize("constraints, message", [
    ("min_cable_gap = 2.0", "constraints.min_cable_gap: cables 'lig1_palmar' and 'lig1_dorsal' cross in the start "
                            "design"),
    ("min_wall = 3.5", "constraints.fabrication: cables 'lig1_palmar' and 'lig1_dorsal' (their holes' radii + "
                       "fabrication.min_wall) cross in the start design"),
])
def test_a_start_with_crossing_cables_is_one_error_line(tmp_path, capsys, constraints, message):
    rc = _run(tmp_path, PUSH.replace("min_wall = 3.5", constraints), "out", *[a for o in CROSSED for a in ("--set", o)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1 and message in err[0], err
    assert not (tmp_path / "out").exists()
