"""arm3d as bundled on a fine mesh with the iterative solver: wall time, peak memory per DOF, tensions.

    python studies/arm3d_fine.py [--size 0.62] [--ranks 1] [--out studies/output/arm3d_fine]

One ``skelfem simulate geometry/arm3d.toml --force --set mesh.size=SIZE --set
solver.linear=iterative`` in a fresh process (under ``mpirun -n RANKS`` when
RANKS > 1). Each rank reports its own peak resident memory (getrusage), and
the peak is their sum: what the machine had to hold. Read from result.json:
DOFs, cells, Newton iterations, the Krylov iterations of each Newton step,
fallbacks, the timings (meshing, compile, solve), the tendon tensions and the
markers. At h = 0.62 mm arm3d has 1.43 million DOFs (P1). run(**params)
returns the numbers; main(argv) prints them and writes arm3d_fine.json.
"""
from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from mpi_speed import ENV  # noqa: E402  (the same environment for mpirun)

CHILD = """
import resource, sys
from skelfem.cli.main import main
try:
    code = main(sys.argv[1:])
finally:
    from mpi4py import MPI
    print(f"peak_kb {MPI.COMM_WORLD.rank} {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}", file=sys.stderr)
sys.exit(code)
"""


def run(size: float = 0.62, ranks: int = 1, out: Path | None = None, progress=print) -> dict:
    out = Path(out or ROOT / "studies" / "output" / "arm3d_fine")
    folder = out / "run"
    shutil.rmtree(folder, ignore_errors=True)
    sets = [f"mesh.size={size}", "solver.linear=iterative"]
    args = ["simulate", "geometry/arm3d.toml", "--force", "--no-picture", "-q", "--out", str(folder)]   # cwd: ROOT
    for s in sets:
        args += ["--set", s]
    cmd = [sys.executable, "-c", CHILD] + args
    if ranks > 1:
        cmd = ["mpirun", "-n", str(ranks)] + cmd
    progress(f"arm3d at h = {size} mm on {ranks} rank(s): " + " ".join(["skelfem"] + args))
    t0 = time.perf_counter()
    res = subprocess.run(cmd, env=ENV, capture_output=True, text=True, cwd=ROOT)
    wall = time.perf_counter() - t0
    peaks = [int(kb) for _, kb in re.findall(r"peak_kb (\d+) (\d+)", res.stderr)]
    if res.returncode != 0 or len(peaks) != ranks:
        raise RuntimeError(f"the run failed (exit {res.returncode}):\n{res.stdout[-2000:]}{res.stderr[-2000:]}")
    r = json.loads((folder / "result.json").read_text())
    shutil.rmtree(folder, ignore_errors=True)
    its = [k for step in r.get("linear_iterations", []) for k in step]
    peak = sum(peaks) * 1024.0
    return {"command": "skelfem " + " ".join(a for a in args if a not in ("--out", str(folder))),
            "ranks": ranks, "size": size, "dofs": r["dofs"], "cells": r.get("cells"), "status": r["status"],
            "newton_iterations": r["newton_iterations"], "linear_solver": r.get("linear_solver"),
            "linear_fallbacks": r.get("linear_fallbacks", 0), "krylov_per_newton": its,
            "krylov_mean": sum(its) / max(len(its), 1), "timings": r["timings"], "wall_s": wall,
            "peak_gb": peak / 2**30, "peak_per_rank_gb": [p / 2**20 for p in peaks],
            "kb_per_dof": peak / 1024.0 / r["dofs"],
            "tensions": {k: c["tension"] for k, c in r["cables"].items()},
            "markers": {k: m["position"] for k, m in r["markers"].items()}}


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=float, default=0.62)
    p.add_argument("--ranks", type=int, default=1)
    p.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "arm3d_fine")
    a = p.parse_args(argv)
    data = run(a.size, a.ranks, a.out)
    print(f"{data['dofs']} DOFs on {data['ranks']} rank(s): {data['status']}, {data['wall_s']:.0f} s, "
          f"{data['peak_gb']:.2f} GB ({data['kb_per_dof']:.2f} KB per DOF), {data['newton_iterations']} Newton, "
          f"Krylov mean {data['krylov_mean']:.1f}")
    from skelfem.io.files import write_json
    a.out.mkdir(parents=True, exist_ok=True)
    write_json(a.out / "arm3d_fine.json", data)
    return data


if __name__ == "__main__":
    main()
