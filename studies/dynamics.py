"""A fast flick of finger4: the quasi-static (Soft IK) plan against a plan through the dynamics.

The target is where the fingertip rests with the flexors pulled by `pose`
(a static solve). Soft IK finds contractions u_IK that reach it statically.
The quasi-static plan ramps u_IK linearly from 0 at t = 0 to full at t = T:
slow enough, it would arrive. Run in time (BDF2, densities of the design),
it misses at t = T by the lag and swing of the body's inertia. `skelfem
optimize`'s planner (schedules on `knots` knots, adjoint gradients,
L-BFGS-B) plans the same motion through the dynamics. Writes dynamics.json
and dynamics.png (both tip paths, the target).

    python studies/dynamics.py [--T 0.03] [--dt 0.0015] [--size 3] [--knots 4] [--out DIR]
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
FINGER4 = ROOT / "geometry" / "finger4.toml"


def run(T: float = 0.03, dt: float = 0.0015, size: float = 3.0, knots: int = 4,
        pose: dict | None = None, max_evaluations: int = 60) -> dict:
    from skelfem import Session
    from skelfem.analysis.control import SoftIK, body_extent
    from skelfem.analysis.optimize import optimize_schedules, schedule_items

    t0 = time.perf_counter()
    pose = pose or {"flexor_distal": 6.0, "flexor_middle": 4.0}
    static_sets = [f"mesh.size={size}"]
    with Session(FINGER4, static_sets + [f"cables.{n}.contraction={u}" for n, u in pose.items()]) as s:
        target = np.array(s.solve().markers["tip"]["position"])
    with Session(FINGER4, static_sets) as s:                    # Soft IK from rest
        ik = SoftIK(s, "tip")
        ik.settle()
        res = ik.solve(target)
        u_ik = dict(zip(ik.names, map(float, res.contractions)))
        length = body_extent(s.model)
    names = list(u_ik)
    dyn_sets = static_sets + [f"dynamics.dt={dt}", f"dynamics.duration={T}"]
    with Session(FINGER4, dyn_sets) as s:
        knot_times = np.round(np.linspace(0.0, T, knots), 12)
        s.set(schedule_items(names, knot_times, [[u_ik[n] * t / T for t in knot_times] for n in names]))
        quasi = s.run()
        quasi_path = [[r["time"], r["tip_x"], r["tip_y"]] for r in quasi.report.trajectory]
        miss = float(np.linalg.norm(np.array(quasi.markers["tip"]["position"]) - target))
        gn = optimize_schedules(s, "tip", [(T, target)], knots=knots, max_evaluations=max_evaluations,
                                method="gauss-newton")
        gauss_newton = {"error_at_T": gn.error, "reached": gn.reached, "forward_runs": gn.forward_runs,
                        "time": gn.time}
        opt = optimize_schedules(s, "tip", [(T, target)], knots=knots, max_evaluations=max_evaluations)
        planned = s.run()
        planned_path = [[r["time"], r["tip_x"], r["tip_y"]] for r in planned.report.trajectory]
        dofs = s.dofs
    return {
        "T": T, "dt": dt, "size": size, "dofs": dofs, "knots": knots, "body_extent": length,
        "target": target.tolist(), "pose": pose,
        "soft_ik": {"contractions": u_ik, "static_error": float(res.error), "reached": bool(res.reached)},
        "quasi_static_plan": {"error_at_T": miss, "path": quasi_path},
        "dynamic_plan": {"error_at_T": opt.error, "reached": opt.reached, "status": opt.status,
                         "schedules": {n: [[float(t), float(u)] for t, u in zip(opt.knot_times, row)]
                                       for n, row in zip(opt.names, opt.schedules)},
                         "forward_runs": opt.forward_runs, "iterations": opt.iterations,
                         "time": opt.time, "path": planned_path},
        "gauss_newton_plan": gauss_newton,
        "time": time.perf_counter() - t0,
    }


def plot(res: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 5.5), dpi=120)
    q = np.array(res["quasi_static_plan"]["path"])
    d = np.array(res["dynamic_plan"]["path"])
    ax.plot(q[:, 1], q[:, 2], "o-", ms=2.5, color="#1f5fbf",
            label=f"quasi-static plan (Soft IK, ramped): misses by {res['quasi_static_plan']['error_at_T']:.2f} mm")
    ax.plot(d[:, 1], d[:, 2], "o-", ms=2.5, color="#2ca02c",
            label=f"planned through the dynamics: {res['dynamic_plan']['error_at_T']:.3f} mm")
    ax.plot(*res["target"], "x", color="#d62728", ms=12, mew=3, label=f"target at t = {res['T']:g} s")
    ax.plot(q[0, 1], q[0, 2], "s", color="k", ms=5, label="tip at rest")
    ax.margins(0.08)
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.set_title(f"finger4 tip paths, flick in {res['T']:g} s (BDF2, dt = {res['dt']:g} s)", fontsize=10)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=1, frameon=False)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--T", type=float, default=0.03)
    p.add_argument("--dt", type=float, default=0.0015)
    p.add_argument("--size", type=float, default=3.0)
    p.add_argument("--knots", type=int, default=4)
    p.add_argument("--max-evaluations", type=int, default=60)
    p.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "dynamics")
    args = p.parse_args(argv)
    res = run(args.T, args.dt, args.size, args.knots, max_evaluations=args.max_evaluations)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "dynamics.json").write_text(json.dumps(res, indent=2) + "\n")
    plot(res, args.out / "dynamics.png")
    q, d = res["quasi_static_plan"], res["dynamic_plan"]
    print(f"finger4 ({res['dofs']} DOFs), target {np.round(res['target'], 2).tolist()} at t = {res['T']} s:")
    print(f"  quasi-static plan (Soft IK {res['soft_ik']['contractions']} ramped): misses by {q['error_at_T']:.3f} mm")
    print(f"  dynamic plan: {d['error_at_T']:.4f} mm ({d['status']}), {d['forward_runs']} forward runs + adjoints, "
          f"{d['time']:.1f} s")
    g = res["gauss_newton_plan"]
    print(f"  the same by Gauss-Newton: {g['error_at_T']:.4f} mm ({'reached' if g['reached'] else 'not reached'}), "
          f"{g['forward_runs']} forward runs + tangent sweeps, {g['time']:.1f} s")
    print(f"  {res['time']:.1f} s; wrote {args.out / 'dynamics.json'} and dynamics.png")
    return res


if __name__ == "__main__":
    main()
