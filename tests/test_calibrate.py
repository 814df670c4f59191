"""Calibration: sensitivities of every parameter kind, recovery, identifiability, coverage, bad data."""

import numpy as np
import pytest

from skelfem import Session
from skelfem.analysis.caldata import DataError, live_keys, prepare_data
from skelfem.analysis.calibrate import Rows, calibrate, misfit, synthesize
from skelfem.design import load_design, parse_design

from conftest import GEOMETRY

FINGER = GEOMETRY / "finger.toml"
STIFFNESSES = ["materials.ecoflex.E", "materials.pla.E", "cables.flexor.stiffness",
               "cables.lig1_palmar.stiffness", "cables.lig1_dorsal.stiffness",
               "cables.lig2_palmar.stiffness", "cables.lig2_dorsal.stiffness"]
TIP = ["markers.tip.x", "markers.tip.y"]
SAME_MESH = "ignore"    # these data come from the fitted model's own mesh: it has no error against them
                        # (test_calibrate_model_error.py fits data from another mesh)


def heavy_finger(size=4.0):
    """finger.toml, coarse, under gravity across the finger (the weight bends it) with a pretensioned ligament."""
    raw = load_design(FINGER, [f"mesh.size={size}"]).raw
    raw["gravity"] = {"acceleration": [-9.81, -2.0]}
    for c in raw["cables"]:
        if c["name"] == "lig1_dorsal":
            c["pretension"] = 0.3
    return parse_design(raw, str(FINGER))


@pytest.fixture(scope="module")
def heavy():
    with Session(heavy_finger()) as s:
        s.solver.rtol, s.solver.atol = 0.0, 1e-11      # tight equilibria for the differences
        yield s


@pytest.fixture(scope="module")
def finger():
    with Session(FINGER, ["mesh.size=4.0"]) as s:
        yield s


def test_live_keys_are_the_model_parameters(heavy, finger):
    for s in (heavy, finger):
        assert set(live_keys(s.design)) == set(s.model.parameters())
    # a free object on the body, a ground with its own friction and one following [contact]'s
    d = {"format": 1, "name": "objects", "dim": 2, "thickness": 10.0, "mesh": {"size": 2.0, "degree": 1},
         "materials": {"soft": {"E": 1.0, "nu": 0.3, "density": 1000.0},
                       "pla": {"E": 1000.0, "nu": 0.35, "density": 1250.0}},
         "body": {"outline": [[0, 0], [10, 0], [10, 10], [0, 10]], "material": "soft"},
         "pins": [{"name": "base", "region": [[-1, -1], [11, 1e-6]], "kind": "fixed"}],
         "objects": [{"name": "box", "outline": [[2, 10.5], [8, 10.5], [8, 13.5], [2, 13.5]], "material": "pla"}],
         "grounds": [{"name": "wall", "point": [12, 0], "normal": [-1, 0], "stiffness": 10.0, "friction": 0.4},
                     {"name": "other", "point": [-2, 0], "normal": [1, 0], "stiffness": 10.0}],
         "gravity": {"acceleration": [0, -9.81]}, "contact": {"dhat": 0.2, "friction": 0.2}}
    with Session(d) as s:
        assert set(live_keys(s.design)) == set(s.model.parameters())


# every kind: E, nu, stiffness, pretension, a contraction offset, density, gravity
KINDS = ["materials.ecoflex.E", "materials.ecoflex.nu", "materials.pla.E", "cables.flexor.stiffness",
         "cables.lig1_dorsal.pretension", "cables.flexor.contraction", "materials.ecoflex.density",
         "gravity.acceleration.y", "cables.lig2_*.stiffness"]       # the last: one value for two ligaments
COLUMNS = TIP + ["cables.flexor.tension", "cables.lig1_dorsal.tension", "pins.base.reaction.x",
                 "pins.base.reaction.y"]


