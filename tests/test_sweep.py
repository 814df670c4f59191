"""`skelfem sweep`: cases, failures recorded, resume after interruption, parallel under mpirun."""
import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from skelfem.cli.main import main
from skelfem.design import DesignError
from skelfem.jobs.sweep import load_sweep

ROOT = Path(__file__).resolve().parents[1]
SKELFEM = [str(Path(sys.executable).parent / "skelfem")]
MPI_ENV = {**os.environ, "OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
           "OMPI_MCA_rmaps_base_oversubscribe": "1", "OPENBLAS_NUM_THREADS": "1"}


def _sweep_file(tmp_path, contractions=(2.0, 5.0), size=4.0, broken=True) -> Path:
    text = f'''design = "{ROOT / "geometry" / "finger.toml"}"
set = ["mesh.size={size}", "solver.steps=2"]

[parameters]
"cables.flexor.contraction" = [{", ".join(map(str, contractions))}]
"materials.pla.E" = [1.0, 1000.0]
'''
    if broken:
        text += '''
[[cases]]
name = "broken"
set = { "materials.pla.nu" = 0.7 }
'''
    path = tmp_path / "sweep.toml"
    path.write_text(text)
    return path


def _summary(out):
    with open(out / "summary.csv") as f:
        return list(csv.DictReader(f))


def test_sweep_runs_every_case_and_records_the_failing_one(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["sweep", str(_sweep_file(tmp_path)), "--out", str(out)]) == 1     # a case had bad input
    assert "1 of 5 case(s) failed (broken)" in capsys.readouterr().err
    rows = _summary(out)
    assert len(rows) == 5
    broken = next(r for r in rows if r["case"] == "broken")
    assert broken["status"] == "bad_input" and broken["converged"] == "False"
    assert "materials.pla.nu" in json.loads((out / "broken" / "result.json").read_text())["error"]
    good = [r for r in rows if r["case"] != "broken"]
    assert all(r["converged"] == "True" for r in good)
    # more contraction, more tip motion, at either bone stiffness
    by = {(float(r["cables.flexor.contraction"]), float(r["materials.pla.E"])): float(r["tip.|u|"]) for r in good}
    assert by[(5.0, 1.0)] > by[(2.0, 1.0)] and by[(5.0, 1000.0)] > by[(2.0, 1000.0)]
    assert (out / "summary.png").stat().st_size > 10_000


def test_rerun_completes_only_missing_cases(tmp_path):
    out = tmp_path / "out"
    path = _sweep_file(tmp_path, broken=False)
    assert main(["sweep", str(path), "--out", str(out), "-q"]) == 0
    done = sorted(out.glob("*/result.json"))
    assert len(done) == 4
    stamps = {p: p.stat().st_mtime_ns for p in done}
    missing = done[1]
    shutil.rmtree(missing.parent)
    sweep = load_sweep(path)
    from skelfem.jobs.sweep import run_sweep
    summary = run_sweep(sweep, out, progress=None)
    assert summary["ran"] == 1 and summary["converged"] == 4
    for p, t in stamps.items():
        if p != missing:
            assert p.stat().st_mtime_ns == t         # untouched
    # a changed override invalidates the stored case
    path.write_text(path.read_text().replace("solver.steps=2", "solver.steps=3"))
    assert run_sweep(load_sweep(path), out, progress=None)["ran"] == 4


def test_killed_sweep_resumes(tmp_path):
    out = tmp_path / "out"
    path = _sweep_file(tmp_path, contractions=(1.0, 2.0, 3.0, 4.0), size=3.0, broken=False)
    proc = subprocess.Popen(SKELFEM + ["sweep", str(path), "--out", str(out), "-q"], env=MPI_ENV,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    while not list(out.glob("*/result.json")) and time.time() < deadline and proc.poll() is None:
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    first = {p.parent.name for p in out.glob("*/result.json")}
    assert 1 <= len(first) < 8, first
    res = subprocess.run(SKELFEM + ["sweep", str(path), "--out", str(out)], env=MPI_ENV,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert f"{len(first)} already done, {8 - len(first)} to run" in res.stdout
    assert len(_summary(out)) == 8 and all(r["converged"] == "True" for r in _summary(out))


@pytest.mark.mpi
@pytest.mark.skipif(shutil.which("mpirun") is None, reason="needs mpirun")
def test_sweep_under_mpirun_splits_cases_over_ranks(tmp_path):
    out = tmp_path / "out"
    path = _sweep_file(tmp_path)
    res = subprocess.run(["mpirun", "-n", "2"] + SKELFEM + ["sweep", str(path), "--out", str(out)],
                         env=MPI_ENV, capture_output=True, text=True, timeout=300)
    assert res.returncode == 1, res.stdout + res.stderr            # the broken case: bad input
    assert [line for line in res.stderr.splitlines() if line.startswith("error:")] == [
        line for line in res.stderr.splitlines() if "1 of 5 case(s) failed (broken)" in line]
    assert "on 2 group(s) of 1 rank(s)" in res.stdout
    rows = _summary(out)
    assert len(rows) == 5 and sum(r["converged"] == "True" for r in rows) == 4
    serial = tmp_path / "serial"
    assert main(["sweep", str(path), "--out", str(serial), "-q"]) == 1
    for a, b in zip(rows, _summary(serial)):
        if a["converged"] == "True":
            assert float(a["tip.x"]) == pytest.approx(float(b["tip.x"]), rel=1e-9)


@pytest.mark.parametrize("text, expected", [
    ('design = "nope.toml"\n[parameters]\n"mesh.size" = [1]\n', "design: no such file"),
    ('design = "{design}"\n', "no cases"),
    ('design = "{design}"\ncolour = 1\n', "colour: unknown key"),
    ('design = "{design}"\n[parameters]\n"mesh.size" = []\n', "parameters.mesh.size: must be a non-empty list"),
])
def test_bad_sweep_file_is_one_error(tmp_path, text, expected):
    path = tmp_path / "s.toml"
    path.write_text(text.format(design=ROOT / "geometry" / "finger.toml"))
    with pytest.raises(DesignError, match=expected):
        load_sweep(path)


def test_bundled_sweep_file_loads():
    sweep = load_sweep(ROOT / "studies" / "stiffness_sweep.toml")
    assert sweep.name == "stiffness" and len(sweep.cases) == 12 and sweep.design.name == "finger.toml"
