"""What does ``--estimate`` cost next to the solve it checks? CPU seconds of both, 2D and 3D, up to 100k DOFs.

    python studies/estimate_cost.py [--cases strip:1 block3d:1.5 block3d:0.65 ...] [--out studies/output/estimate_cost]

A case is DESIGN:SIZE, DESIGN one of estimate_effectivity's builders (``strip``:
the 2D strip with bones, P1; ``block3d``: the 3D block with a bone and a tendon,
P1; ``block3d_in_bone``: the same with the tendon ending in the bone; ``pinch``:
the gripper closed on its box with contact friction, 2D P1; ``beam3d``, ``finger3d``:
the slender beam and the finger-like cylinder, nearly incompressible). Each is
solved once from rest (Session.solve) and then estimated (Session.estimate) in
the same process; both are timed in CPU seconds of this process
(time.process_time: on a shared machine the wall time counts the other
processes too) and in wall seconds. The estimate's forms are compiled before
the clock starts (FFCx's cache: once per machine). Also reported: the
richer solve's DOFs, Newton iterations, its assemblies and Krylov iterations
(iterative solves) and the algebraic part's time.

run(cases) returns the rows; main(argv) prints them and writes estimate_cost.json.
"""
from __future__ import annotations

import argparse
import copy
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import estimate_effectivity as effectivity  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
BUILDERS = {"strip": lambda h: effectivity.strip(size=h), "block3d": lambda h: effectivity.block3d(size=h),
            "block3d_in_bone": lambda h: effectivity.block3d(size=h, in_bone=True),
            "pinch": lambda h: effectivity._gripper(h, 1), "beam3d": lambda h: effectivity.beam3d(size=h),
            "finger3d": lambda h: effectivity.finger3d(size=h)}
DEFAULT = ("strip:1", "strip:0.5", "strip:0.25", "pinch:2", "block3d:3", "beam3d:2", "finger3d:2.5", "block3d:1.5",
           "block3d:0.65")


def run_case(case: str) -> dict:
    from skelfem.design.parse import parse_design
    from skelfem.session import Session
    name, size = case.split(":")
    d = BUILDERS[name](float(size))
    warm = BUILDERS[name](float(size) * 4)
    with Session(parse_design(copy.deepcopy(warm), "warm")) as s:
        s.solve(estimate=True)                  # the richer degree's forms compiled (FFCx's cache)
    with Session(parse_design(copy.deepcopy(d), d["name"])) as s:
        t0, c0 = time.perf_counter(), time.process_time()
        r = s.solve()
        solve = (time.perf_counter() - t0, time.process_time() - c0)
        if not r.converged:
            raise RuntimeError(f"{case}: {r.status}")
        t0, c0 = time.perf_counter(), time.process_time()
        est = s.estimate()["estimate"]
        estimate = (time.perf_counter() - t0, time.process_time() - c0)
    return {"case": case, "dim": d["dim"], "dofs": r.dofs, "newton_iterations": r.newton_iterations,
            "solve_cpu_s": round(solve[1], 3), "estimate_cpu_s": round(estimate[1], 3),
            "ratio_cpu": round(estimate[1] / solve[1], 2),
            "solve_wall_s": round(solve[0], 3), "estimate_wall_s": round(estimate[0], 3),
            "ratio_wall": round(estimate[0] / solve[0], 2),
            "richer_dofs": est["dofs"], "richer_newton_iterations": est.get("newton_iterations"),
            "assemblies": est.get("assemblies"), "krylov_iterations": est.get("krylov_iterations"),
            "algebraic_s": est["seconds"]["algebraic"], "status": est["status"]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=list(DEFAULT))
    ap.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "estimate_cost")
    args = ap.parse_args(argv)
    rows = []
    for case in args.cases:
        rows.append(run_case(case))
        r = rows[-1]
        print(f"{case:18s} {r['dofs']:7d} DOFs  solve {r['solve_cpu_s']:8.2f} s CPU  "
              f"estimate {r['estimate_cpu_s']:8.2f} s CPU  ratio {r['ratio_cpu']:5.2f} (wall {r['ratio_wall']:5.2f})  "
              f"richer: {r['richer_dofs']} DOFs, "
              f"{r['richer_newton_iterations']} Newton, {r['krylov_iterations']} Krylov", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "estimate_cost.json").write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
