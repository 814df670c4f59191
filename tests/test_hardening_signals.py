"""Interrupts at random moments: one `error: interrupted` line, 130 / 143, a consistent folder, a rerun completes.

`simulate`, `track` and `sweep` are started as subprocesses and sent SIGINT
or SIGTERM after a random delay (seeded, so CI sees the same moments). After
each kill the output folder must hold one complete result or none (and no
staging folder, lock or temporary file beside or inside it); then the same
command runs to the end, resuming where that is promised.
"""
from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from _hardening import ENV, ROOT, SKELFEM, error_lines, listing

pytestmark = pytest.mark.slow

SIMULATE = ["simulate", str(ROOT / "geometry" / "finger.toml"), "--set", "mesh.size=1.2", "-q"]
TRACK = ["track", str(ROOT / "geometry" / "finger4.toml"), "--marker", "tip", "--line", "-10", "88", "20", "88",
         "--steps", "10", "--set", "mesh.size=2.5", "-q"]


def _start(args, cwd):
    return subprocess.Popen([SKELFEM, *args], cwd=cwd, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)


def _interrupt(args, cwd, sig, delay):
    """Run, send sig after delay seconds; returns (exit status, stderr). Interrupted, it is gone within 2 s
    of the signal, wherever it was (meshing, solving, writing)."""
    code, err, took = _stop_time(args, cwd, sig, delay)
    if code != 0:
        assert took < 2.0, (args[0], delay, took)
    return code, err


def _check_interrupted(code, err, sig):
    print(f"[{'finished' if code == 0 else 'interrupted'}]", end=" ")
    assert "Traceback" not in err, err
    if code == 0:                                # it finished before the signal came
        assert not error_lines(err), err
    else:
        assert code == 128 + sig, (code, err)
        assert error_lines(err) == ["error: interrupted"], err


def _no_debris(parent: Path, name: str, allowed=()):
    """Nothing of a run left beside the output folder (staging, old copies, lock), nor hidden inside it."""
    extra = [e for e in os.listdir(parent) if e.startswith(f".{name}.") and e not in allowed]
    assert not extra, extra
    if (parent / name).is_dir():
        assert not [p for p in listing(parent / name) if Path(p).name.startswith(".")]


def _complete_simulate(out: Path) -> dict | None:
    if not out.exists():
        return None
    res = json.loads((out / "result.json").read_text())
    assert res["converged"] is True
    assert sorted(os.listdir(out)) == ["deformed.png", "result.json", "solution.xdmf"]
    return res


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_simulate_interrupted_at_random_moments(tmp_path, sig):
    rng = random.Random(1000 + sig)
    out = tmp_path / "out"
    contraction = None
    for k in range(4):
        delay = rng.uniform(0.2, 3.5)
        c = 4.0 + k
        code, err = _interrupt(SIMULATE + ["--out", str(out), "--set", f"cables.flexor.contraction={c}"],
                               tmp_path, sig, delay)
        _check_interrupted(code, err, sig)
        res = _complete_simulate(out)
        if res is not None:
            got = res["cables"]["flexor"]["contraction"]
            assert got == contraction or got == c      # the old complete result, or the new complete one
            contraction = got
        if code == 0:
            assert contraction == c
        _no_debris(tmp_path, "out")
    code = subprocess.run([SKELFEM, *SIMULATE, "--out", str(out)], cwd=tmp_path, env=ENV, capture_output=True,
                          text=True, timeout=120).returncode
    assert code == 0
    assert _complete_simulate(out)["cables"]["flexor"]["contraction"] == 8.0
    _no_debris(tmp_path, "out")


