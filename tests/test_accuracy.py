"""--tol: Richardson estimates on the design's own meshes, and runs that meet the tolerance they report."""
import json
import math
from pathlib import Path

import numpy as np
import pytest

from skelfem.accuracy import ladder as ladder_rules, tol as accuracy
from skelfem.design import resources
from skelfem.accuracy.ladder import Level, observed_rate, richardson
from skelfem.cli.main import main

from _designs import strip, toml_text

GEOMETRY = Path(__file__).resolve().parents[1] / "geometry"


EXACT = np.array([[1.0, 2.0]])


def _levels(sizes, C=0.3, r=1.6, exact=EXACT):
    """Levels whose marker error is exactly C h^r (along a fixed direction)."""
    out = []
    for h in sizes:
        out.append(Level(h, 0, 0, 0.0, exact + C * h ** r * np.array([[0.6, 0.8]])))
        if len(out) > 1:
            out[-1].estimate, out[-1].rate = richardson(out)
            out[-1].change = float(np.linalg.norm(out[-1].markers - out[-2].markers))
    return out


@pytest.mark.parametrize("sizes", [(4.0, 2.0, 1.0), (4.0, 2.0, 1.0, 0.37), (3.0, 3 / math.sqrt(2), 1.5)])
def test_richardson_is_exact_for_a_power_law(sizes):
    levels = _levels(sizes)
    last = levels[-1]
    assert last.rate == pytest.approx(1.6, rel=1e-6)
    assert last.estimate == pytest.approx(0.3 * sizes[-1] ** 1.6, rel=1e-6)


def test_the_rate_is_clipped_and_differences_that_grow_give_the_smallest():
    assert observed_rate((4.0, 2.0, 1.0), (1.0, 1.0 / 2 ** 3)) == ladder_rules.R_MAX
    assert observed_rate((4.0, 2.0, 1.0), (1.0, 2.0)) == ladder_rules.R_MIN      # not converging
    assert observed_rate((4.0, 2.0, 1.0), (0.0, 0.0)) == ladder_rules.R_MIN
    two = _levels((4.0, 2.0))[-1]
    assert two.rate == ladder_rules.R_TWO_LEVELS                                  # two levels: a rate is assumed


def test_an_oscillating_ladder_is_bounded_by_half_its_spread():
    """Answers that overshoot (e = C_k h^r with C_k changing sign) fool Richardson: its estimate from the
    last change is below the true error; half the spread of the last three answers is not."""
    levels = []
    for h, x in zip((4.0, 2.0, 1.0), (-0.1, 0.03, 0.02)):   # the limit is 0: the finest is 0.02 off
        levels.append(Level(h, 0, 0, 0.0, np.array([[x, 0.0]])))
        if len(levels) > 1:
            levels[-1].change = float(np.linalg.norm(levels[-1].markers - levels[-2].markers))
    true_error = 0.02
    x = [lv.markers[0, 0] for lv in levels]
    assert ladder_rules.oscillation(levels) == pytest.approx(0.5 * (max(x) - min(x)))
    estimate, _ = richardson(levels)
    assert estimate == pytest.approx(0.5 * (max(x) - min(x)))
    assert estimate >= true_error
    d = abs(x[2] - x[1])
    assert d / (2.0 ** ladder_rules.R_MAX - 1.0) < true_error   # what Richardson alone would have said
    monotone = _levels((4.0, 2.0, 1.0))
    assert ladder_rules.oscillation(monotone) == 0.0         # answers from one side: Richardson alone
    two_markers = [Level(lv.size, 0, 0, 0.0, np.vstack([lv.markers, m.markers]))
                   for lv, m in zip(levels, monotone)]
    assert ladder_rules.oscillation(two_markers) == ladder_rules.oscillation(levels)   # the reversing marker's spread


def test_next_size_aims_below_the_tolerance_within_bounds():
    lv = Level(1.0, 0, 0, 0.0, np.zeros((1, 2)), change=0.1, rate=2.0, estimate=0.1)
    h = ladder_rules.next_size(lv, 0.1, 3)                                       # 3D: between h/2 and h/sqrt 2
    assert h == pytest.approx((0.1 / (ladder_rules.MARGIN * ladder_rules.AIM * 0.1)) ** 0.5)
    assert ladder_rules.next_size(lv, 1e-9, 3) == 0.5                            # at most 2x finer
    assert ladder_rules.next_size(lv, 0.29, 3) == pytest.approx(1 / np.sqrt(2))  # at least one ratio
    assert ladder_rules.next_size(lv, 1e-9, 2) == ladder_rules.next_size(lv, 0.29, 2) == 0.5   # 2D: halving


