"""Adversarial inputs under `mpirun -n 2`: every failure ends both ranks promptly with one error line.

Each run has a timeout that fails the test instead of hanging it. Open MPI
adds its own notices after a non-zero exit; the test counts the lines that
start with `error:` (exactly one) and looks for tracebacks (none).
"""
from __future__ import annotations

import shutil
import subprocess
import sys
import textwrap
import time

import pytest

from _hardening import ENV, SKELFEM, assert_one_error, box3d, changed, listing, strip2d, toml_dumps

pytestmark = [pytest.mark.mpi, pytest.mark.skipif(shutil.which("mpirun") is None, reason="needs mpirun")]

TIMEOUT = 90          # s; a hang fails the test


def _mpirun(args, cwd, timeout=TIMEOUT):
    t0 = time.perf_counter()
    try:
        res = subprocess.run(["mpirun", "-n", "2", *map(str, args)], cwd=cwd, env=ENV, capture_output=True,
                             text=True, timeout=timeout)
    except subprocess.TimeoutExpired as exc:
        pytest.fail(f"mpirun -n 2 {' '.join(map(str, args))} hung for {timeout} s: {exc.stderr}")
    return res, time.perf_counter() - t0


@pytest.fixture
def work(tmp_path):
    w = tmp_path / "a" / "work"
    w.mkdir(parents=True)
    (w / "strip.toml").write_text(toml_dumps(strip2d()))
    return w


def _refused(work, root, *args, code=1, match=None, within=30.0):
    before = listing(root)
    res, seconds = _mpirun([SKELFEM, *args], work)
    assert res.returncode == code, res.stdout + res.stderr
    assert_one_error(res.stderr, match)
    assert listing(root) == before
    assert seconds < within, f"took {seconds:.1f} s"
    return seconds


def test_output_below_a_file_ends_both_ranks_at_once(work, tmp_path):
    (work / "taken").write_text("x")
    s = _refused(work, tmp_path, "simulate", "strip.toml", "-q", "--out", "taken/sub", match="exists and is not a folder")
    print(f"\nmpirun -n 2 simulate --out <file>/sub: exit 1 after {s:.1f} s")


@pytest.mark.parametrize("args, match", [
    (("--out", "/proc/skelfem-test/out"), "/proc/skelfem-test/out"),
    (("--set", "name=../../x"), "name: the design name"),
    (("--set", "mesh.size=1e-7"), "more than this machine solves"),
    (("--out", "."), "working folder"),
    (("--tol", "nan"), "--tol"),
    (("--colour", "red"), "unrecognized arguments"),
])
def test_bad_input_under_mpirun(work, tmp_path, args, match):
    _refused(work, tmp_path, "simulate", "strip.toml", "-q", *args, match=match)


def test_3d_overlapping_bones_under_mpirun_are_refused_not_crashed(work, tmp_path):
    d = changed(box3d(), (("bones", 1, "solids"), [{"box": {"min": [3, 3, 15], "max": [7, 7, 36]}}]))
    (work / "block.toml").write_text(toml_dumps(d))
    _refused(work, tmp_path, "simulate", "block.toml", "-q", match="overlaps bone 'b1'")


def test_ik_under_mpirun_is_refused(work, tmp_path):
    _refused(work, tmp_path, "ik", "strip.toml", "--marker", "tip", "--target", "5", "50", "-q",
             match="runs on one MPI process")


def test_output_locked_under_mpirun(work, tmp_path):
    import fcntl
    import os
    fd = os.open(work / ".res.lock", os.O_RDWR | os.O_CREAT)
    fcntl.flock(fd, fcntl.LOCK_EX)
    try:
        _refused(work, tmp_path, "simulate", "strip.toml", "-q", "--out", "res", match="another skelfem run")
    finally:
        os.close(fd)


def _sweep(work, ranks_per_case, cases):
    text = f'design = "strip.toml"\nset = ["mesh.size=5"]\nranks_per_case = {ranks_per_case}\n'
    for name, sets in cases:
        text += f'\n[[cases]]\nname = "{name}"\nset = {{ {sets} }}\n'
    (work / "sweep.toml").write_text(text)
    return "sweep.toml"


def test_sweep_two_ranks_per_case_output_below_a_file(work, tmp_path):
    (work / "taken").write_text("x")
    sweep = _sweep(work, 2, [("a", '"cables.flexor.contraction" = 1.0')])
    s = _refused(work, tmp_path, "sweep", sweep, "-q", "--out", "taken/sub", match="exists and is not a folder")
    print(f"\nmpirun -n 2 sweep (ranks_per_case = 2) --out <file>/sub: exit 1 after {s:.1f} s")


def test_sweep_two_ranks_per_case_goes_on_after_a_bad_case(work, tmp_path):
    sweep = _sweep(work, 2, [("good", '"cables.flexor.contraction" = 1.0'),
                             ("bad", '"materials.soft.nu" = 0.7'),
                             ("also_good", '"cables.flexor.contraction" = 2.0')])
    res, _ = _mpirun([SKELFEM, "sweep", sweep, "--out", "out", "-q"], work)
    assert res.returncode == 1, res.stdout + res.stderr
    assert_one_error(res.stderr, "1 of 3 case(s) failed (bad)")
    assert sorted(p for p in listing(work) if "/" not in p) == ["out", "strip.toml", "sweep.toml"]
    assert sorted(listing(work / "out")) == ["also_good", "also_good/result.json", "also_good/solution.xdmf",
                                             "bad", "bad/result.json", "good", "good/result.json",
                                             "good/solution.xdmf", "summary.csv", "summary.png"]


def test_sweep_named_case_escape_is_refused_under_mpirun(work, tmp_path):
    sweep = _sweep(work, 1, [("..", '"cables.flexor.contraction" = 1.0')])
    _refused(work, tmp_path, "sweep", sweep, "-q", "--out", "out", match="cases[0].name")


GUARD = textwrap.dedent("""
    import sys
    from mpi4py import MPI
    from skelfem.runtime import mpiguard
    comm = MPI.COMM_WORLD
    ctl = mpiguard.control(comm)
    mode = sys.argv[1]
    if mode == "one" and comm.rank == 1:
        code, msg, in_step = 3, "internal error: rank 1 alone failed", False
    elif mode == "both":
        code, msg, in_step = 1, "both ranks refused the input", False
    else:
        code, msg, in_step = 0, None, True
    if mode == "one" and comm.rank == 0:
        comm.barrier()                     # waits for rank 1, which never comes
    code, msg = mpiguard.agree(ctl, code, msg, in_step, grace=2.0,
                               say=lambda m: print("error: " + m, file=sys.stderr, flush=True))
    if msg and comm.rank == 0:
        print("error: " + msg, file=sys.stderr, flush=True)
    sys.exit(code)
""")


@pytest.mark.parametrize("mode, code, match", [("one", 3, "rank 1 alone failed"),
                                               ("both", 1, "both ranks refused the input"),
                                               ("none", 0, None)])
def test_a_fault_on_one_rank_ends_every_rank(tmp_path, mode, code, match):
    script = tmp_path / "guard.py"
    script.write_text(GUARD)
    res, seconds = _mpirun([sys.executable, script, mode], tmp_path, timeout=60)
    assert res.returncode == code, res.stderr
    if match:
        assert_one_error(res.stderr, match)
    else:
        assert "error:" not in res.stderr
    assert seconds < 20
