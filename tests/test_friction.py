"""Coulomb friction on grounds against analytic answers: incline threshold, pull-through plateau,
the dissipation of a spring-and-slider loop, and no creep while sticking.

A block (20 x 5 mm, slab 10 mm) rests on a floor under gravity; a soft
spring pin on its right face holds it weakly (k_p, total N/mm), so a block
that slides moves by (tangential load - mu_k N) / k_p and one that sticks
only by its elastic and penalty shifts (micrometres).
"""
import math

import numpy as np
import pytest

from skelfem import Session
from skelfem.design import DesignError, parse_design

W_AREA = 20.0 * 5.0 * 10.0          # block volume, mm^3
RHO, G = 1e4, 9.81                  # kg/m^3, m/s^2
WEIGHT = RHO * 1e-9 * G * W_AREA    # N
FACE = 5.0 * 10.0                   # pinned face area, mm^2


def block(mu=0.5, mu_s=None, theta=0.0, kp=1e-4, E=100.0, size=1.0, steps=2):
    """The block on a floor, gravity tilted by theta (deg) towards -x, spring pin of total stiffness kp."""
    th = math.radians(theta)
    d = {"format": 1, "name": "block", "dim": 2, "thickness": 10.0, "mesh": {"size": size, "degree": 1},
         "materials": {"m": {"E": E, "nu": 0.3, "density": RHO}},
         "body": {"outline": [[0, 0], [20, 0], [20, 5], [0, 5]], "material": "m"},
         "pins": [{"name": "pull", "region": [[19.9, -1], [21, 6]], "kind": "spring", "stiffness": kp / FACE}],
         "grounds": [{"name": "floor", "point": [0, 0], "normal": [0, 1], "stiffness": 100.0, "friction": mu}],
         "gravity": {"acceleration": [-G * math.sin(th), -G * math.cos(th)]},
         "markers": {"c": [10, 2.5]}, "solver": {"steps": steps}}
    if mu_s is not None:
        d["grounds"][0]["friction_static"] = mu_s
    return d


def _slide(theta, **kw):
    with Session(block(theta=theta, **kw)) as s:
        r = s.solve()
        assert r.converged, r.status
        d = r.to_dict()
    return -d["markers"]["c"]["displacement"][0], d


@pytest.mark.parametrize("mu_k, mu_s", [(0.5, 0.5), (0.4, 0.5)])
def test_incline_sticks_iff_tan_theta_below_mu_s(mu_k, mu_s):
    """Sticks 0.4 deg below atan(mu_s) (moves micrometres), slides 0.4 deg above it by
    W (sin - mu_k cos) / k_p: the threshold is found within 0.4 deg."""
    kp = 1e-4
    crit = math.degrees(math.atan(mu_s))
    below, d = _slide(crit - 0.4, mu=mu_k, mu_s=mu_s, kp=kp)
    assert below < 2e-3
    floor = d["grounds"]["floor"]
    assert floor["sticking"] > 0.1          # partly slipping so close to the limit, held as a whole
    th = math.radians(crit - 0.4)
    assert floor["friction_force"][0] == pytest.approx(-WEIGHT * math.sin(th), rel=1e-3)  # what holds it
    above, d = _slide(crit + 0.4, mu=mu_k, mu_s=mu_s, kp=kp)
    th = math.radians(crit + 0.4)
    expected = WEIGHT * (math.sin(th) - mu_k * math.cos(th)) / kp
    assert above == pytest.approx(expected, rel=0.02)
    floor = d["grounds"]["floor"]
    N = -floor["force"][1]
    assert N == pytest.approx(WEIGHT * math.cos(th), rel=1e-3)
    assert -floor["friction_force"][0] == pytest.approx(mu_k * N, rel=1e-3)       # slides at mu_k N
    assert floor["sticking"] < 0.01


def _cycle(s, path):
    """Reactions of the pin along a path of pin moves, one warm quasi-static step each."""
    R = []
    for dx in path:
        s.model.set_parameter("pins.pull.move", np.array([dx, 0.0]))
        rep = s.solver.resolve(1)
        assert rep.converged, rep.status
        R.append(s.model.readouts()["pins"]["pull"]["reaction"][0])
    return np.array(R)


def test_pull_through_plateau_and_spring_slider_loop():
    """Pulling through a spring k: the force plateaus at mu N (1 %); a cycle +-A dissipates
    4 F_s (A - F_s / k) (2 %)."""
    mu, k, A = 0.5, 1.0, 0.5
    with Session(block(mu=mu, kp=k, steps=1)) as s:
        assert s.solve().converged
        n = 20
        path = np.r_[np.linspace(0, A, n + 1)[1:], np.linspace(A, -A, 2 * n + 1)[1:],
                     np.linspace(-A, A, 2 * n + 1)[1:]]
        R = _cycle(s, path)
        floor = s.model.readouts()["grounds"]["floor"]
    N = -floor["force"][1]
    Fs = mu * N
    assert N == pytest.approx(WEIGHT, rel=1e-3)
    assert R.max() == pytest.approx(Fs, rel=0.01) and R.min() == pytest.approx(-Fs, rel=0.01)
    assert floor["friction_force"][0] == pytest.approx(Fs, rel=0.01)      # the body drags the floor along +x
    D, Rc = path[n - 1:], R[n - 1:]                                          # from +A round to +A
    work = float(np.sum(0.5 * (Rc[1:] + Rc[:-1]) * np.diff(D)))
    assert work == pytest.approx(4 * Fs * (A - Fs / k), rel=0.02)


