"""Does ``skelfem simulate --tol`` meet its tolerance, and is it cheaper than a fine mesh?

    python studies/tol_check.py [--designs finger finger_bones] [--tols 2 0.5 0.2] [--ref-size 0.5]

For each design it solves a reference (P2 at --ref-size, the finest mesh of
studies/speed_accuracy.py) and each tolerance with the command itself
(``python -m skelfem simulate``, one process per run, as a user runs it),
then reports the chosen discretisation, the marker error against the
reference, and wall times (each run's own ``timings.total`` from result.json:
for --tol it includes the estimate solve, not the interpreter's start-up).
run(**params) returns the rows; main(argv) prints them and writes tol_check.csv.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from skelfem.output import say, write_csv

ROOT = Path(__file__).resolve().parents[1]


def _simulate(design: str, out: Path, *extra: str) -> tuple[dict, float]:
    """`skelfem simulate` in its own process; (result.json, the run's total time in s)."""
    cmd = [sys.executable, "-m", "skelfem", "simulate", str(ROOT / "geometry" / f"{design}.toml"), "--out", str(out),
           "-q", "--no-picture", *extra]
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    res = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if res.returncode != 0:
        raise RuntimeError(f"{design} {extra}: exit {res.returncode}: {res.stderr.strip()}")
    result = json.loads((out / "result.json").read_text())
    return result, float(result["timings"]["total"])


def _markers(res: dict) -> np.ndarray:
    return np.array([m["position"] for m in res["markers"].values()])


def run(designs=("finger", "finger_bones"), tols=(2.0, 0.5, 0.2), ref_size: float = 0.5,
        out: Path | None = None) -> list[dict]:
    out = Path(out or ROOT / "studies" / "output" / "tol_check")
    rows = []
    for design in designs:
        ref, t_ref = _simulate(design, out / design / "reference", "--set", "mesh.degree=2",
                               "--set", f"mesh.size={ref_size}")
        say(f"{design}: reference P2 h={ref_size}: {t_ref:.1f} s", flush=True)
        for tol in tols:
            res, t = _simulate(design, out / design / f"tol_{tol:g}", "--tol", str(tol))
            err = float(np.linalg.norm(_markers(res) - _markers(ref), axis=1).max())
            a = res["accuracy"]
            rows.append({"design": design, "tol": tol, "degree": a["degree"], "size": a["size"],
                         "estimated_error": a["estimated_error"], "error_vs_reference": err,
                         "met": err <= tol, "time": t, "reference_time": t_ref, "dofs": res["dofs"],
                         "reference_dofs": ref["dofs"]})
            r = rows[-1]
            say(f"  tol {tol:g} mm: P{r['degree']} h={r['size']:g} ({r['dofs']} DOFs), estimated "
                  f"{r['estimated_error']:.3g} mm, actual {err:.3g} mm, {t:.1f} s "
                  f"({t / t_ref:.2f} of the reference)", flush=True)
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--designs", nargs="+", default=["finger", "finger_bones"])
    p.add_argument("--tols", nargs="+", type=float, default=[2.0, 0.5, 0.2])
    p.add_argument("--ref-size", type=float, default=0.5)
    p.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "tol_check")
    a = p.parse_args(argv)
    rows = run(a.designs, a.tols, a.ref_size, a.out)
    a.out.mkdir(parents=True, exist_ok=True)
    write_csv(a.out / "tol_check.csv", list(rows[0]), rows)
    say(f"{sum(r['met'] for r in rows)}/{len(rows)} tolerances met; table in {a.out / 'tol_check.csv'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
