"""SIGINT and SIGTERM in every command and every phase: one `error: interrupted` line, 130 / 143, gone within
2 s of the signal, no output folder and nothing of the run beside it.

The command runs in a subprocess started as the `skelfem` entry point is (``import skelfem.cli`` first);
a profile hook sends the signal `delay` seconds after the first call of the phase's function (meshing:
mesh_design; OpenCASCADE: a bone's booleans; solve: Newton; writing: the atomic write of an output file),
from a timer thread, so that it arrives while that phase runs (inside Gmsh's or OpenCASCADE's C++ calls
for the meshing and OCC phases). The time of the signal is written to a file; the test measures from it
to the exit. Long-lived phases that tests elsewhere cover at random moments (simulate, track, sweep,
fabricate: test_hardening_signals.py; the editor's server during a solve: test_hardening_editor.py)
are not repeated here for every delay.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from _hardening import ENV, ROOT, error_lines

pytestmark = pytest.mark.slow

GEOMETRY = ROOT / "geometry"

HOOK = textwrap.dedent("""
    import importlib, inspect, os, signal, sys, threading, time
    import skelfem.cli                                       # the entry point's start-up: handlers installed
    target, delay, signum, stamp = sys.argv[1], float(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
    module, qualname = target.split(":")
    obj = importlib.import_module(module)
    for part in qualname.split("."):
        obj = getattr(obj, part)
    code = inspect.unwrap(obj).__code__
    fired = []

    def kill():
        with open(stamp, "w") as f:
            f.write(repr(time.time()))
        os.kill(os.getpid(), signum)

    def profile(frame, event, arg):
        if event == "call" and frame.f_code is code and not fired:
            fired.append(True)
            sys.setprofile(None)
            if delay <= 0.0:
                kill()
            else:
                t = threading.Timer(delay, kill)
                t.daemon = True
                t.start()
    sys.setprofile(profile)
    threading.setprofile(profile)                            # fabricate builds parts in a worker thread
    from skelfem.cli.main import main
    sys.argv = ["skelfem", *sys.argv[5:]]
    sys.exit(main(sys.argv[1:]))
""")

SIGNALS = [signal.SIGINT, signal.SIGTERM]
IDS = ["SIGINT", "SIGTERM"]


def interrupt_at(tmp_path: Path, target: str, delay: float, sig: int, args: list, timeout: float = 300):
    """Run skelfem args with the signal sent delay s after target's first call; (status, stderr, seconds
    from the signal to the exit, whether the signal was sent)."""
    stamp = tmp_path / "signalled-at"
    proc = subprocess.Popen([sys.executable, "-c", HOOK, target, str(delay), str(int(sig)), str(stamp),
                             *map(str, args)], cwd=tmp_path, env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        _, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        pytest.fail(f"{args[0]} ({target}) did not end within {timeout} s")
    end = time.time()
    sent = stamp.exists() and stamp.read_text().strip() != ""
    took = end - float(stamp.read_text()) if sent else float("nan")
    return proc.returncode, err, took, sent


def assert_stopped(tmp_path: Path, code: int, err: str, took: float, sent: bool, sig: int, out: Path,
                   allowed=(), sweep=False):
    assert sent, f"the phase was never reached: {code} {err}"
    assert "Traceback" not in err, err
    assert code == 128 + sig, (code, err)
    assert error_lines(err) == ["error: interrupted"], err
    assert took < 2.0, took
    assert not out.exists() or (sweep and complete_sweep_cases(out)), sorted(os.listdir(out))
    debris = [e for e in os.listdir(out.parent) if e.startswith(f".{out.name}") and e not in allowed]
    assert not debris, debris


def complete_sweep_cases(out: Path) -> bool:
    """A sweep keeps the cases it finished before the signal (a rerun resumes after them): a folder of
    complete case folders, each with its result.json, and nothing else. (On a loaded machine the timer
    that sends the signal may wait for the GIL until a case has been written.)"""
    entries = list(out.iterdir())
    return bool(entries) and all(e.is_dir() and (e / "result.json").is_file() and not e.name.startswith(".")
                                 for e in entries)


def calibration_data(tmp_path: Path) -> Path:
    data = tmp_path / "data.csv"
    data.write_text("cables.flexor.contraction,markers.tip.x,markers.tip.y\n"
                    "2.0,-1.99,97.66\n4.0,-13.86,94.44\n6.0,-25.17,89.36\n8.0,-35.52,82.53\n")
    return data


def sweep_file(tmp_path: Path) -> Path:
    path = tmp_path / "sweep.toml"
    path.write_text(f'design = "{GEOMETRY / "finger.toml"}"\nset = ["mesh.size=2.5"]\n'
                    '[parameters]\n"cables.flexor.contraction" = [2.0, 4.0, 6.0]\n')
    return path


FINGER = [str(GEOMETRY / "finger.toml"), "--set", "mesh.size=2"]
FINGER4 = [str(GEOMETRY / "finger4.toml"), "--set", "mesh.size=3"]
FLICK = [str(GEOMETRY / "flick.toml"), "--set", "mesh.size=3"]

NEWTON = "skelfem.fem.newton:NewtonSolver.attempt"
MESHING = "skelfem.mesh.geometry:mesh_design"
WRITING = "skelfem.io.files:atomic_write"

# (command, phase) -> (args after the command, without --out; the hooked function; delay s)
CASES = {
    ("simulate", "meshing"): (["simulate", str(GEOMETRY / "finger3d.toml"), "--set", "mesh.size=1.0"],
                              MESHING, 1.0),
    ("simulate", "solve"): (["simulate", *FINGER], NEWTON, 0.05),
    ("simulate", "writing"): (["simulate", *FINGER], WRITING, 0.0),
    ("ik", "solve"): (["ik", *FINGER4, "--marker", "tip", "--target", "-15", "88"], NEWTON, 0.05),
    ("ik", "writing"): (["ik", *FINGER4, "--marker", "tip", "--target", "-15", "88"], WRITING, 0.0),
    ("track", "writing"): (["track", *FINGER4, "--marker", "tip", "--line", "-10", "88", "20", "88",
                            "--steps", "3"], WRITING, 0.0),
    ("optimize", "solve"): (["optimize", *FLICK, "--marker", "tip", "--target", "-20", "80",
                             "--max-evaluations", "3"], NEWTON, 0.05),
    ("optimize", "writing"): (["optimize", *FLICK, "--marker", "tip", "--target", "-20", "80",
                               "--max-evaluations", "2"], WRITING, 0.0),
    ("calibrate", "solve"): (["calibrate", *FINGER, "--data", "{data}", "--fit", "materials.ecoflex.E"],
                             NEWTON, 0.05),
    ("calibrate", "writing"): (["calibrate", str(GEOMETRY / "finger.toml"), "--set", "mesh.size=4", "--data",
                                "{data}", "--fit", "materials.ecoflex.E", "--model-error", "ignore"], WRITING, 0.0),
    ("sweep", "solve"): (["sweep", "{sweep}"], NEWTON, 0.05),
    ("bench", "solve"): (["bench", str(GEOMETRY / "finger.toml"), "--sizes", "2", "--repeats", "1"], NEWTON,
                         0.05),
    ("bench", "writing"): (["bench", str(GEOMETRY / "finger.toml"), "--sizes", "4", "--repeats", "1"],
                           WRITING, 0.0),
    ("fabricate", "occ"): (["fabricate", str(GEOMETRY / "finger3d.toml"), "--no-picture"],
                           "skelfem.fabricate.build:build_bone", 0.3),
    ("fabricate", "meshing"): (["fabricate", str(GEOMETRY / "finger3d.toml"), "--no-picture"],
                               "skelfem.fabricate.meshing:generate_surface_mesh", 0.05),
    ("fabricate", "writing"): (["fabricate", str(GEOMETRY / "finger3d.toml"), "--no-picture"],
                               "skelfem.fabricate.build:write_step", 0.0),
}


@pytest.mark.parametrize("sig", SIGNALS, ids=IDS)
@pytest.mark.parametrize("command, phase", list(CASES), ids=[f"{c}-{p}" for c, p in CASES])
def test_a_signal_in_every_command_and_phase_stops_it_within_two_seconds(tmp_path, command, phase, sig):
    args, target, delay = CASES[(command, phase)]
    fill = {"data": str(calibration_data(tmp_path)), "sweep": str(sweep_file(tmp_path))}
    args = [a.format(**fill) if "{" in a else a for a in args]
    out = tmp_path / "out"
    code, err, took, sent = interrupt_at(tmp_path, target, delay, sig, [*args, "--out", str(out), "-q"])
    resumable = (".out.track-partial",) if command == "track" else ()      # track resumes from it
    assert_stopped(tmp_path, code, err, took, sent, sig, out, resumable, sweep=command == "sweep")
