"""Dynamics: time steps as incremental-potential minimisation (skelfem.terms.inertia, skelfem.dynamics).

Against references: a cantilever released under a sudden tip load oscillates
at Euler-Bernoulli's first bending frequency; the error against a fine-dt
run falls as dt (Euler) and dt^2 (BDF2); without damping or input the
energy never grows; a slow schedule ends at the static equilibrium.
Through the CLI: the files of a run, and bad input as one error line.
"""
import json

import numpy as np
import pytest

from _designs import strip
from _designs import toml_text as _toml
from skelfem import Session
from skelfem.cli.main import main
from skelfem.design import DesignError, parse_design
from skelfem.terms.inertia import MASS_UNIT, bdf_coefficients

from _studies import load_study

checks = load_study("dynamics_checks")        # the scenarios and measurements the README quotes
cantilever = checks.cantilever
THICK, RHO = checks.THICK, checks.RHO


def test_bdf_coefficients_differentiate_quadratics_exactly():
    # v = (a0 x(t+h) + a1 x(t) + a2 x(t-h/w)) / h is exact for x = 1, t, t^2 (BDF2) and x = 1, t (BDF1)
    for w in (0.5, 1.0, 2.0):
        a0, a1, a2 = bdf_coefficients(2, w)
        h = 0.3
        for p in (0, 1, 2):
            x = lambda t: t ** p
            d = (a0 * x(1.0 + h) + a1 * x(1.0) + a2 * x(1.0 - h / w)) / h
            assert d == pytest.approx(p * (1.0 + h) ** max(p - 1, 0) if p else 0.0, abs=1e-12)
    assert bdf_coefficients(2, 1.0) == (1.5, -2.0, 0.5)
    assert bdf_coefficients(1) == (1.0, -1.0, 0.0)


def test_mass_matrix_units_give_the_weight():
    # M applied to a uniform acceleration a (mm/s^2) is the force rho V a, in N: the total of
    # grad 1/2 |x - x~|_M^2 / (beta h^2) at x - x~ = a beta h^2, against rho V a with 1 kg/m^3 mm/s^2 = 1e-12 N/mm^3
    d = cantilever(L=20.0, size=2.0, degree=1)
    with Session(d) as s:
        model, inertia = s.model, s.model.term("dynamics")
        inertia.start(np.zeros(model.n_local))
        h, a = 0.01, 9810.0                              # 9.81 m/s^2 in mm/s^2
        inertia.prepare(h)                               # Euler: beta = 1
        model.u.x.array.reshape(-1, 2)[:, 1] = a * h * h
        g = model.full_gradient()
        inertia.stop()
    fy = g.reshape(-1, 2)[:, 1].sum()                    # a translation: no elastic force
    weight = MASS_UNIT * RHO * 20.0 * 4.0 * THICK * a        # N
    assert fy == pytest.approx(weight, rel=1e-10)
    assert weight == pytest.approx(1000.0 * 9.81 * 800e-9, rel=1e-12)   # rho V g with V in m^3


@pytest.mark.slow
def test_cantilever_oscillates_at_the_euler_bernoulli_frequency():
    f = checks.frequency()                                # BDF2, dt = T1/100, P2, 834 DOFs
    assert f["converged"] and f["cuts"] == 0 and f["crossings"] >= 3
    assert abs(f["relative_error"]) < 0.02, f
    assert abs(f["relative_error"]) < 0.005                # measured: -0.32 %
    # it swings through the static value with an amplitude of the static deflection
    assert f["swing_up"] == pytest.approx(f["swing_down"], rel=0.1)


@pytest.mark.slow
def test_order_in_dt_is_one_for_euler_and_two_for_bdf2():
    o = checks.orders()                                   # dt = T/20, T/40, T/80 against BDF2 at T/640
    assert 0.85 < o["euler"]["slope"] < 1.15, o
    assert 1.8 < o["bdf2"]["slope"] < 2.4, o


@pytest.mark.slow
@pytest.mark.parametrize("integrator", ["euler", "bdf2"])
def test_energy_never_grows_without_damping_or_input(integrator):
    # a sudden load from rest: E = kinetic + Pi (load potential included) starts at 0 and may only fall
    e = checks.energy(integrator)
    assert e["converged"] and e["initial"] == 0.0
    assert e["max_increase_relative"] <= 1e-9, e
    assert e["final"] < 0.0                                # both dissipate (numerically)


