"""The 3D P2 reference of the accuracy studies, solved with the direct and the iterative linear solver.

    python studies/reference_3d.py [--design post3d] [--h-ref 0.841] [--solvers direct iterative]
                                   [--out studies/output/reference_3d]

``studies/tol_check.py``'s reference for a 3D design (P2 at 2 h, sqrt 2 h
and h, graded at the clamped edges, warm-started; 682k DOFs at h = 0.841 on
post3d) is solved once per linear solver, each in its own process, so that
its wall time and peak memory (the child's maximum resident set) are its
own. Read from each result.json: DOFs, Newton iterations, the solver, its
fallbacks and the tip; the tips of the two solvers are compared.
run(**params) returns the rows; main(argv) also writes reference_3d.json.
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

CHILD = """
import importlib.util
from pathlib import Path
import skelfem.design as D
load = D.load_design
D.load_design = lambda path, overrides=(): load(path, list(overrides) + ["solver.linear={linear}"])
spec = importlib.util.spec_from_file_location("tol_check", {script!r})
tol_check = importlib.util.module_from_spec(spec)
spec.loader.exec_module(tol_check)
tol_check.solve_reference({design!r}, {h!r}, Path({out!r}))
"""


def case(design: str, h_ref: float, linear: str) -> dict:
    """One reference in a child process: its numbers, wall time and peak memory."""
    with tempfile.TemporaryDirectory() as tmp:
        code = CHILD.format(script=str(ROOT / "studies" / "tol_check.py"), linear=linear, design=design,
                            h=h_ref, out=tmp)
        t0 = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-c", code], cwd=ROOT, stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, env={**os.environ, "OPENBLAS_NUM_THREADS": "1"})
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        err = proc.stderr.read().decode(errors="replace").strip()
        proc.stderr.close()
        path = Path(tmp) / "result.json"
        res = json.loads(path.read_text()) if path.exists() else {}
    return {"solver": linear, "exit": os.waitstatus_to_exitcode(status), "wall_s": wall,
            "peak_gb": usage.ru_maxrss / 2**20, "dofs": res.get("dofs"), "status": res.get("status", err[-300:]),
            "newton_iterations": res.get("newton_iterations"), "fallbacks": res.get("linear_fallbacks", 0),
            "tip": next(iter((res.get("markers") or {}).values()), {}).get("position")}


def run(design: str = "post3d", h_ref: float = 0.841, solvers=("direct", "iterative"), progress=print) -> dict:
    rows = []
    for linear in solvers:
        r = case(design, h_ref, linear)
        rows.append(r)
        progress(f"{design} h = {h_ref}: {linear}: {r['dofs']} DOFs, {r['wall_s']:.0f} s, {r['peak_gb']:.2f} GB, "
                 f"{r['status']}")
    by = {r["solver"]: r for r in rows}
    out = {"design": design, "h_ref": h_ref, "rows": rows}
    if {"direct", "iterative"} <= set(by) and by["direct"]["tip"] and by["iterative"]["tip"]:
        d, i = by["direct"], by["iterative"]
        out["speedup"] = d["wall_s"] / i["wall_s"]
        out["memory_ratio"] = d["peak_gb"] / i["peak_gb"]
        out["tip_difference_mm"] = max(abs(a - b) for a, b in zip(d["tip"], i["tip"]))
    return out


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--design", default="post3d")
    p.add_argument("--h-ref", type=float, default=0.841)
    p.add_argument("--solvers", nargs="+", default=["direct", "iterative"], choices=["direct", "iterative"])
    p.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "reference_3d")
    a = p.parse_args(argv)
    data = run(a.design, a.h_ref, a.solvers)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "reference_3d.json").write_text(json.dumps(data, indent=1))
    return data


if __name__ == "__main__":
    main()