class _Solved:
    """What next_level reads of a Result."""

    def __init__(self, dofs, positions):
        self.dofs, self.newton_iterations = dofs, 3
        self.markers = {"tip": {"position": positions}}


def test_a_levels_size_is_measured_by_its_dofs_not_the_size_asked_for():
    """Gmsh may make a mesh finer (or the same) than asked: h_k = h_{k-1} (N_{k-1} / N_k)^(1/dim)."""
    a = ladder_rules.next_level([], 2.83, _Solved(5391, [0.0, 0.0, 0.0]), 0.0)
    assert a.h == 2.83
    b = ladder_rules.next_level([a], 2.0, _Solved(7869, [0.01, 0.0, 0.0]), 0.0)
    assert b.h == pytest.approx(2.83 * (5391 / 7869) ** (1 / 3))             # 2.49, not 2.0
    assert b.estimate == pytest.approx(0.01 / (2.83 / b.h - 1.0))            # r = 1 with two levels
    flat = ladder_rules.next_level([], 2.0, _Solved(1000, [0.0, 0.0]), 0.0)
    twice = ladder_rules.next_level([flat], 1.0, _Solved(4000, [0.01, 0.0]), 0.0)
    assert twice.h == pytest.approx(1.0)                                     # 2D: 4x the DOFs, half h
    lv = Level(1.0, 0, 0, 0.0, np.zeros((1, 2)), h=0.8, change=0.1, rate=2.0, estimate=0.1)
    assert ladder_rules.next_size(lv, 1e-9, 3) == 0.5                            # the jump scales what is asked


class _FakeSession:
    """A session whose solve on a mesh of size h has (3D) DOFs dofs(h) and a tip at position(h, k),
    k the solve's number; no mesh is made."""
    comm = type("C", (), {"size": 1})()
    solved = False

    def __init__(self, dofs, position):
        from skelfem.design import load_design
        self.design = ladder_rules.at_size(load_design(GEOMETRY / "pillar3d.toml"), 4.0)
        self.model, self.sizes, self.dofs, self.position = None, [], dofs, position

    def edit(self, design, size=None):
        self.design = design

    def solve(self):
        h = float(self.design.mesh.size)
        self.sizes.append(h)
        return type("R", (), {"converged": True, "dofs": self.dofs(h), "newton_iterations": 2,
                              "markers": {"tip": {"position": self.position(h, len(self.sizes) - 1)}}})()


def test_a_repeated_mesh_replaces_the_last_level(monkeypatch):
    """On a body barely larger than h, h = 4 and 2.83 give one mesh: it is one level (labelled 2.83)."""
    monkeypatch.setattr(accuracy, "ladder_zones", lambda model, design, h0: None)
    session = _FakeSession(lambda h: 1000 if h > 2.5 else int(1000 * (2.83 / h) ** 3),
                           lambda h, k: [0.01 * h ** 2, 0.0, 0.0])
    _, acc = accuracy.refine(session, tol=1e-3)
    sizes = [lv["size"] for lv in acc["levels"] if not lv["twin"]]
    assert sizes[0] == pytest.approx(2.828427) and 4.0 not in sizes
    assert all(b["dofs"] > a["dofs"] for a, b in zip(acc["levels"], acc["levels"][1:]))


