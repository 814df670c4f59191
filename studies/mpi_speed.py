"""Wall time of one ``skelfem simulate`` serially and under ``mpirun -n N``: does a parallel run pay?

    python studies/mpi_speed.py [DESIGN] [--set mesh.size=2.5] [--ranks 2] [--repeats 3]
                                [--warmup-set mesh.size=4] [--out studies/output/mpi_speed]

Runs the same simulation alternately on 1 and on `ranks` ranks, `repeats`
times each (after one warm-up run that fills the form cache), each in a
fresh process writing a fresh folder, and reports the medians of the wall
times, of the set-up (meshing + model: `mesh` + `compile` in result.json)
and of the solve, and their ratios. Alternating keeps both under the same
machine load. The two runs must agree (energy, Newton iterations).
run(**params) returns the numbers; main(argv) prints them and writes mpi_speed.json.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
       "OMPI_MCA_rmaps_base_oversubscribe": "1", "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
       "MPLBACKEND": "Agg"}


def _simulate(design: Path, sets: list[str], ranks: int, out: Path) -> dict:
    """One run in a fresh process: wall time and its result.json."""
    shutil.rmtree(out, ignore_errors=True)
    cmd = [sys.executable, "-m", "skelfem", "simulate", str(design), "--out", str(out), "-q"]
    for s in sets:
        cmd += ["--set", s]
    if ranks > 1:
        cmd = ["mpirun", "-n", str(ranks)] + cmd
    t0 = time.perf_counter()
    res = subprocess.run(cmd, env=ENV, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if res.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{res.stdout}{res.stderr}")
    result = json.loads((out / "result.json").read_text())
    t = result["timings"]
    return {"wall": wall, "setup": t["mesh"] + t["compile"], "solve": t["solve"],
            "energy": result["energy"], "newton_iterations": result["newton_iterations"],
            "dofs": result["dofs"]}


def run(design=ROOT / "geometry" / "arm3d.toml", sets=("mesh.size=2.5",), ranks: int = 2,
        repeats: int = 3, out: Path | None = None, warmup_sets=()) -> dict:
    """Median wall, set-up and solve times on 1 and on `ranks` ranks, and their ratios. warmup_sets:
    more overrides for the warm-up run only (a coarser mesh.size compiles the same forms sooner)."""
    out = Path(out or ROOT / "studies" / "output" / "mpi_speed")
    out.mkdir(parents=True, exist_ok=True)
    sets = list(sets)
    _simulate(Path(design), sets + list(warmup_sets), 1, out / "warmup")
    shutil.rmtree(out / "warmup", ignore_errors=True)
    runs: dict = {1: [], ranks: []}
    for _ in range(repeats):
        for n in (1, ranks):
            runs[n].append(_simulate(Path(design), sets, n, out / f"ranks{n}"))
    med = {n: {k: float(np.median([r[k] for r in rs])) for k in ("wall", "setup", "solve")}
           for n, rs in runs.items()}
    first = runs[1][0]
    return {"design": str(design), "set": sets, "ranks": ranks, "repeats": repeats, "dofs": first["dofs"],
            "serial": med[1], "parallel": med[ranks],
            "wall_ratio": med[ranks]["wall"] / med[1]["wall"],
            "setup_ratio": med[ranks]["setup"] / med[1]["setup"],
            "solve_ratio": med[ranks]["solve"] / med[1]["solve"],
            "energy": first["energy"],
            "energy_difference": max(abs(r["energy"] - first["energy"]) for rs in runs.values() for r in rs),
            "newton_iterations": sorted({r["newton_iterations"] for rs in runs.values() for r in rs}),
            "walls": {str(n): [r["wall"] for r in rs] for n, rs in runs.items()}}


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("design", nargs="?", default=str(ROOT / "geometry" / "arm3d.toml"))
    p.add_argument("--set", action="append", dest="sets", default=None, metavar="KEY=VALUE")
    p.add_argument("--ranks", type=int, default=2)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--warmup-set", action="append", dest="warmup_sets", default=[], metavar="KEY=VALUE",
                   help="override for the warm-up run only, e.g. mesh.size=4")
    p.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "mpi_speed")
    a = p.parse_args(argv)
    r = run(a.design, a.sets if a.sets is not None else ["mesh.size=2.5"], a.ranks, a.repeats, a.out,
            a.warmup_sets)
    (a.out / "mpi_speed.json").write_text(json.dumps(r, indent=1))
    s, q = r["serial"], r["parallel"]
    print(f"{Path(r['design']).name} {' '.join(r['set'])}: {r['dofs']} DOFs, medians of {r['repeats']}")
    print(f"  1 rank : wall {s['wall']:.2f} s, set-up {s['setup']:.2f} s, solve {s['solve']:.2f} s")
    print(f"  {r['ranks']} ranks: wall {q['wall']:.2f} s, set-up {q['setup']:.2f} s, solve {q['solve']:.2f} s")
    print(f"  ratios: wall {r['wall_ratio']:.2f}, set-up {r['setup_ratio']:.2f}, solve {r['solve_ratio']:.2f}; "
          f"energies agree to {r['energy_difference']:.1e}")
    return r


if __name__ == "__main__":
    main()