@pytest.mark.slow
def test_damping_dissipates_more():
    lost = {name: checks.energy("bdf2", damping, duration=0.1) for name, damping in
            (("none", None), ("mass", {"mass": 20.0}), ("stiffness", {"stiffness": 0.002}))}
    for e in lost.values():
        assert e["max_increase_relative"] <= 1e-9, e
    assert lost["mass"]["lost_relative"] > 1.5 * lost["none"]["lost_relative"], lost
    assert lost["stiffness"]["lost_relative"] > 1.5 * lost["none"]["lost_relative"], lost


@pytest.mark.slow
def test_slow_schedule_ends_at_the_static_equilibrium():
    s = checks.slow_schedule()
    assert s["converged"] and s["contraction"] == 3.0
    assert s["relative"] < 1e-3, s


def test_schedules_and_dynamics_are_validated_before_meshing():
    d = strip()
    for m in d["materials"].values():
        m["density"] = RHO
    d["dynamics"] = {"dt": 0.01, "duration": 0.1}
    spec = parse_design(d).dynamics
    assert (spec.dt, spec.duration, spec.integrator, spec.steps) == (0.01, 0.1, "bdf2", 10)
    cases = {
        "dynamics.dt=-0.01": "dynamics.dt: must be > 0",
        "dynamics.dt=0": "dynamics.dt: must be > 0",
        "dynamics.duration=0.001": "dynamics.duration: must be at least one time step",
        'dynamics.integrator="rk4"': "dynamics.integrator: must be one of euler, bdf2",
        "dynamics.damping.mass=-1": "dynamics.damping.mass: must be >= 0",
        "dynamics.dt=nan": "dynamics.dt: must be a finite number",
        "cables.flexor.schedule=[[0,0],[0.2,1],[0.1,2]]": "cables.flexor.schedule: times must increase strictly",
        "cables.flexor.schedule=[[0,0],[0.2,inf]]": "cables.flexor.schedule: entry 1 must be finite",
        "cables.flexor.schedule=[[0,0,1]]": "must be a [time, contraction] pair",
        "cables.flexor.schedule=[1,2]": "must be a [time, contraction] pair",
        "cables.flexor.schedule=[]": "must be a non-empty list",
        "cables.flexor.schedule=[[0,-1]]": "contractions must be >= 0",
        "cables.flexor.schedule=[[0,0],[1,100]]": "contractions must be shorter than the cable",
        "materials.soft.density=-5": "materials.soft.density: must be > 0",
    }
    for override, message in cases.items():
        with pytest.raises(DesignError, match=message.replace("[", r"\[").replace("]", r"\]")):
            parse_design(d, "f.toml", [override])
    no_density = strip()
    no_density["dynamics"] = {"dt": 0.01, "duration": 0.1}
    with pytest.raises(DesignError, match=r"materials.soft.density: missing \(required with \[dynamics\]\)"):
        parse_design(no_density, "f.toml")
    sched = parse_design(d, "f.toml", ["cables.flexor.schedule=[[0,0],[0.2,6]]"]).cable("flexor")
    assert sched.contraction_at(0.1) == pytest.approx(3.0) and sched.contraction_at(1.0) == 6.0


@pytest.fixture
def flick_file(tmp_path):
    d = strip(length=40.0, width=8.0, size=4.0, contraction=0.0, k=5.0, E=0.5)
    for m in d["materials"].values():
        m["density"] = 1100.0
    d["cables"][0]["schedule"] = [[0.0, 0.0], [0.05, 2.0]]
    d["dynamics"] = {"dt": 0.01, "duration": 0.1, "integrator": "bdf2"}
    path = tmp_path / "flick.toml"
    path.write_text(_toml(d))
    return path