def _creep(anchored: bool, steps: int) -> tuple[float, float]:
    """(slip of the first step, drift over `steps` more quasi-static steps) at 0.8 of the limit."""
    mu = 0.5
    theta = math.degrees(math.atan(0.8 * mu))
    with Session(block(mu=mu, theta=theta, kp=1e-6, size=2.5, steps=1)) as s:
        for term in s.model.terms_in("grounds"):
            if hasattr(term, "anchored"):
                term.anchored = anchored
        assert s.solve().converged
        x0 = s.model.readouts()["markers"]["c"]["position"][0]
        for _ in range(steps):
            rep = s.solver.resolve(1, again=True)
            assert rep.converged, rep.status
        x1 = s.model.readouts()["markers"]["c"]["position"][0]
    return x0 - 10.0, x1 - x0


def test_sticking_does_not_creep():
    """Held at 0.8 of its friction limit for 1000 quasi-static steps, the block moves less than 1e-6
    of its size (20 mm); friction regularised on each step's increment (re-anchored every step)
    drifts by the elastic shift at every step."""
    first, drift = _creep(anchored=True, steps=1000)
    assert abs(drift) < 1e-6 * 20.0
    _, drift_regularised = _creep(anchored=False, steps=50)
    assert abs(drift_regularised) > 100 * max(abs(drift), 1e-12)
    print(f"\nfirst step {first:.3e} mm; drift over 1000 steps anchored {drift:.3e} mm; "
          f"re-anchored every step: {drift_regularised:.3e} mm over 50 steps")


# -- design keys ----------------------------------------------------------------------------------------
def test_friction_defaults_to_zero_and_reads_contact_defaults():
    d = parse_design(block(mu=0.0))
    assert d.friction.ground("floor").static == 0.0
    raw = block()
    del raw["grounds"][0]["friction"]
    raw["contact"] = {"friction": 0.3, "friction_static": 0.4}
    d = parse_design(raw)
    assert (d.friction.ground("floor").kinetic, d.friction.ground("floor").static) == (0.3, 0.4)
    assert "friction" in d.raw["contact"]                  # the raw design keeps its keys
    d = parse_design(block(), overrides=["grounds.floor.friction=0.7"])
    assert d.friction.ground("floor").kinetic == 0.7


@pytest.mark.parametrize("where, value, key", [
    ("ground", {"friction": -0.1}, "grounds.floor.friction"),
    ("ground", {"friction": 0.5, "friction_static": 0.3}, "grounds.floor.friction_static"),
    ("contact", {"friction": -1.0}, "contact.friction"),
    ("contact", {"friction": 0.5, "friction_static": 0.2}, "contact.friction_static"),
    ("ground", {"friction": "high"}, "grounds.floor.friction"),
])
def test_bad_friction_is_one_error_naming_the_key(where, value, key):
    raw = block()
    del raw["grounds"][0]["friction"]
    if where == "ground":
        raw["grounds"][0].update(value)
    else:
        raw["contact"] = value
    with pytest.raises(DesignError) as e:
        parse_design(raw, "d.toml")
    assert str(e.value).startswith(f"d.toml: {key}: ") and "\n" not in str(e.value)


@pytest.mark.mpi
def test_friction_serial_equals_two_ranks(tmp_path, mpirun):
    """Between mu_k and mu_s (tan theta = 0.55, mu_k 0.5, mu_s 0.6) the block sticks, then a pull of
    0.3 mm: the same state and read-outs on 1 and 2 ranks."""
    import json
    import sys
    from pathlib import Path
    script = tmp_path / "run.py"
    script.write_text(
        "import json, math, sys\n"
        f"sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
        "import numpy as np\nfrom mpi4py import MPI\nfrom skelfem import Session\nimport test_friction as t\n"
        "d = t.block(mu=0.5, mu_s=0.6, theta=math.degrees(math.atan(0.55)), kp=1e-4)\n"
        "with Session(d) as s:\n"
        "    r = s.solve().to_dict()\n"
        "    s.model.set_parameter('pins.pull.move', np.array([0.3, 0.0]))\n"
        "    assert s.solver.resolve(1).converged\n"
        "    ro = s.model.readouts()\n"
        "    if MPI.COMM_WORLD.rank == 0:\n"
        "        print(json.dumps([r['markers']['c']['position'], r['grounds']['floor']['sticking'],\n"
        "                          ro['grounds']['floor']['friction_force'].tolist(),\n"
        "                          ro['pins']['pull']['reaction'].tolist()]))\n")
    out = []
    for ranks in (1, 2):
        proc = mpirun.run([sys.executable, script], ranks=ranks, timeout=300)
        assert proc.returncode == 0, proc.stderr[-2000:]
        out.append(json.loads(proc.stdout.strip().splitlines()[-1]))
    (x1, st1, f1, r1), (x2, st2, f2, r2) = out
    assert st1 == st2 == 1.0                                  # static friction holds it above mu_k
    assert np.allclose(x1, x2, rtol=0, atol=1e-9)
    assert np.allclose(f1, f2, rtol=1e-8, atol=1e-12) and np.allclose(r1, r2, rtol=1e-8, atol=1e-12)


