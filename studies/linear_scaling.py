"""Direct (MUMPS) against iterative (CG + GAMG) linear solves on a 3D design, mesh by mesh.

    python studies/linear_scaling.py [--design geometry/post3d.toml] [--degree 2]
                                     [--sizes 1.2 0.8 0.6] [--solvers direct iterative]
                                     [--out studies/output/linear_scaling] [--figures studies/figures]

Each case is one ``skelfem simulate`` of the design at one mesh size with
``--set solver.linear=...``, in its own process, so that its peak memory
(the child's maximum resident set, from ``os.wait4``) and wall time are its
own; both solvers run each size in the same study run, so their ratio holds
on a noisy machine. Read from each result.json: DOFs, Newton iterations,
Krylov iterations per Newton step, fallbacks, and the tip's marker position
(the two solvers' answers compared). The default is post3d at P2, the
design of the 3D accuracy reference.

run(**params) returns the rows; main(argv) also writes linear_scaling.json
into out and linear_scaling.png into figures.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DESIGN = ROOT / "geometry" / "post3d.toml"


def case(design: Path, size: float, degree: int, solver: str) -> dict:
    """One simulate run in a child process: its numbers, wall time and peak memory."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out"
        cmd = [sys.executable, "-m", "skelfem", "simulate", str(design), "--out", str(out), "-q",
               "--set", f"mesh.size={size}", "--set", f"mesh.degree={degree}",
               "--set", f"solver.linear={solver}"]
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        err = proc.stderr.read().decode(errors="replace").strip()
        proc.stderr.close()
        code = os.waitstatus_to_exitcode(status)
        res = json.loads((out / "result.json").read_text()) if (out / "result.json").exists() else {}
    its = [k for step in res.get("linear_iterations", []) for k in step]
    row = {"size": size, "degree": degree, "solver": solver, "exit": code, "wall_s": wall,
           "peak_mb": usage.ru_maxrss / 1024.0, "dofs": res.get("dofs"), "status": res.get("status", err[-200:]),
           "newton_iterations": res.get("newton_iterations"), "krylov_per_newton": its,
           "fallbacks": res.get("linear_fallbacks", 0),
           "markers": {k: v["position"] for k, v in (res.get("markers") or {}).items()}}
    if row["dofs"]:
        row["kb_per_dof"] = usage.ru_maxrss / row["dofs"]
    return row


def run(design: Path = DESIGN, sizes=(1.2, 0.8, 0.6), degree: int = 2,
        solvers=("direct", "iterative"), progress=print) -> dict:
    rows = []
    for h in sizes:
        for solver in solvers:
            r = case(Path(design), float(h), int(degree), solver)
            rows.append(r)
            progress(f"h = {h}: {solver}: {r['dofs']} DOFs, {r['wall_s']:.1f} s, {r['peak_mb']:.0f} MB, "
                     f"{r['status']}")
    for h in sizes:                     # the two solvers' answers, side by side
        pair = {r["solver"]: r for r in rows if r["size"] == float(h)}
        if {"direct", "iterative"} <= set(pair) and pair["direct"]["markers"]:
            a, b = pair["direct"]["markers"], pair["iterative"]["markers"]
            diff = max(abs(x - y) for k in a for x, y in zip(a[k], b.get(k, a[k])))
            pair["iterative"]["marker_difference_mm"] = diff
            pair["iterative"]["time_ratio"] = pair["iterative"]["wall_s"] / pair["direct"]["wall_s"]
            pair["iterative"]["memory_ratio"] = pair["iterative"]["peak_mb"] / pair["direct"]["peak_mb"]
    return {"design": Path(design).name, "degree": degree, "rows": rows,
            "cpu": os.cpu_count()}


def figure(data: dict, path: Path) -> None:
    import matplotlib.pyplot as plt
    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.6))
    for solver, style in (("direct", "o-"), ("iterative", "s-")):
        rows = [r for r in data["rows"] if r["solver"] == solver and r["dofs"]]
        n = [r["dofs"] for r in rows]
        a.loglog(n, [r["wall_s"] for r in rows], style, label=solver)
        b.loglog(n, [r["kb_per_dof"] for r in rows], style, label=solver)
    a.set_xlabel("DOFs")
    a.set_ylabel("wall time of simulate (s)")
    b.set_xlabel("DOFs")
    b.set_ylabel("peak memory per DOF (KB)")
    for ax in (a, b):
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.suptitle(f"{data['design']}, P{data['degree']}: direct (MUMPS) and iterative (CG + GAMG)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--design", type=Path, default=DESIGN)
    p.add_argument("--degree", type=int, default=2)
    p.add_argument("--sizes", type=float, nargs="+", default=[1.2, 0.8, 0.6])
    p.add_argument("--solvers", nargs="+", default=["direct", "iterative"], choices=["direct", "iterative"])
    p.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "linear_scaling")
    p.add_argument("--figures", type=Path, default=ROOT / "studies" / "figures")
    a = p.parse_args(argv)
    data = run(a.design, a.sizes, a.degree, a.solvers)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "linear_scaling.json").write_text(json.dumps(data, indent=1))
    figure(data, a.figures / "linear_scaling.png")
    return data


if __name__ == "__main__":
    main()