@pytest.mark.parametrize("override, message", [
    ("dynamics.dt=-0.005", "dynamics.dt: must be > 0"),
    ("cables.flexor.schedule=[[0,0],[0.2,6],[0.1,1]]", "cables.flexor.schedule: times must increase strictly"),
    ("cables.flexor.schedule=[[0,0],[0.2,nan]]", "cables.flexor.schedule: entry 1 must be finite"),
    ("dynamics.duration=0.001", "dynamics.duration: must be at least one time step"),
    ('dynamics.integrator="verlet"', "dynamics.integrator: must be one of"),
    ("materials.soft.density=0", "materials.soft.density: must be > 0"),
])
def test_bad_dynamic_input_is_one_error_line_and_nothing_written(flick_file, tmp_path, capsys, override,
                                                                  message):
    out = tmp_path / "never"
    assert main(["simulate", str(flick_file), "--out", str(out), "-q", "--set", override]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and message in err[0], err
    assert not out.exists() and not list(tmp_path.glob(".never*"))


def test_dynamics_without_density_is_one_error_line(tmp_path, capsys):
    d = strip(size=4.0)
    d["dynamics"] = {"dt": 0.01, "duration": 0.1}
    path = tmp_path / "nodensity.toml"
    path.write_text(_toml(d))
    out = tmp_path / "never"
    assert main(["simulate", str(path), "--out", str(out), "-q"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "materials.soft.density: missing (required with [dynamics])" in err[0], err
    assert not out.exists()


@pytest.mark.slow
def test_simulate_writes_trajectory_xdmf_gif_and_result(flick_file, tmp_path, capsys):
    import meshio
    from PIL import Image

    out = tmp_path / "out"
    assert main(["simulate", str(flick_file), "--out", str(out), "-q", "--set", "dynamics.dt=0.005"]) == 0
    res = json.loads((out / "result.json").read_text())
    dyn = res["dynamics"]
    assert res["converged"] and dyn["dt"] == 0.005 and dyn["steps"] == 20 and dyn["time_reached"] == 0.1
    assert len(dyn["energy_history"]["time"]) == 21 and res["newton_iterations"] >= 20
    assert res["cables"]["flexor"]["contraction"] == 2.0 and "tip" in res["markers"]
    lines = (out / "trajectory.csv").read_text().splitlines()
    assert lines[0] == "time,tip_x,tip_y,flexor_tension,kinetic_energy,potential_energy"
    rows = np.array([[float(v) for v in line.split(",")] for line in lines[1:]])
    assert rows.shape == (21, 6) and rows[0, 0] == 0.0 and rows[-1, 0] == pytest.approx(0.1)
    assert np.allclose(rows[-1, 1:3], res["markers"]["tip"]["position"])
    assert rows[-1, 3] == pytest.approx(res["cables"]["flexor"]["tension"])
    with meshio.xdmf.TimeSeriesReader(str(out / "trajectory.xdmf")) as reader:
        points, cells = reader.read_points_cells()
        assert reader.num_steps == 21
        t, point_data, _ = reader.read_data(reader.num_steps - 1)
    assert t == pytest.approx(0.1) and point_data["displacement"].shape == (len(points), 3)
    gif = Image.open(out / "motion.gif")
    assert gif.n_frames == 21 and gif.size[0] >= 300
    assert not list(out.glob(".*")) and not list(tmp_path.glob(".out*")), "temporary files left behind"


def _flick(**dynamics):
    d = strip(length=40.0, width=8.0, size=4.0, contraction=0.0, k=5.0, E=0.5)
    for m in d["materials"].values():
        m["density"] = 1100.0
    d["cables"][0]["schedule"] = [[0.0, 0.0], [0.05, 2.0]]
    d["dynamics"] = {"dt": 0.01, "duration": 0.1, "integrator": "bdf2", **dynamics}
    return d


def test_failed_steps_are_cut_and_never_accepted():
    d = _flick(dt=0.05)
    d["solver"] = {"max_iterations": 3}
    with Session(d) as s:
        run = s.run_in_time()
    dyn = run.dynamics
    assert run.converged and dyn["time_reached"] == pytest.approx(0.1) and dyn["cuts"] >= 1
    failed = [a for a in run.attempts if a["status"] != "converged"]
    assert len(failed) == dyn["cuts"] and all(a["iterations"] == 3 for a in failed)
    times = [r["time"] for r in run.report.trajectory]
    assert len(times) == dyn["steps"] + 1 and np.all(np.diff(times) > 0)
    # every accepted step is one of the converged attempts, in order
    accepted = [a["time"] for a in run.attempts if a["status"] == "converged"]
    assert np.allclose(times[1:], accepted)


def test_a_step_is_never_halved_below_dt_over_2_to_the_max_cuts():
    """Every other attempt fails (and a success is never easy enough to let h grow back): h halves at each
    failure although no two fail in a row. The run stops once a step would fall below dt / 2^MAX_CUTS,
    with the failed step's status; before, it crept on with ever smaller steps (a thrown box: minutes)."""
    from skelfem.fem.dynamics import EASY_ITERATIONS, MAX_CUTS, Dynamics
    from skelfem.fem.newton import SolveReport
    d = _flick()
    calls = []
    with Session(d) as s:
        real = s.solver.newton

        def flaky():
            calls.append(1)
            assert len(calls) < 4 * MAX_CUTS, "the step kept halving"
            if len(calls) % 2:
                return SolveReport(False, "diverged", EASY_ITERATIONS + 1)
            rep = real()
            rep.newton_iterations = max(rep.newton_iterations, EASY_ITERATIONS + 1)
            return rep
        s.solver.newton = flaky
        rep = Dynamics(s.model, s.solver, s.design).run()
    assert not rep.converged and rep.status == "diverged"
    dts = [a["dt"] for a in rep.attempts]
    assert min(dts) == pytest.approx(0.01 / 2 ** MAX_CUTS) and rep.cuts == MAX_CUTS + 1


def test_a_run_that_cannot_step_stops_with_exit_2_and_keeps_its_trajectory(tmp_path, capsys):
    d = _flick()
    d["solver"] = {"max_iterations": 1}
    path = tmp_path / "stuck.toml"
    path.write_text(_toml(d))
    out = tmp_path / "out"
    assert main(["simulate", str(path), "--out", str(out), "-q", "--no-picture"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "time step failed (max_iterations)" in err[0]
    res = json.loads((out / "result.json").read_text())
    assert not res["converged"] and res["status"] == "max_iterations" and res["markers"] is None
    assert res["dynamics"]["time_reached"] == 0.0 and res["dynamics"]["cuts"] == 9
    assert len((out / "trajectory.csv").read_text().splitlines()) == 2     # the header and t = 0


@pytest.mark.slow
def test_a_falling_cantilever_lands_on_a_ground():
    d = cantilever(L=40.0, size=2.0, degree=1, gravity=9.81, dt=0.002, duration=0.1)
    d["grounds"] = [{"name": "floor", "point": [0.0, -1.0], "normal": [0.0, 1.0], "stiffness": 10.0}]
    d["markers"]["corner"] = [40.0, 0.0]
    with Session(d) as s:
        run = s.run_in_time()
    assert run.converged
    corner = np.array([r["corner_y"] for r in run.report.trajectory])
    assert corner.min() < -0.95 and corner.min() > -1.1              # it reaches the floor and stays on it
    assert run.grounds["floor"]["force"][1] < 0.0                      # pressing on it at the end
    total = np.array(run.dynamics["energy_history"]["total"])
    assert np.diff(total).max() <= 1e-9 * np.abs(run.dynamics["energy_history"]["potential"]).max()


def test_progress_bar_prints_tenths_when_not_a_terminal():
    import io
    from skelfem.jobs.run import ProgressBar
    stream = io.StringIO()
    bar = ProgressBar("run", after=0.0, stream=stream)
    for k in range(1, 101):
        bar(k / 100)
    bar.close()
    lines = stream.getvalue().splitlines()
    assert len(lines) == 10 and lines[0].startswith("run: 10 %") and lines[-1].startswith("run: 100 %")


@pytest.mark.slow
@pytest.mark.mpi
def test_serial_equals_mpirun_2(tmp_path, mpirun):
    import sys
    path = tmp_path / "flick.toml"
    path.write_text(_toml(_flick()))
    rows = {}
    for ranks in (1, 2):
        out = tmp_path / f"out{ranks}"
        p = mpirun.run([sys.executable, "-m", "skelfem", "simulate", path, "--out", out, "-q", "--no-picture"],
                       ranks=ranks)
        assert p.returncode == 0, p.stderr
        lines = (out / "trajectory.csv").read_text().splitlines()
        rows[ranks] = np.array([[float(v) for v in line.split(",")] for line in lines[1:]])
    assert rows[1].shape == rows[2].shape
    assert np.allclose(rows[1], rows[2], rtol=1e-7, atol=1e-9)