def test_a_twin_mesh_measures_the_scatter_richardson_cannot_see(monkeypatch):
    """Answers e = C h^1.8 plus a mesh-to-mesh scatter: the ladder alone would stop (and be wrong); the twin
    (a mesh of 0.95 h) sees the scatter, the ladder goes on, and the answer's estimate covers its error."""
    monkeypatch.setattr(accuracy, "ladder_zones", lambda model, design, h0: None)
    session = _FakeSession(lambda h: int(1000 * (4.0 / h) ** 3), None)

    def position(h, k):                          # the ladder's meshes converge cleanly, every twin is off
        twin = k > 0 and h == pytest.approx(ladder_rules.TWIN * session.sizes[k - 1])
        return [1e-4 * h ** 1.8 + (0.004 * h if twin else 0.0), 0.0, 0.0]
    session.position = position
    _, acc = accuracy.refine(session, tol=0.01)
    levels = acc["levels"]
    twins = [i for i, lv in enumerate(levels) if lv["twin"]]
    assert levels[-1]["twin"] and len(twins) == 2                      # the first twin failed, the ladder went on
    first = levels[twins[0]]
    assert first["size"] == pytest.approx(ladder_rules.TWIN * levels[twins[0] - 1]["size"])
    assert ladder_rules.MARGIN * levels[twins[0] - 1]["estimate"] <= 0.01      # Richardson alone would have stopped
    assert ladder_rules.MARGIN * first["estimate"] > 0.01                       # the twin did not
    for i in twins:
        lv, ladder = levels[i], levels[i - 1]
        assert lv["estimate"] == pytest.approx(max(ladder["estimate"], lv["scatter"]))
    h = acc["size"]
    assert acc["met"] and ladder_rules.MARGIN * acc["estimated_error"] >= 1e-4 * h ** 1.8 + 0.004 * h   # its error
    assert acc["scatter"] == levels[-1]["scatter"] and session.sizes[-1] == h      # the answer is the twin


class _FailingSession(_FakeSession):
    """A _FakeSession whose solves fail below size `fails_below`: warm (a start carried over) only, or also
    from rest (``solved`` reset, as the ladder does before a second try)."""
    def __init__(self, fails_below: float, cold_too: bool):
        super().__init__(lambda h: int(1000 * (4.0 / h) ** 3), lambda h, k: [1e-4 * h ** 1.8, 0.0, 0.0])
        self.fails_below, self.cold_too, self.solved, self.tries = fails_below, cold_too, True, []

    def edit(self, design, size=None):
        self.design, self.solved = design, True          # an edit carries the last state over

    def _attempt(self, h: float) -> bool:
        self.tries.append((h, self.solved))
        return not (h < self.fails_below and (self.cold_too or self.solved))

    def solve(self):
        """As Session.solve: a warm start that fails is tried once more from rest."""
        h = float(self.design.mesh.size)
        warm = self.solved
        ok = self._attempt(h)
        if not ok and warm:
            self.solved = False
            ok = self._attempt(h)
        if not ok:
            self.solved = False
            return type("R", (), {"converged": False, "status": "inverted_elements", "dofs": self.dofs(h),
                                  "newton_iterations": 0, "markers": {}})()
        self.solved = True
        return super().solve()


def test_a_start_carried_over_that_fails_is_solved_again_from_rest(monkeypatch):
    monkeypatch.setattr(accuracy, "ladder_zones", lambda model, design, h0: None)
    session = _FailingSession(fails_below=3.0, cold_too=False)
    _, acc = accuracy.refine(session, tol=0.01)
    assert acc["met"] and acc["warning"] is None
    retried = [a for a, b in zip(session.tries, session.tries[1:]) if a[1] and b == (a[0], False)]
    assert retried and all(h < 3.0 for h, _ in retried)                        # warm failed, then from rest


def test_a_finer_level_that_fails_returns_the_level_that_met_the_tolerance(monkeypatch):
    """A level whose estimate met tol, then a finer one that fails even from rest (the ladder wanted its
    third level): the answer is the met level again, met with a warning, never a failure."""
    monkeypatch.setattr(accuracy, "ladder_zones", lambda model, design, h0: None)
    session = _FailingSession(fails_below=2.5, cold_too=True)
    result, acc = accuracy.refine(session, tol=0.05)
    assert result.converged and acc["met"]
    assert acc["size"] == pytest.approx(2.828427) and session.sizes[-1] == acc["size"]   # solved again there
    assert "failed (inverted_elements)" in acc["warning"] and acc["stop"] == acc["warning"]
    assert ladder_rules.MARGIN * acc["estimated_error"] <= 0.05
    strict = _FailingSession(fails_below=2.5, cold_too=True)
    _, acc = accuracy.refine(strict, tol=1e-6)                                   # nothing met: not met
    assert not acc["met"] and acc["warning"] is None and "failed" in acc["stop"]


def test_twin_level_takes_the_larger_of_richardson_and_the_scatter():
    level = Level(1.0, 8000, 3, 0.1, np.array([[1.0, 2.0]]), h=1.0, rate=1.5, estimate=0.01)
    res = type("R", (), {"dofs": 9000, "newton_iterations": 2, "markers": {"m": {"position": [1.0, 2.03]}}})()
    twin = ladder_rules.twin_level(level, 0.95, res, 0.2)
    assert twin.twin and twin.scatter == pytest.approx(0.03) and twin.estimate == pytest.approx(0.03)
    assert twin.h == pytest.approx((8000 / 9000) ** 0.5)                     # measured by its DOFs
    res.markers["m"]["position"] = [1.0, 2.001]
    assert ladder_rules.twin_level(level, 0.95, res, 0.2).estimate == pytest.approx(0.01)