def test_sensitivities_with_rigid_bones():
    raw = load_design(FINGER, ["mesh.size=4.0"]).raw
    for b in raw["bones"]:
        b["rigid"] = True
    keys = ["materials.ecoflex.E", "materials.ecoflex.nu", "cables.flexor.stiffness", "cables.lig1_dorsal.stiffness"]
    columns = ["markers.tip.x", "markers.tip.y", "cables.flexor.tension", "cables.lig1_dorsal.tension"]
    with Session(parse_design(raw, str(FINGER))) as s:
        s.solver.rtol, s.solver.atol = 0.0, 1e-11
        assert set(live_keys(s.design)) == set(s.model.parameters())
        data = prepare_data(s.design, {"cables.flexor.contraction": [3.0, 6.0], **{c: [0.0, 0.0] for c in columns}},
                            keys)
        _check_sensitivities(s, data, keys, 4)


def _problem(session, values=None, keys=KINDS, contractions=(3.0, 6.0)):
    n = len(contractions)
    data = {"cables.flexor.contraction": list(contractions), **{c: [0.0] * n for c in COLUMNS}}
    if values is not None:
        data.update({c: list(values[:, j]) for j, c in enumerate(COLUMNS)})
    return prepare_data(session.design, data, keys)


def _check_sensitivities(session, data, keys, markers_and_tensions):
    """J of Rows against central differences (step 1e-5) of the solved measurements, per parameter."""
    theta = np.array([p.initial for p in data.parameters])
    Y, J, _ = Rows(session, data).run(theta)
    scale = np.array([p.scale for p in data.parameters])
    fds = []
    for j, key in enumerate(keys):
        h = 1e-5 * scale[j]
        e = np.zeros(len(theta))
        e[j] = h
        yp = Rows(session, data).run(theta + e, jacobian=False)[0]
        ym = Rows(session, data).run(theta - e, jacobian=False)[0]
        fds.append((yp - ym) / (2 * h))
        assert np.abs(fds[-1]).max() > 1e-9, key              # the parameter moves something
    fds = np.array(fds)                                         # (parameters, rows, columns)
    # each column's size: its largest change per relative change of a parameter
    size = np.max(np.abs(fds) * scale[:, None, None], axis=(0, 1))
    floor = 1e-3 * np.abs(Y).max(axis=0)       # a change below this is "does not move it"
    for j, key in enumerate(keys):
        moves = np.max(np.abs(fds[j]) * scale[j], axis=0) > floor
        err = np.abs(J[:, :, j] - fds[j]) * scale[j] / np.maximum(size, floor)
        # the differences carry the Newton tolerance (|R| ~ 1e-9 N at x*): /2h = 1e-4 of a reaction for nu
        assert err[:, :markers_and_tensions][:, moves[:markers_and_tensions]].max(initial=0) < 2e-5, (key, err)
        assert err[:, moves].max(initial=0) < 5e-4, (key, err, J[:, :, j], fds[j])
        assert np.all(np.abs(J[:, ~moves, j]) * scale[j] < 2 * floor[~moves]), (key, J[:, :, j])    # nor does J


@pytest.mark.parametrize("half", [0, 1])
def test_sensitivities_of_every_parameter_kind(heavy, half):
    keys = KINDS[:5] if half == 0 else KINDS[5:]
    data = _problem(heavy, keys=keys)
    if half:
        assert data.parameters[0].offset              # cables.flexor.contraction: a condition column
    _check_sensitivities(heavy, data, keys, 4)