def _complete_track(out: Path, steps: int = 10) -> bool:
    if not out.exists():
        return False
    assert sorted(os.listdir(out)) == ["track.csv", "track.json", "track.png"]
    summary = json.loads((out / "track.json").read_text())
    assert summary["targets"] == steps
    assert len((out / "track.csv").read_text().strip().splitlines()) == steps + 1
    return True


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_track_interrupted_resumes(tmp_path, sig):
    rng = random.Random(2000 + sig)
    out = tmp_path / "out"
    partial = tmp_path / ".out.track-partial"
    done_before = 0
    for k in range(3):
        delay = rng.uniform(0.8, 2.6)
        code, err = _interrupt(TRACK + ["--out", str(out)], tmp_path, sig, delay)
        _check_interrupted(code, err, sig)
        if code == 0:
            assert _complete_track(out) and not partial.exists()
            break
        assert not out.exists()                           # nothing published until the track is complete
        _no_debris(tmp_path, "out", allowed=(".out.track-partial",))
        if partial.exists():
            done = len(json.loads((partial / "progress.json").read_text())["results"])
            assert done >= done_before
            done_before = done
    res = subprocess.run([SKELFEM, *TRACK[:-1], "--out", str(out)], cwd=tmp_path, env=ENV, capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    if done_before and not out.exists():
        pass
    assert _complete_track(out)
    assert not partial.exists()
    _no_debris(tmp_path, "out")
    summary = json.loads((out / "track.json").read_text())
    if done_before:
        assert f"resuming after {done_before} of 10 targets" in res.stdout or summary["resumed_after"] == 0
        assert summary["resumed_after"] in (0, done_before)


def test_track_resume_gives_the_same_targets(tmp_path):
    """A track stopped after some targets and resumed reports every target once, in order."""
    out = tmp_path / "out"
    proc = _start(TRACK + ["--out", str(out)], tmp_path)
    partial = tmp_path / ".out.track-partial" / "progress.json"
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None:
        try:
            if len(json.loads(partial.read_text())["results"]) >= 2:
                break
        except (OSError, ValueError, KeyError):
            pass
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    proc.communicate(timeout=60)
    if proc.returncode == 0:
        pytest.skip("the track finished before it could be interrupted")
    done = len(json.loads(partial.read_text())["results"])
    res = subprocess.run([SKELFEM, *TRACK, "--out", str(out)], cwd=tmp_path, env=ENV, capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    summary = json.loads((out / "track.json").read_text())
    assert summary["resumed_after"] == done and summary["targets"] == 10
    rows = (out / "track.csv").read_text().strip().splitlines()[1:]
    targets = [float(r.split(",")[1]) for r in rows]
    assert targets == pytest.approx(list(-10 + 30 * i / 9 for i in range(10)))


def _sweep_file(tmp_path: Path) -> Path:
    path = tmp_path / "sweep.toml"
    path.write_text(f'design = "{ROOT / "geometry" / "finger.toml"}"\nset = ["mesh.size=2.5"]\n'
                    '[parameters]\n"cables.flexor.contraction" = [2.0, 4.0, 6.0, 8.0]\n"materials.pla.E" = [10.0, 1000.0]\n')
    return path


def _check_sweep_folder(out: Path) -> set:
    """Every case folder present is complete; returns the names of the converged ones."""
    done = set()
    if not out.exists():
        return done
    for e in os.listdir(out):
        if e.startswith("."):
            assert e.endswith(".lock") or ".tmp-" in e or ".old-" in e, e   # only a killed case's staging
            continue
        if e.startswith("summary"):
            continue
        res = json.loads((out / e / "result.json").read_text())
        assert res["converged"] is True
        assert sorted(os.listdir(out / e)) == ["result.json", "solution.xdmf"]
        done.add(e)
    return done


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_sweep_interrupted_resumes(tmp_path, sig):
    rng = random.Random(3000 + sig)
    path = _sweep_file(tmp_path)
    out = tmp_path / "out"
    before = set()
    for k in range(3):
        code, err = _interrupt(["sweep", str(path), "--out", str(out), "-q"], tmp_path, sig, rng.uniform(1.0, 3.0))
        _check_interrupted(code, err, sig)
        done = _check_sweep_folder(out)
        assert done >= before
        before = done
        assert not [e for e in os.listdir(out) if e.startswith(".")] if out.exists() else True
        _no_debris(tmp_path, "out")
        if code == 0:
            break
    res = subprocess.run([SKELFEM, "sweep", str(path), "--out", str(out)], cwd=tmp_path, env=ENV,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert f"{len(before)} already done, {8 - len(before)} to run" in res.stdout
    assert len(_check_sweep_folder(out)) == 8
    with open(out / "summary.csv") as f:
        assert len(f.read().strip().splitlines()) == 9


def test_interrupt_inside_a_finalizer_is_not_lost():
    """A signal whose Interrupted is raised inside a weakref callback (where Python only prints
    "Exception ignored") is delivered again and ends the run as interrupted, with no traceback."""
    code = textwrap.dedent("""
        import gc, os, signal, sys, time, weakref
        from skelfem.runtime import interrupts
        interrupts.install()
        class Box: pass
        def callback(_):
            os.kill(os.getpid(), signal.SIGINT)   # the handler raises here, inside the callback
            time.sleep(0.05)
        b = Box(); ref = weakref.ref(b, callback)
        try:
            del b; gc.collect()
            for _ in range(200):
                time.sleep(0.01)
            print("not interrupted")
        except interrupts.Interrupted as exc:
            print("interrupted", exc.code)
    """)
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert p.stdout.strip() == "interrupted 130", (p.stdout, p.stderr)
    assert "Traceback" not in p.stderr and "Exception ignored" not in p.stderr, p.stderr


def test_a_signal_after_the_result_is_published_is_dropped(tmp_path):
    """With outdir.ON_COMMIT = interrupts.finish (the CLI, one-result commands), a SIGTERM that comes
    once the result is committed does not turn a complete run into an interrupted one; before the
    commit it still interrupts and publishes nothing."""
    from skelfem.runtime import interrupts
    from skelfem.io import outdir
    interrupts.install()
    try:
        outdir.ON_COMMIT = interrupts.finish
        with pytest.raises(interrupts.Interrupted):
            with outdir.publish(tmp_path / "a") as stage:
                (stage.path / "result.json").write_text("{}")
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(0.05)
        assert not (tmp_path / "a").exists()
        with outdir.publish(tmp_path / "b") as stage:
            (stage.path / "result.json").write_text("{}")
        os.kill(os.getpid(), signal.SIGTERM)                     # after the commit: dropped
        time.sleep(0.05)
        assert (tmp_path / "b" / "result.json").exists()
    finally:
        outdir.ON_COMMIT = None
        interrupts.uninstall()


def _stop_time(args, cwd, sig, delay):
    """Run, send sig after delay seconds; (exit status, stderr, seconds from the signal to the exit)."""
    proc = _start(args, cwd)
    time.sleep(delay)
    t0 = time.monotonic()
    if proc.poll() is None:
        proc.send_signal(sig)
    try:
        _, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail(f"{args[0]} did not stop within 60 s of signal {sig}")
    return proc.returncode, err, time.monotonic() - t0


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_stops_meshing_inside_gmsh_within_two_seconds(tmp_path, sig):
    """A 3D mesh that takes Gmsh half a minute: the signal arrives while Gmsh meshes (a C++ call that
    never returns to Python; it runs in a worker thread now), and the command is gone within 2 s."""
    out = tmp_path / "big"
    args = ["simulate", str(ROOT / "geometry" / "finger3d.toml"), "--set", "mesh.size=0.6", "--force", "--out",
            str(out), "-q"]
    code, err, took = _stop_time(args, tmp_path, sig, 8.0)
    assert code == 128 + sig and error_lines(err) == ["error: interrupted"] and "Traceback" not in err, (code, err)
    assert took < 2.0, took
    assert not out.exists()
    _no_debris(tmp_path, "big")


@pytest.mark.parametrize("delay", [1.5, 2.5, 3.5])
def test_fabricate_stops_within_two_seconds_wherever_it_is(tmp_path, delay):
    """fabricate spends most of its time in OpenCASCADE and Gmsh: SIGTERM at several moments; each run
    ends within 2 s of it with 143 and no folder (or had finished: a complete one)."""
    out = tmp_path / "fab"
    code, err, took = _stop_time(["fabricate", str(ROOT / "geometry" / "finger3d.toml"), "--out", str(out), "-q"],
                                 tmp_path, signal.SIGTERM, delay)
    _check_interrupted(code, err, signal.SIGTERM)
    assert took < 2.0, took
    if code:
        assert not out.exists()
    else:
        assert (out / "fabrication.json").exists()
    _no_debris(tmp_path, "fab")


def test_an_interrupted_gmsh_call_is_left_behind_and_gmsh_refused_after_it(tmp_path):
    """In process: interruptible() returns control to the caller at the signal (its worker thread keeps
    the call), and later Gmsh use in that process is refused with one clear message."""
    script = textwrap.dedent("""
        import os, signal, threading, time
        from skelfem.runtime import interrupts
        from skelfem.design.occ import MeshingError, ensure_gmsh
        interrupts.install()
        threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGINT)).start()
        t0 = time.monotonic()
        try:
            interrupts.interruptible(time.sleep, 30.0)
        except interrupts.Interrupted:
            print("interrupted after", round(time.monotonic() - t0, 2), "abandoned", interrupts.abandoned())
        import gmsh
        try:
            ensure_gmsh(gmsh)
        except MeshingError as exc:
            print("refused:", exc)
        os._exit(0)
    """)
    p = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env=ENV, capture_output=True, text=True,
                       timeout=60)
    lines = p.stdout.splitlines()
    assert p.returncode == 0 and len(lines) == 2, (p.stdout, p.stderr)
    took = float(lines[0].split()[2])
    assert took < 0.6 and lines[0].endswith("abandoned Gmsh"), lines
    assert lines[1] == "refused: Gmsh is still inside an interrupted call in this process: start a new one"


@pytest.mark.parametrize("delay", [0.3, 0.36, 0.42, 0.48, 0.54, 0.6, 0.66])
def test_a_signal_during_start_up_is_one_line_and_130(tmp_path, delay):
    """Interrupted while the command line imports itself (MPI_Init, DOLFINx importing Gmsh, which sets
    SIGINT's default action): it was a traceback with status 1, or the process killed outright (-2)."""
    proc = _start(SIMULATE + ["--out", str(tmp_path / "out")], tmp_path)
    time.sleep(delay)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    _check_interrupted(proc.returncode, err, signal.SIGINT)