def test_a_twin_that_gmsh_meshes_as_its_level_tries_smaller_sizes_then_warns(monkeypatch):
    """0.95, 0.95^2, 0.95^3 of the size, each the level's own mesh: the scatter (0) is not measured, and says so."""
    level = Level(2.0, 8000, 3, 0.1, np.array([[1.0, 2.0]]), h=2.0, rate=1.5, estimate=0.01)
    same = type("R", (), {"converged": True, "dofs": 8000, "newton_iterations": 1,
                          "markers": {"m": {"position": [1.0, 2.0]}}})()
    session, factors, warnings = type("S", (), {"solve": lambda self: same, "solved": True})(), [], []
    monkeypatch.setattr(accuracy.log, "warning", lambda msg, *args: warnings.append(msg % args))
    twin, _ = ladder_rules.solve_twin(session, level, factors.append)   # (the CLI's logger does not propagate)
    assert factors == pytest.approx([0.95, 0.95 ** 2, 0.95 ** 3]) and twin.size == pytest.approx(2.0 * 0.95 ** 3)
    assert twin.scatter == 0 and twin.estimate == 0.01
    assert len(warnings) == 1 and "scatter is not measured" in warnings[0]


def _strip_file(tmp_path, **kw) -> Path:
    p = tmp_path / "strip.toml"
    p.write_text(toml_text(strip(length=40.0, width=8.0, size=2.0, contraction=1.0, tendon_offset=2.0, **kw)))
    return p


def _tip(path: Path) -> np.ndarray:
    return np.asarray(json.loads(path.read_text())["markers"]["tip"]["position"], float)


@pytest.mark.slow
@pytest.mark.parametrize("tol", [0.05, 0.01])
def test_tol_run_meets_the_tolerance_it_reports_against_a_much_finer_reference(tmp_path, capsys, tol):
    design = _strip_file(tmp_path, bones=False)
    assert main(["simulate", str(design), "--out", str(tmp_path / "tol"), "--no-picture", "--tol", str(tol)]) == 0
    res = json.loads((tmp_path / "tol" / "result.json").read_text())
    a = res["accuracy"]
    assert a["met"] and ladder_rules.MARGIN * a["estimated_error"] <= tol and len(a["levels"]) >= 3
    assert res["degree"] == 2 and res["dofs"] == a["dofs"] and a["size"] == a["levels"][-1]["size"]
    assert "--tol" in capsys.readouterr().out
    assert main(["simulate", str(design), "--out", str(tmp_path / "ref"), "-q", "--no-picture",
                 "--set", "mesh.degree=2", "--set", "mesh.size=0.2"]) == 0
    err = float(np.linalg.norm(_tip(tmp_path / "tol" / "result.json") - _tip(tmp_path / "ref" / "result.json")))
    assert err <= tol


@pytest.mark.parametrize("E_bone, tol, rigid, adaptive", [
    (1000.0, 0.5, True, False), (1000.0, 0.05, False, False), (3.0, 0.5, False, False),
    (1000.0, 0.5, True, True), (1000.0, 0.05, False, True)])        # --adaptive chooses them the same way
def test_tol_makes_bones_rigid_where_their_difference_is_well_below_it(tmp_path, capsys, E_bone, tol, rigid,
                                                                        adaptive):
    """The first level with rigid bones moves the tip by b; rigid bones (b added to the estimate) only where
    MARGIN b <= RIGID_SHARE tol: not for a stricter tolerance, nor for bones barely stiffer than the body."""
    design = tmp_path / "strip.toml"
    design.write_text(toml_text(strip(length=60.0, width=10.0, size=2.0, contraction=1.0, tendon_offset=2.0,
                                      bones=True)))
    assert main(["simulate", str(design), "--out", str(tmp_path / "o"), "--no-picture", "--tol", str(tol),
                 "--set", f"materials.hard.E={E_bone}"] + (["--adaptive"] if adaptive else [])) == 0
    res = json.loads((tmp_path / "o" / "result.json").read_text())
    a, b = res["accuracy"], res["accuracy"]["bones"]
    assert a["met"] and b["rigid"] == rigid and b["difference"] > 0
    assert (ladder_rules.MARGIN * b["difference"] <= ladder_rules.RIGID_SHARE * tol) == rigid
    assert all(bone.get("rigid", False) == rigid for bone in (res.get("bones") or {"b1": {}}).values())
    if rigid:                              # the bones' difference is part of the estimate it reports
        assert a["estimated_error"] == pytest.approx(a["levels"][-1]["estimate"] + b["difference"])
    assert ("rigid bones" if rigid else "elastic bones") in capsys.readouterr().out