def test_sensitivities_with_a_sensor_loads_and_pin_moves():
    """A ground plane as force sensor, a point load and the base driven onto the sensor."""
    raw = load_design(FINGER, ["mesh.size=4.0"]).raw
    raw["cables"] = [c for c in raw["cables"] if c["kind"] == "ligament"]
    raw["loads"] = [{"name": "side", "at": [10.0, 96.0], "force": [0.05, 0.0]}]
    raw["grounds"] = [{"name": "fsr", "point": [10.0, 100.3], "normal": [-0.0175, -0.9998], "stiffness": 10.0}]
    keys = ["grounds.fsr.stiffness", "grounds.fsr.point.y", "loads.side.force.x", "pins.base.move.y",
            "materials.ecoflex.E"]
    columns = ["markers.tip.x", "markers.tip.y", "grounds.fsr.force.y", "pins.base.reaction.y"]
    with Session(parse_design(raw, str(FINGER))) as s:
        s.solver.rtol, s.solver.atol = 0.0, 1e-11
        data = prepare_data(s.design, {"pins.base.move.y": [0.5, 1.0], **{c: [0.0, 0.0] for c in columns}}, keys)
        assert [p.offset for p in data.parameters] == [False, False, False, True, False]
        _check_sensitivities(s, data, keys, 3)


@pytest.mark.parametrize("half", [0, 1])
def test_misfit_gradient_against_central_differences(heavy, half):
    keys = KINDS[:5] if half == 0 else KINDS[5:]
    data0 = _problem(heavy, keys=keys, contractions=(6.0,))
    theta0 = np.array([p.initial for p in data0.parameters])
    Y = Rows(heavy, data0).run(theta0, jacobian=False)[0]
    rng = np.random.default_rng(1)
    data = _problem(heavy, Y + rng.normal(0, 0.05, Y.shape), keys=keys, contractions=(6.0,))
    theta = theta0 * (1 + 0.01 * rng.standard_normal(len(theta0))) + 0.01 * (theta0 == 0)
    f, g = misfit(heavy, data, theta)
    scale = np.array([p.scale for p in data.parameters])
    for j, key in enumerate(keys):
        # central differences at h and h/2, Richardson-extrapolated (error O(h^4)): a step large enough
        # that the Newton tolerance's noise (|R| ~ 1e-11 N) stays far below the 1e-5 asked of it
        def central(h):
            e = np.zeros(len(theta))
            e[j] = h
            return (misfit(heavy, data, theta + e, False)[0] - misfit(heavy, data, theta - e, False)[0]) / (2 * h)
        h = 1e-3 * scale[j]
        fd = (4 * central(h / 2) - central(h)) / 3
        # within 1e-5 of itself, or (a parameter the misfit hardly sees: PLA's E, 7e-5 of the largest
        # component) within 1e-7 of the gradient's largest scaled component
        assert abs(g[j] - fd) <= 1e-5 * abs(fd) + 1e-7 * np.max(np.abs(g * scale)) / scale[j], (key, g[j], fd)


@pytest.fixture(scope="module")
def finger_data(finger):
    """Noise-free tip positions and flexor tension of the coarse finger over four contractions."""
    return synthesize(finger, {"cables.flexor.contraction": [2.0, 4.0, 6.0, 8.0]},
                      TIP + ["cables.flexor.tension"])


def test_noise_free_recovery_from_twice_off(finger, finger_data, no_error_estimate):
    keys = ["materials.ecoflex.E", "cables.flexor.stiffness", "cables.lig1_dorsal.stiffness"]
    true = np.array([finger.model.parameters()[k] for k in keys])
    try:
        finger.set(dict(zip(keys, true * np.array([2.0, 0.5, 2.0]))))
        cal = calibrate(finger, finger_data, keys, model_error=SAME_MESH)
    finally:
        finger.set(dict(zip(keys, true)))
    assert cal.converged and cal.iterations <= 10, (cal.iterations, cal.status)
    assert np.max(np.abs(cal.values / true - 1)) < 1e-6, cal.values
    assert list(cal.initial) == pytest.approx(true * [2.0, 0.5, 2.0])


ACTIVE = ["materials.ecoflex.E", "materials.pla.E", "cables.flexor.stiffness",
          "cables.lig1_dorsal.stiffness", "cables.lig2_dorsal.stiffness"]