def test_friction_is_live():
    """grounds.NAME.friction and contact.friction change without re-meshing; the static coefficient
    follows the kinetic one unless it was written."""
    raw = block(mu=0.0)
    del raw["grounds"][0]["friction"]
    with Session(raw) as s:
        model = s.model
        live = model.parameters()
        assert {"grounds.floor.friction", "grounds.floor.friction_static", "contact.friction"} <= live.keys()
        s.set({"contact.friction": 0.3})
        assert s.model is model
        term = next(t for t in model.terms_in("grounds") if t.has_ufl_energy() is False)
        assert (term.mu_k, term.mu_s) == (0.3, 0.3)
        r = s.solve()
        assert r.converged and "friction_force" in r.to_dict()["grounds"]["floor"]
        s.set({"grounds.floor.friction": 0.4})
        assert (term.mu_k, term.mu_s) == (0.4, 0.4) and s.model is model
        s.set({"grounds.floor.friction_static": 0.6})
        s.set({"grounds.floor.friction": 0.5})
        assert (term.mu_k, term.mu_s) == (0.5, 0.6)
        assert s.design.friction.ground("floor").static == 0.6


def test_a_ramp_from_rest_forgets_the_history():
    """After a pull-through, a solve ramped from rest (what a failed warm re-solve falls back to)
    reaches the state of a first solve: the stick anchors start again where the body rests."""
    with Session(block(mu=0.5, kp=1.0, steps=1)) as s:
        assert s.solve().converged
        first = s.model.readouts()["markers"]["c"]["position"].copy()
        s.model.set_parameter("pins.pull.move", np.array([1.0, 0.0]))
        assert s.solver.resolve(1).converged
        assert s.model.readouts()["markers"]["c"]["position"][0] > first[0] + 0.9    # pulled through
        s.model.set_parameter("pins.pull.move", np.array([0.0, 0.0]))
        s.model.u.x.array[:] = 0.0
        assert s.solver.solve(1).converged
        again = s.model.readouts()["markers"]["c"]["position"]
    assert np.allclose(again, first, rtol=0, atol=1e-9)


# -- dynamics ------------------------------------------------------------------------------------------
def _run(theta, mu, mu_s=None, duration=0.2, dt=0.01):
    d = block(mu=mu, mu_s=mu_s, theta=theta, kp=1e-9, size=2.5, steps=1)
    d["dynamics"] = {"dt": dt, "duration": duration, "integrator": "bdf2"}
    with Session(d) as s:
        r = s.run_in_time()
        assert r.converged, r.status
        rows = list(r.report.trajectory)
        return np.array([row["time"] for row in rows]), np.array([row["c_x"] for row in rows]), r.to_dict()


@pytest.mark.slow
@pytest.mark.parametrize("theta, mu_k, mu_s", [(30.0, 0.3, 0.35), (20.0, 0.1, None)])
def test_sliding_in_dynamics_accelerates_at_g_sin_minus_mu_k_cos(theta, mu_k, mu_s):
    """The block slides down the tilted floor (BDF2, no damping): its centre's acceleration (second
    differences of the last steps: exact for a constant one) is g (sin theta - mu_k cos theta) within 2 %."""
    t, x, d = _run(theta, mu_k, mu_s)
    h = t[1] - t[0]
    acc = -(x[2:] - 2 * x[1:-1] + x[:-2]) / h ** 2 * 1e-3          # m/s^2, down the slope (-x)
    th = math.radians(theta)
    expected = G * (math.sin(th) - mu_k * math.cos(th))
    assert np.median(acc[-5:]) == pytest.approx(expected, rel=0.02), acc
    assert d["grounds"]["floor"]["sticking"] < 0.01


@pytest.mark.slow
def test_below_mu_s_the_block_stays_in_dynamics():
    """Tilted at 0.8 of its static limit, with a kinetic mu far below the tilt: the block never breaks
    away, so it stays within micrometres (it would slide 21 mm in 0.1 s at mu_k)."""
    mu_s = 0.5
    theta = math.degrees(math.atan(0.8 * mu_s))
    t, x, d = _run(theta, 0.1, mu_s, duration=0.1)
    assert abs(x - x[0]).max() < 2e-3, abs(x - x[0]).max()
    assert d["grounds"]["floor"]["sticking"] > 0.5