def test_a_ladder_that_ends_on_its_first_level_answers_with_the_bones_it_chose(tmp_path, monkeypatch):
    """Elastic bones chosen, then the DOF limit stops the ladder at once: the session holds the elastic
    solve it answers with (result.json and solution.xdmf), not the rigid probe it solved last."""
    from skelfem import Session
    from skelfem.design import parse_design
    d = parse_design(strip(length=60.0, width=10.0, size=2.0, contraction=1.0, tendon_offset=2.0, bones=True),
                     overrides=["materials.hard.E=3.0"])
    monkeypatch.setitem(resources.MAX_DOFS, 2, 1500)
    with Session(ladder_rules.first_level(d)) as s:
        result, a = accuracy.refine(s, 0.5)
        assert not a["met"] and "DOF limit" in a["stop"] and not a["bones"]["rigid"] and len(a["levels"]) == 1
        assert not s.model.rigid and not any(b.rigid for b in s.design.bones)
        tip = s.model.readouts()["markers"]["tip"]["position"]
        assert np.allclose(tip, result.markers["tip"]["position"], atol=1e-9)


def test_a_tolerance_beyond_the_dof_limit_is_reported_not_met(tmp_path, monkeypatch, capsys):
    design = _strip_file(tmp_path)
    monkeypatch.setitem(resources.MAX_DOFS, 2, 4000)
    assert main(["simulate", str(design), "--out", str(tmp_path / "o"), "--no-picture", "--tol", "1e-6"]) == 0
    a = json.loads((tmp_path / "o" / "result.json").read_text())["accuracy"]
    assert not a["met"] and "DOF limit" in a["stop"] and a["estimated_error"] > 1e-6
    assert "NOT met" in capsys.readouterr().out