def test_scaling_every_stiffness_is_unidentifiable_from_positions(finger, finger_data, no_error_estimate):
    positions = {k: v for k, v in finger_data.items() if k != "cables.flexor.tension"}
    cal = calibrate(finger, positions, STIFFNESSES, model_error=SAME_MESH)
    # the scaling direction: every taut cable and both materials; the slack palmar ligaments do nothing
    assert sorted(map(sorted, cal.unidentifiable)) == sorted(
        [sorted(ACTIVE), ["cables.lig1_palmar.stiffness"], ["cables.lig2_palmar.stiffness"]])
    assert all(cal.to_dict()["parameters"][k]["std"] is None for k in STIFFNESSES)
    # one tension column fixes the scale
    cal = calibrate(finger, finger_data, ACTIVE, model_error=SAME_MESH)
    assert cal.unidentifiable == [] and np.all(np.isfinite(cal.std))
    assert np.max(np.abs(cal.values / cal.initial - 1)) < 1e-6


def test_holdout_and_calibrated_design(finger, finger_data):
    cal = calibrate(finger, finger_data, ["materials.ecoflex.E"], holdout=0.25, model_error=SAME_MESH)
    assert cal.holdout["rows"] == 1 and cal.data.train.sum() == 3
    assert cal.holdout["weighted_rms"] < 1e-6
    assert set(cal.overrides(finger.design)) == {"materials.ecoflex.E"}
    out = cal.to_dict()
    assert set(out) >= {"parameters", "correlation", "unidentifiable", "iterations", "converged",
                        "residual_rms", "holdout"}


def _coverage(finger, seeds, rows=8):
    keys = ["materials.ecoflex.E", "cables.flexor.stiffness"]
    sigma = {"markers.*": 0.2, "cables.flexor.tension": 0.05}
    clean = synthesize(finger, {"cables.flexor.contraction": np.linspace(1.0, 8.0, rows)},
                       TIP + ["cables.flexor.tension"])
    true = np.array([finger.model.parameters()[k] for k in keys])
    est, std, inside = [], [], []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        data = dict(clean)
        for c in TIP:
            data[c] = clean[c] + rng.normal(0, 0.2, rows)
        data["cables.flexor.tension"] = clean["cables.flexor.tension"] + rng.normal(0, 0.05, rows)
        cal = calibrate(finger, data, keys, sigma=sigma, model_error=SAME_MESH)
        est.append(cal.values)
        std.append(cal.std)
        inside.append((cal.ci95[:, 0] <= true) & (true <= cal.ci95[:, 1]))
    return true, np.array(est), np.array(std), np.array(inside)


@pytest.fixture
def no_error_estimate(monkeypatch):
    """model_error "ignore" only reports the model's error: the estimate (a richer solve of every row, at
    the start and at the estimate: three quarters of these fits' time) changes no value, std, interval or
    group (measured: the coverage study's estimates and stds bit for bit the same). Tests that read none of
    the report's model_error skip it (its cells reported as not estimated)."""
    from skelfem.analysis.calerror import ModelError

    def not_estimated(self, rows, theta, states=None):
        assert self.mode == "ignore"
        return np.full(self.data.values.shape, np.nan), np.full(self.data.values.shape, np.nan)
    monkeypatch.setattr(ModelError, "estimate", not_estimated)


@pytest.mark.slow
def test_noise_coverage_over_twenty_seeds(finger, no_error_estimate):
    true, est, std, inside = _coverage(finger, range(20))
    assert inside.mean() >= 0.85, inside.mean()
    spread = est.std(axis=0, ddof=1)
    assert np.all(np.abs(spread / std.mean(axis=0) - 1) < 0.3), (spread, std.mean(axis=0))


