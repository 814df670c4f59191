"""Wall time of one sweep run serially and under ``mpirun -n N``: the parallel speed-up of batch runs.

    python studies/sweep_speedup.py [--cases 8] [--ranks 2] [--size 1.5] [--out studies/output/sweep_speedup]

It writes a sweep of `cases` contractions of geometry/finger.toml, runs it
with ``skelfem sweep`` once on 1 rank and once on `ranks` ranks (fresh output
folders, FFCx cache warm), and prints both wall times and their ratio. As a
control it also runs `ranks` independent serial sweeps on shares of the
cases at the same time, without MPI: their ratio is what the machine allows.
run(**params) returns the numbers; main(argv) prints them and writes speedup.json.
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

from skelfem.io.files import say, write_json

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
       "OMPI_MCA_rmaps_base_oversubscribe": "1", "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}


def _sweep_file(folder: Path, cases: int, size: float, part: slice = slice(None), name="speedup") -> Path:
    values = [1.0 + 7.0 * i / max(cases - 1, 1) for i in range(cases)][part]
    contractions = ", ".join(f"{v:.3f}" for v in values)
    path = folder / f"{name}.toml"
    path.write_text(f'design = "{ROOT / "geometry" / "finger.toml"}"\nname = "speedup"\n'
                    f'set = ["mesh.size={size}"]\n\n[parameters]\n'
                    f'"cables.flexor.contraction" = [{contractions}]\n')
    return path


def _timed(cmd: list[str], out: Path) -> float:
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    res = subprocess.run(cmd + ["--out", str(out), "-q"], env=ENV, capture_output=True, text=True)
    elapsed = time.perf_counter() - t0
    if res.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{res.stdout}{res.stderr}")
    return elapsed


def run(cases: int = 8, ranks: int = 2, size: float = 1.5, out: Path | None = None) -> dict:
    """Time the same sweep on 1 and on `ranks` MPI ranks."""
    out = Path(out or ROOT / "studies" / "output" / "sweep_speedup")
    out.mkdir(parents=True, exist_ok=True)
    path = _sweep_file(out, cases, size)
    skelfem = [sys.executable, "-m", "skelfem", "sweep", str(path)]
    _timed(skelfem, out / "warmup")          # compile forms once, so both runs find them cached
    serial = _timed(skelfem, out / "serial")
    parallel = _timed(["mpirun", "-n", str(ranks)] + skelfem, out / "parallel")
    control = _independent(out, cases, ranks, size)
    return {"cases": cases, "ranks": ranks, "mesh_size": size, "serial_s": serial,
            "parallel_s": parallel, "ratio": parallel / serial,
            "independent_s": control, "machine_ratio": control / serial}


def _independent(out: Path, cases: int, ranks: int, size: float) -> float:
    """Control without MPI: `ranks` separate serial sweeps, each on its share of the cases, at once.

    Its time over the serial time is the best ratio this machine allows for
    concurrent processes (shared cores, memory bandwidth, turbo).
    """
    procs, t0 = [], time.perf_counter()
    for r in range(ranks):
        path = _sweep_file(out, cases, size, slice(r, None, ranks), name=f"share{r}")
        folder = out / f"independent{r}"
        shutil.rmtree(folder, ignore_errors=True)
        procs.append(subprocess.Popen([sys.executable, "-m", "skelfem", "sweep", str(path), "--out", str(folder),
                                       "-q"], env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE))
    for p in procs:
        if p.wait() != 0:
            raise RuntimeError(p.stderr.read().decode())
    return time.perf_counter() - t0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cases", type=int, default=8)
    p.add_argument("--ranks", type=int, default=2)
    p.add_argument("--size", type=float, default=1.5)
    p.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "sweep_speedup")
    a = p.parse_args(argv)
    r = run(a.cases, a.ranks, a.size, a.out)
    say(f"{r['cases']} cases of finger.toml (mesh size {r['mesh_size']} mm): serial {r['serial_s']:.1f} s, "
        f"{r['ranks']} ranks {r['parallel_s']:.1f} s, ratio {r['ratio']:.2f}; {r['ranks']} independent serial "
        f"processes on the same cases at once {r['independent_s']:.1f} s, ratio {r['machine_ratio']:.2f} "
        "(what this machine allows)")
    write_json(a.out / "speedup.json", r)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