def test_tol_needs_a_marker_and_a_positive_value(tmp_path, capsys):
    design = str(GEOMETRY / "finger_soft.toml")
    assert main(["simulate", design, "--out", str(tmp_path / "a"), "--tol", "0"]) == 1
    assert main(["simulate", design, "--out", str(tmp_path / "b"), "--tol", "1", "--set", "markers={}"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("error: ") for line in err)
    assert err[0].startswith("error: --tol: must be") and "> 0" in err[0] and err[0].endswith("got 0")
    assert "needs at least one marker" in err[1]
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_a_sudden_drop_after_stalled_differences_is_not_trusted():
    def ladder(*observed):
        out = [Level(4.0 / 2 ** k, 0, 0, 0.0, np.zeros((1, 2))) for k in range(2 + len(observed))]
        for lv, r in zip(out[2:], observed):
            lv.observed = r
        return out
    assert not ladder_rules.trusted(ladder()[:2])                     # two levels: no rate yet
    assert ladder_rules.trusted(ladder(1.4))                          # a P2-like rate
    assert ladder_rules.trusted(ladder(0.3))                          # slow: trusted (its estimate is large)
    assert not ladder_rules.trusted(ladder(3.8))                      # a drop faster than P2, first rate
    assert not ladder_rules.trusted(ladder(0.05, 3.8))                # ... right after a stall
    assert ladder_rules.trusted(ladder(1.7, 2.3))                     # ... after convergence had begun


def test_an_untrusted_drop_is_estimated_with_the_two_level_rate(monkeypatch):
    """Changes 0.1 then 0.004 (an observed rate above 2 as the first rate): the estimate is the last
    change at r = 1, not at the clipped rate 2; a trusted rate keeps its own estimate. In the ladder,
    the untrusted level stops it when twice that estimate meets the tolerance, and refines otherwise."""
    def ladder(changes):
        x, out = 0.0, []
        for k, d in enumerate((0.0,) + changes):
            x += d
            out.append(ladder_rules.next_level(out, 4.0 / 2 ** k, _Solved(1000 * 4 ** k, [x, 0.0]), 0.0))
        return out
    fast = ladder((0.1, 0.004))
    assert fast[-1].observed > ladder_rules.R_MAX and not ladder_rules.trusted(fast)
    judged = ladder_rules.judged(fast)
    assert judged.rate == ladder_rules.R_TWO_LEVELS and judged.estimate == pytest.approx(0.004 / (2.0 - 1.0))
    assert fast[-1].estimate == pytest.approx(0.004 / 3.0)                 # r = 2 would say 0.0013
    steady = ladder((0.1, 0.03))
    assert ladder_rules.judged(steady) is steady[-1]
    stalled = ladder((0.1, 0.1, 0.004))                    # a drop right after a stall: refine on, as before
    assert not ladder_rules.trusted(stalled) and ladder_rules.judged(stalled) is stalled[-1]
    assert not ladder_rules.may_stop(stalled) and ladder_rules.may_stop(fast) and ladder_rules.may_stop(steady)

    monkeypatch.setattr(accuracy, "ladder_zones", lambda model, design, h0: None)
    tip = {4.0: 0.0, 2.828427: 0.1, 2.0: 0.104}
    for tol, levels in ((0.02, 3), (0.01, 4)):      # r = 1 at sqrt 2: 2 x 0.0097 <= 0.02; > 0.01 (r = 2: 0.008)
        session = _FakeSession(lambda h: int(1000 * (4.0 / h) ** 3),
                               lambda h, k: [tip.get(h, 0.104 + 0.001 * (2.0 - h)), 0.0, 0.0])
        _, acc = accuracy.refine(session, tol=tol)
        ladder_levels = [lv for lv in acc["levels"] if not lv["twin"]]
        assert len(ladder_levels) >= levels and ladder_levels[2]["rate"] == ladder_rules.R_TWO_LEVELS
        assert (len(ladder_levels) == 3) == (levels == 3)


def _strip_design(tmp_path, *sets):
    from skelfem.design import load_design
    path = tmp_path / "strip.toml"
    path.write_text(toml_text(strip(length=60.0, width=10.0, size=2.0)))
    return load_design(path, list(sets))


@pytest.mark.parametrize("region, expected", [
    ("[[-1, -1], [11, 1e-6]]", [[10.0, 0.0], [0.0, 0.0]]),          # the base edge: its two corners
    ("[[-1, -1], [4, 1e-6]]", [[4.0, 0.0], [0.0, 0.0]]),            # part of it: where the box cuts it
    ("[[-1, 20], [1e-6, 30]]", [[0.0, 30.0], [0.0, 20.0]]),         # a stretch of the left side
])
def test_clamped_corners_are_where_a_fixed_pins_box_cuts_the_outline(tmp_path, region, expected):
    d = _strip_design(tmp_path, f"pins.base.region={region}")
    got = ladder_rules.clamp_corners(d)
    assert got.shape == (2, 2)
    assert np.allclose(sorted(got.tolist()), sorted(expected), atol=1e-5)


def test_spring_pins_have_no_clamped_corner_zones_and_3d_bodies_no_clamped_corners(tmp_path):
    d = _strip_design(tmp_path, "pins.base.kind=\"spring\"", "pins.base.stiffness=10.0")
    assert ladder_rules.clamp_corners(d).shape == (0, 2) and ladder_rules.corner_zones(d, 4.0) is None
    from skelfem.design import load_design
    assert ladder_rules.clamp_corners(load_design(GEOMETRY / "post3d.toml")).shape == (0, 2)


def _box_design(tmp_path, region, kind="fixed"):
    from skelfem.design import load_design
    path = tmp_path / "block.toml"
    path.write_text(f"""format = 1
name = "block"
dim = 3
[mesh]
size = 2.0
[materials]
gel = {{ E = 0.1, nu = 0.45 }}
[body]
material = "gel"
solids = [{{ box = {{ min = [0, 0, 0], max = [6, 4, 10] }} }}]
[[pins]]
name = "clamp"
region = {region}
kind = "{kind}"
[markers]
tip = [3, 2, 10]
""")
    return load_design(path, ["pins.clamp.stiffness=1.0"] if kind == "spring" else [])


@pytest.mark.parametrize("region, top", [
    ("[[-1, -1, -1], [7, 5, 0.01]]", 0.01),      # the base face: its rim, 20 mm long
    ("[[-1, -1, -1], [7, 5, 3]]", 3.0),          # the box cuts the sides at z = 3: a ring, 20 mm long
])
def test_clamped_edges_in_3d_are_where_a_fixed_pins_box_cuts_the_surface(tmp_path, region, top):
    from skelfem import Session
    d = _box_design(tmp_path, region)
    with Session(d) as s:
        seg = ladder_rules.clamp_edges(s.model, d)
        zones = ladder_rules.corner_zones(d, 4.0, s.model)
    assert seg.shape[1:] == (2, 3) and np.allclose(seg[..., 2], top, atol=1e-6)
    on_side = np.isclose(seg[..., 0], 0) | np.isclose(seg[..., 0], 6) | np.isclose(seg[..., 1], 0) | \
        np.isclose(seg[..., 1], 4)
    assert on_side.all()
    assert np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1).sum() == pytest.approx(20.0)
    # balls about CORNER_RADIUS h0 / 2 apart cover the whole ring: each point is within 0.3 radii of one
    ring = ladder_rules.along(seg, 0.01)
    gap = np.linalg.norm(ring[:, None] - zones.centers[None], axis=2).min(axis=1).max()
    assert gap <= 0.3 * ladder_rules.CORNER_RADIUS * 4.0
    assert np.allclose(zones.radii, ladder_rules.CORNER_RADIUS * 4.0)
    assert np.allclose(zones.inner, ladder_rules.CORNER_SIZE * 4.0)


