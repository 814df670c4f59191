"""Soft IK and tracking on finger4: library and `skelfem ik` / `skelfem track` end to end."""
import json
from pathlib import Path

import numpy as np
import pytest

from skelfem.cli.main import main
from skelfem.analysis.control import SoftIK, body_extent, track
from skelfem.analysis.sensitivity import set_contractions, tendons
from skelfem.fem.newton import SolveReport

ROOT = Path(__file__).resolve().parents[1]
FINGER4 = str(ROOT / "geometry" / "finger4.toml")


def _tip(model):
    return model.term("markers").positions(model.u.x.array)[0].copy()


def _from_rest(session, **kw):
    session.model.u.x.array[:] = 0.0
    set_contractions(session.model, np.zeros(4))
    ik = SoftIK(session, "tip", **kw)
    ik.settle(1)
    return ik


def test_body_extent_is_the_longest_extent(finger4):
    assert body_extent(finger4.model) == pytest.approx(100.0)


def test_ik_recovers_targets_of_random_contractions(finger4):
    """Targets made by forward simulation are reached within 1e-3 x length in <= 15 solves."""
    model, solver = finger4.model, finger4.solver
    rng = np.random.default_rng(7)
    for _ in range(3):
        u_true = rng.uniform(0.0, 12.0, 4)
        model.u.x.array[:] = 0.0
        set_contractions(model, u_true)
        assert solver.solve(finger4.design.solver.steps).converged
        target = _tip(model)
        ik = _from_rest(finger4)
        res = ik.solve(target)
        assert res.reached and res.status == "reached"
        assert res.error < 1e-3 * body_extent(model)
        assert np.linalg.norm(_tip(model) - target) == pytest.approx(res.error)
        assert 1 <= res.forward_solves <= 15
        assert np.all(res.contractions >= 0.0)
        assert np.all(np.diff(res.errors) < 0)            # every accepted step lowered |y - y'|


def test_upper_bounds_hold_and_an_unreachable_target_ends_at_the_closest_pose(finger4):
    ik = _from_rest(finger4, upper={"flexor_distal": 2.0, "flexor_middle": 2.0})
    res = ik.solve([-40.0, 75.0])                          # needs far more flexion than 2 mm
    assert not res.reached and res.status in ("stalled", "max_solves")
    assert res.contractions[0] <= 2.0 + 1e-12 and res.contractions[1] <= 2.0 + 1e-12
    assert max(res.contractions[:2]) > 1.9                 # pressed against the bound
    assert res.error < res.errors[0] - 10.0                # but much closer than at rest
    with pytest.raises(KeyError, match="not a tendon"):
        SoftIK(finger4, "tip", upper={"lig1_palmar": 1.0})
    with pytest.raises(KeyError, match=r"marker 'nail' not in design \(have: tip\)"):
        SoftIK(finger4, "nail")


def test_a_failed_forward_solve_is_never_accepted(finger4, monkeypatch):
    model, solver = finger4.model, finger4.solver
    ik = _from_rest(finger4)
    ik.trial(np.array([3.0, 0.0, 0.0, 0.0]))
    ik.accept(np.array([3.0, 0.0, 0.0, 0.0]))
    x_before, y_before = model.u.x.array.copy(), ik.position()

    def failing(steps=1, start=0.0, end=1.0):
        model.set_factor(0.0)
        model.u.x.array[:] += 1.0                          # garbage that must not survive
        return SolveReport(False, "max_iterations")
    monkeypatch.setattr(solver, "solve", failing)
    assert not ik.trial(np.array([9.0, 0.0, 0.0, 0.0]))
    assert np.array_equal(model.u.x.array, x_before) and model.factor == 1.0
    assert np.allclose(ik.u, [3.0, 0.0, 0.0, 0.0]) and tendons(model)[0].cable.contraction == 3.0
    assert model.parameters()["cables.flexor_distal.contraction"] == 3.0
    res = ik.solve([-20.0, 85.0], max_solves=3)
    assert res.status == "max_solves" and res.failed_solves == 3 and not res.reached
    assert np.allclose(res.position, y_before) and np.allclose(res.contractions, [3.0, 0.0, 0.0, 0.0])


def test_tracking_a_short_line(finger4):
    ik = _from_rest(finger4)
    targets = np.linspace([0.0, 90.0], [12.0, 90.0], 4)
    seen = []
    results = track(ik, targets, lambda i, r: seen.append(i))
    assert seen == [0, 1, 2, 3]
    errors = np.array([r.error for r in results])
    assert errors.max() < 0.01 * body_extent(finger4.model)
    assert all(r.reached for r in results)
    assert sum(r.forward_solves for r in results[1:]) <= 4 * 3   # warm starts: a few solves each


# -- command line ------------------------------------------------------------------------------------
def test_cli_ik_unreachable_target_is_not_an_error(tmp_path, capsys, picture):
    out = tmp_path / "ik"
    code = main(["ik", FINGER4, "--marker", "tip", "--target", "10", "150", "--set", "mesh.size=4",
                 "--out", str(out), "-q"])
    assert code == 0
    res = json.loads((out / "ik.json").read_text())
    assert res["reached"] is False and res["error"] > 150.0 - 100.0
    assert set(res["contractions"]) == {"flexor_distal", "flexor_middle", "extensor_distal", "extensor_middle"}
    assert np.linalg.norm(np.subtract(res["position"], res["target"])) == pytest.approx(res["error"])
    # straight above the rest tip (10, 99) along the finger's axis: every tendon shortens the finger,
    # so the linearised model promises no gain and the IK stops at rest without a forward solve
    assert res["status"] == "stalled" and res["forward_solves"] == 0 and res["failed_solves"] == 0
    assert res["iterations"] == 0 and res["errors"] == [pytest.approx(51.0)] and res["error"] == pytest.approx(51.0)
    assert res["position"] == pytest.approx([10.0, 99.0], abs=1e-9)
    assert all(u == 0.0 for u in res["contractions"].values())
    # the IK's time (a Jacobian at least) is real and part of the run's total
    assert 0 < res["time"] == res["timings"]["ik"] < res["timings"]["total"]
    assert res["timings"]["initial_solve"] > 0 and res["timings"]["mesh"] > 0
    picture(out / "ik.png", 600, 700)
    assert not list(out.glob(".*"))                        # no temporary files left behind
    assert capsys.readouterr().out == ""