# -- bad data: one line naming the problem -----------------------------------------------------------
@pytest.mark.parametrize("data, fit, kw, message", [
    ("markers.tip.x,foo\n1,2\n", ["materials.ecoflex.E"], {}, "column 'foo' names no marker"),
    ("markers.tip.x\nabc\n", ["materials.ecoflex.E"], {}, "'abc' is not a number"),
    ("markers.tip.x\n1\n", ["materials.ecoflex.E", "materials.pla.E"], {}, "fewer than the 2 parameters"),
    ("markers.tip.x\n1\n", ["mesh.size"], {}, "'mesh.size' is not a live parameter"),
    ("markers.tip.x\n1\n2\n", ["materials.ecoflex.E"], {"bounds": ["materials.ecoflex.E=0.2,0.3"]},
     "excludes the start"),
    ("markers.tip.x\n1\n2\n", ["materials.ecoflex.E"], {"sigma": ["markers.tip.q=1"]}, "names no measurement"),
    ("markers.tip.x\n1\n2\n", ["materials.ecoflex.E"], {"sigma": ["markers.tip.x=-1"]}, "must be > 0"),
    ("markers.tip.x,experiment\n1,a\n2,b\n3,a\n", ["materials.ecoflex.E"], {}, "consecutive"),
    ("markers.tip.x\n1\n2\n", ["materials.*.E"], {}, "start at different values (materials.ecoflex.E=0.1"),
    ("markers.tip.x\n1\n2\n", ["cables.nope*.stiffness"], {}, "matches no live parameter"),
    ("markers.tip.x\n1\n2\n", ["cables.flexor.friction"], {}, "starts at 0, a cable without friction"),
])
def test_bad_data_is_one_line(data, fit, kw, message):
    design = load_design(FINGER)
    with pytest.raises(DataError, match=message.replace("(", r"\(")) as err:
        prepare_data(design, data, fit, **kw)
    assert "\n" not in str(err.value)


def test_size_limit(tmp_path):
    path = tmp_path / "big.csv"
    path.write_text("markers.tip.x\n" + "1.0\n" * 100)
    with pytest.raises(DataError, match="over the limit"):
        prepare_data(load_design(FINGER), path, ["materials.ecoflex.E"], max_bytes=100)


def test_solve_many_is_solve_column_by_column(finger):
    from skelfem.analysis.sensitivity import Linearization
    finger.solve()
    lin = Linearization(finger.model, finger.solver)
    try:
        rng = np.random.default_rng(0)
        B = rng.standard_normal((len(finger.model.u.vector.array_r), 3))
        B[finger.model.fixed[:len(B)]] = 0.0
        X = lin.solve_many(B)
        for j in range(3):
            b = finger.model.u.vector.duplicate()
            b.array_w[:] = B[:, j]
            x = lin.solve(b)
            assert np.allclose(X[:, j], x.array_r, rtol=1e-10, atol=1e-12 * np.abs(x.array_r).max())
            b.destroy()
            x.destroy()
    finally:
        lin.destroy()


def test_the_session_gets_its_design_values_back(finger, finger_data):
    before = finger.model.parameters()
    cal = calibrate(finger, finger_data, ["materials.ecoflex.E"], sigma={"markers.*": 0.1},
                    model_error=SAME_MESH)
    after = finger.model.parameters()
    assert all(np.array_equal(np.asarray(before[k]), np.asarray(after[k])) for k in before)
    finger.set(cal.overrides(finger.design))
    r = finger.solve()
    assert r.converged and finger.model.parameters()["materials.ecoflex.E"] == pytest.approx(0.1, rel=1e-6)
    assert r.marker("tip") == pytest.approx([-35.5159494, 82.5264545], abs=1e-5)    # contraction 8 (design)


@pytest.mark.slow
def test_3d_design_recovery(no_error_estimate):
    with Session(GEOMETRY / "finger3d.toml", ["mesh.size=9.0"]) as s:    # 1035 DOFs (6.0: 1764, twice the cost)
        cols = ["markers.tip.x", "markers.tip.y", "markers.tip.z", "cables.flexor.tension"]
        data = synthesize(s, {"cables.flexor.contraction": [3.0, 6.0]}, cols)
        s.set({"materials.ecoflex.E": 0.2})
        cal = calibrate(s, data, ["materials.ecoflex.E"], model_error=SAME_MESH)
    assert cal.converged and cal.values[0] == pytest.approx(0.1, rel=1e-6)