def test_spring_pins_have_no_clamped_edges_in_3d(tmp_path):
    from skelfem import Session
    d = _box_design(tmp_path, "[[-1, -1, -1], [7, 5, 0.01]]", kind="spring")
    with Session(d) as s:
        assert ladder_rules.clamp_edges(s.model, d).shape == (0, 2, 3)
        assert ladder_rules.corner_zones(d, 4.0, s.model) is None


def test_along_samples_segments_at_most_spacing_apart_without_duplicates():
    seg = np.array([[[0.0, 0, 0], [1.0, 0, 0]], [[1.0, 0, 0], [1.0, 0.25, 0]]])
    p = ladder_rules.along(seg, 0.3)
    assert len(p) == 5 + 1                       # 0, .25, .5, .75, 1, then (1, .25): (1, 0) once
    assert np.allclose(p[:5, 0], [0, 0.25, 0.5, 0.75, 1.0]) and np.allclose(p[5], [1.0, 0.25, 0])


def test_the_ladders_meshes_are_graded_at_clamped_corners_and_at_anchors(tmp_path):
    """Zones of CORNER_SIZE h within CORNER_RADIUS h_0 of each clamped corner, merged with the anchor zones;
    scaled with h they stay one family (the zones keep their extent in mm)."""
    from skelfem import Session
    from skelfem.design import load_design
    from skelfem.mesh.points import cell_sizes
    d = load_design(GEOMETRY / "thumb.toml")
    h0 = float(ladder_rules.first_level(d).mesh.size)
    with Session(ladder_rules.first_level(d)) as s:
        z = accuracy.ladder_zones(s.model, s.design, h0)
        anchors = ladder_rules.anchor_zones(s.model, h0)
        assert len(z.radii) == len(anchors.radii) + 2
        corners = z.centers[len(anchors.radii):]
        assert np.allclose(sorted(corners.tolist()), [[0.0, 0.01], [16.0, 0.01]], atol=1e-6)
        assert np.allclose(z.inner[-2:], ladder_rules.CORNER_SIZE * h0) and np.allclose(z.radii[-2:], 0.25 * h0)
        half = z.scaled(0.5)
        assert np.allclose(half.inner, 0.5 * z.inner) and np.array_equal(half.radii, z.radii)
        assert np.array_equal(np.broadcast_to(half.thickness, (len(z.radii),)),
                              np.broadcast_to(z.thickness, (len(z.radii),)))
        s.edit(ladder_rules.at_size(d, h0), size=z)
        mesh = s.model.mesh
        h = cell_sizes(mesh)
        x = mesh.geometry.x[mesh.geometry.dofmap.array.reshape(-1, 3)][:, :, :2].mean(axis=1)
        at_corner = np.linalg.norm(x - [0.0, 0.0], axis=1) < ladder_rules.CORNER_RADIUS * h0
        far = np.linalg.norm(x - [8.0, 35.0], axis=1) < 5.0
        assert h[at_corner].max() < 0.35 * h0 and h[far].min() > 0.5 * h0