def test_cli_ik_reaches_and_honours_bounds(tmp_path, capsys):
    out = tmp_path / "ik"
    code = main(["ik", FINGER4, "--marker", "tip", "--target", "-15", "88", "--set", "mesh.size=4",
                 "--max-contraction", "flexor_distal=8", "--out", str(out)])
    assert code == 0
    res = json.loads((out / "ik.json").read_text())
    assert res["reached"] is True and res["error"] < res["tol"] == pytest.approx(0.1)
    assert res["contractions"]["flexor_distal"] <= 8.0 and res["max_contraction"]["flexor_distal"] == 8.0
    assert "reached" in capsys.readouterr().out


@pytest.mark.parametrize("argv, message", [
    (["--marker", "nail", "--target", "0", "90"], "marker 'nail' not in design (have: tip)"),
    (["--marker", "tip", "--target", "0", "90", "--max-contraction", "lig1_palmar=3"], "not a tendon"),
    (["--marker", "tip", "--target", "0", "90", "--max-contraction", "flexor_distal"], "TENDON=MM"),
    (["--marker", "tip", "--target", "0", "90", "1"], "--target"),
])
def test_cli_ik_bad_input_is_one_line_and_writes_nothing(tmp_path, capsys, argv, message):
    out = tmp_path / "ik"
    assert main(["ik", FINGER4, "--set", "mesh.size=4", "--out", str(out), "-q", *argv]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and message in err[0]
    assert not out.exists()


def test_cli_track_line_writes_csv_json_png(tmp_path, capsys, picture):
    out = tmp_path / "track"
    code = main(["track", FINGER4, "--marker", "tip", "--line", "0", "90", "10", "90", "--steps", "3",
                 "--set", "mesh.size=4", "--out", str(out)])
    assert code == 0
    printed = capsys.readouterr().out.strip().splitlines()
    assert sum("target (" in line for line in printed) == 3
    lines = (out / "track.csv").read_text().strip().splitlines()
    assert lines[0].split(",")[:7] == ["step", "target_x", "target_y", "x", "y", "error", "reached"]
    assert lines[0].split(",")[-2:] == ["forward_solves", "seconds"] and "flexor_distal" in lines[0]
    rows = np.array([[float(v) for v in line.split(",")] for line in lines[1:]])
    assert len(rows) == 3 and np.allclose(rows[:, 1], [0, 5, 10]) and np.allclose(rows[:, 2], 90)
    assert np.allclose(np.hypot(rows[:, 3] - rows[:, 1], rows[:, 4] - rows[:, 2]), rows[:, 5], atol=1e-5)
    assert rows[:, 5].max() < 0.01 * 100.0
    summary = json.loads((out / "track.json").read_text())
    assert summary["targets"] == 3 and summary["reached"] == 3
    assert summary["error"]["max"] == pytest.approx(rows[:, 5].max(), rel=1e-4)
    picture(out / "track.png", 600, 700)


def test_cli_track_csv_targets_and_bad_csv(tmp_path, capsys):
    good = tmp_path / "path.csv"
    good.write_text("x,y\n5, 92\n8, 91\n")
    out = tmp_path / "track"
    assert main(["track", FINGER4, "--marker", "tip", "--csv", str(good), "--set", "mesh.size=4",
                 "--out", str(out), "-q"]) == 0
    assert json.loads((out / "track.json").read_text())["targets"] == 2
    assert capsys.readouterr().out == ""
    bad = tmp_path / "bad.csv"
    bad.write_text("x,y\n5, 92\n8, oops\n")
    out2 = tmp_path / "track2"
    assert main(["track", FINGER4, "--marker", "tip", "--csv", str(bad), "--set", "mesh.size=4",
                 "--out", str(out2), "-q"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "line 3" in err[0]
    assert not out2.exists()


def test_ik_never_asks_for_more_contraction_than_a_tendon_can_give():
    """A soft, long strip pulled towards a point far below its base: the answer stays within
    MAX_SHORTENING of the tendon's length (it used to exceed the whole cable), and simulate takes it."""
    from _designs import strip

    from skelfem import Session, parse_design
    from skelfem.analysis.control import MAX_SHORTENING
    d = strip(length=30.0, size=4.0, contraction=0.0, tendon_offset=4.0, k=50.0)
    with Session(d) as s:
        s.solve()
        ik = SoftIK(s, "tip", max_solves=12)
        assert ik.upper[0] == pytest.approx(MAX_SHORTENING * 30.0)                  # it used to be inf
        assert SoftIK(s, "tip", upper={"flexor": 1e3}).upper[0] == pytest.approx(MAX_SHORTENING * 30.0)
        assert SoftIK(s, "tip", upper={"flexor": 5.0}).upper[0] == 5.0
        res = ik.solve(np.array([60.0, -200.0]))
    assert res.contractions[0] <= MAX_SHORTENING * 30.0 + 1e-9
    parse_design(d, overrides=[f"cables.flexor.contraction={res.contractions[0]!r}"])   # simulate accepts it