# -- log-parameters, identifiability from the structure, a fit that moves ---------------------------
BONES = GEOMETRY / "finger_bones.toml"      # one tendon, silicone and PLA bones: three stiffnesses
SCALED = ["materials.ecoflex.E", "materials.pla.E", "cables.flexor.stiffness"]


@pytest.fixture(scope="module")
def bones():
    with Session(BONES, ["mesh.size=4.0"]) as s:
        yield s


def _from(session, keys, start, **kw):
    """calibrate with keys started at start (the session gets its values back)."""
    true = {k: session.model.parameters()[k] for k in keys}
    try:
        session.set(dict(zip(keys, start)))
        return calibrate(session, **kw, fit=keys, model_error=SAME_MESH)
    finally:
        session.set(true)


@pytest.mark.slow
def test_an_exact_invariance_is_one_group_from_any_start(bones, no_error_estimate):
    """Contraction-driven, positions only: scaling every stiffness together moves no marker."""
    data = synthesize(bones, {"cables.flexor.contraction": [2.0, 4.0, 6.0, 8.0]}, TIP)
    true = np.array([bones.model.parameters()[k] for k in SCALED])
    for factors in ([1.0, 1.0, 1.0], [2.0, 0.5, 1.0], [100.0, 1.0, 1.0], [1.0, 1.0, 0.01]):
        cal = _from(bones, SCALED, true * factors, data=data, sigma={"markers.*": 0.05})
        assert cal.unidentifiable == [SCALED], (factors, cal.unidentifiable)
        assert cal.groups_end == [SCALED] and not any(cal.identified), factors
        ways = " ".join(cal.identify_with[0])
        assert "cables.flexor.tension" in ways and "known load or mass" in ways
        out = cal.to_dict()
        assert all(out["parameters"][k]["std"] is None and not out["parameters"][k]["identified"] for k in SCALED)
        # the fit still matches the markers: only the scale is unknown
        assert cal.cost < 1e-3 * max(cal.history[0], 1e-12) or cal.cost < 1e-6, (factors, cal.history)


def test_a_single_stiffness_fit_moves_off_its_start(bones, no_error_estimate):
    """The tendon's stiffness alone from positions, started 25x too stiff: 6 iterations reach the truth
    (a linear-parameter step overshot to the lower bound and stalled there)."""
    key = "cables.flexor.stiffness"
    true = bones.model.parameters()[key]
    try:
        bones.set({key: 4.0})
        data = synthesize(bones, {"cables.flexor.contraction": [2.0, 4.0, 6.0, 8.0]}, TIP)
    finally:
        bones.set({key: true})
    cal = _from(bones, [key], [100.0], data=data, sigma={"markers.*": 0.05}, max_iterations=6)
    assert cal.converged and cal.cost <= 0.1 * cal.history[0], cal.history
    assert cal.values[0] == pytest.approx(4.0, rel=1e-4) and cal.identified == [True]


def test_intervals_of_positive_parameters_are_positive(finger, finger_data, no_error_estimate):
    """Noisy tip positions, four rows: the ligaments' linear interval would reach below zero."""
    rng = np.random.default_rng(3)
    data = {k: (np.asarray(v) + rng.normal(0, 0.2, len(v)) if k.startswith("markers") else v)
            for k, v in finger_data.items()}
    keys = ["materials.ecoflex.E", "cables.flexor.stiffness", "cables.lig*.stiffness"]
    cal = calibrate(finger, data, keys, sigma={"markers.*": 0.2, "cables.flexor.tension": 0.05},
                    model_error=SAME_MESH)
    assert cal.converged and np.all(np.isfinite(cal.std))
    assert np.all(cal.ci95[:, 0] > 0), cal.ci95
    assert np.allclose(cal.ci95[:, 0] * cal.factor, cal.values) and np.allclose(cal.values * cal.factor,
                                                                                   cal.ci95[:, 1])
    linear_low = cal.values - 1.959963984540054 * cal.std
    assert linear_low[2] < 0, linear_low                     # the interval a linear fit would report
    wide = cal.factor ** 2 > 10.0
    assert wide[2] and [not w for w in wide] == cal.identified
    assert "more than a decade" in cal.reasons[2]


def test_multiple_starts_keep_the_lowest_misfit(finger, finger_data, no_error_estimate):
    cal = calibrate(finger, finger_data, ["materials.ecoflex.E"], starts=3, seed=1, model_error=SAME_MESH)
    assert len(cal.starts) == 3 and sum(s["best"] for s in cal.starts) == 1
    assert cal.cost == min(s["cost"] for s in cal.starts)
    assert cal.values[0] == pytest.approx(0.1, rel=1e-6)
    starts = [s["initial"]["materials.ecoflex.E"] for s in cal.starts]
    assert starts[0] == pytest.approx(0.1) and all(0.01 <= e <= 1.0 for e in starts) and len(set(starts)) == 3


def test_null_groups_do_not_depend_on_the_rotation_of_the_null_space():
    from skelfem.analysis.calibrate import _null_groups, _rref
    rng = np.random.default_rng(0)
    # columns: a, b, c scale together (their sum is zero), d does nothing, e is seen
    a, b, e = rng.standard_normal((3, 20))
    A = np.column_stack([a, b, -(a + b), np.zeros(20), e])
    groups, basis, _ = _null_groups(A, 1e-6)
    assert groups == [[0, 1, 2], [3]] and np.allclose(A @ basis.T, 0.0, atol=1e-9)
    Q = np.linalg.qr(rng.standard_normal((2, 2)))[0]          # another basis of the same null space
    assert np.allclose(_rref(Q @ basis), basis)


@pytest.mark.parametrize("data, fit, kw, message", [
    ("markers.tip.x\n1_000\n2\n", ["materials.ecoflex.E"], {}, "'1_000' is not a number"),
    ("markers.tip.x\n\u0661\u0662\n2\n", ["materials.ecoflex.E"], {}, "is not a number"),
    ("markers.tip.x\n1\n2\n", ["materials.ecoflex.E"], {"sigma": ["markers.*=1e-200"]}, "within 1e-09 and 1e+09"),
    ("markers.tip.x\n1\n2\n", ["cables.flexor.stiffness"], {"bounds": ["cables.flexor.stiffness=-100,100"]},
     "lower bound > 0"),
    ("markers.tip.x\n1\n2\n", ["materials.ecoflex.nu"], {"bounds": ["materials.ecoflex.nu=0.3,0.7"]},
     "0.7 is not a valid value (materials.ecoflex.nu: must lie in (-1, 0.5)"),
    ("markers.tip.x\n1\n2\n", ["materials.ecoflex.nu"], {"bounds": ["materials.ecoflex.nu=-1.5,0.49"]},
     "-1.5 is not a valid value"),
    ("markers.tip.x\n1\n2\n", ["materials.ecoflex.E"], {"bounds": ["materials.ecoflex.E=0x1,1"]}, "not a number"),
])
def test_bounds_sigma_and_numbers_are_checked_before_meshing(data, fit, kw, message):
    import re
    with pytest.raises(DataError, match=re.escape(message)) as err:
        prepare_data(load_design(FINGER), data, fit, **kw)
    assert "\n" not in str(err.value)


def test_a_failed_sensitivity_solve_is_a_solve_error(finger, finger_data, monkeypatch):
    """E.g. GMRES through friction that does not converge: a reason naming the row, not an internal error."""
    from skelfem.analysis.sensitivity import Linearization
    from skelfem.fem.newton import SolveError

    def stalled(self, B):
        raise RuntimeError("sensitivity through friction: GMRES did not converge (|r| 0.1)")
    monkeypatch.setattr(Linearization, "solve_many", stalled)
    with pytest.raises(SolveError, match="at the start: row 1: the equilibrium converged but its sensitivity "
                                         "solve failed .*GMRES did not converge"):
        calibrate(finger, finger_data, ["materials.ecoflex.E"], model_error=SAME_MESH)
