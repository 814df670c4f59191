"""Pull test (paper Sec. IV.A, Figs. 5/6): tip displacement under an axial tip load.

    python studies/pull_test.py [--out studies/output/pull_test] [--size 1.0] [--loads 1 2 4 6 8 10]

The finger's base is pinned (as in the design files) and a cable tied
through the tip pulls along the finger's axis (+y) with increasing force.
The cable's pull is spread over `points` material points across the tip at
y = `at_y` (a point force on a 2D continuum has a log-singular displacement,
so a single point would measure mostly the mesh). Three conditions, the
bundled designs without their flexor (its spool is free in this test; with
contraction 0 it would be a 20 N/mm tie carrying most of the pull and
bending the finger toward it):

    bones_ligaments    geometry/finger.toml
    bones              geometry/finger_bones.toml
    neither            geometry/finger_soft.toml

Each load is solved from the previous equilibrium (the design's load is the
largest one and the load factor walks through the others). The reported tip
displacement is the axial (y) displacement of the `tip` marker.

run(**params) returns the displacements; main(argv) also writes
pull_test.csv, pull_test.png (tip displacement vs load) and pull_shapes.png
(the three fingers at `snapshot` N).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from skelfem.io.files import say

ROOT = Path(__file__).resolve().parents[1]
CONDITIONS = {   # key: (design, label)
    "bones_ligaments": ("finger", "bones + ligaments"),
    "bones": ("finger_bones", "bones only"),
    "neither": ("finger_soft", "neither"),
}
DEFAULT_LOADS = (1.0, 2.0, 4.0, 6.0, 8.0, 10.0)


def build(name: str, size: float, total: float, points: int, at_y: float):
    """Session of geometry/<name>.toml with the tip cable's pull `total` N spread over `points` points."""
    from skelfem import Session
    from skelfem.design import load_design, parse_design

    path = ROOT / "geometry" / f"{name}.toml"
    raw = load_design(path, [f"mesh.size={size}"]).raw
    raw["cables"] = [c for c in raw.get("cables", []) if c["kind"] == "ligament"]   # tendon spool free
    xs = np.linspace(4.0, 16.0, points)
    raw["loads"] = [{"name": f"pull{i}", "at": [float(x), float(at_y)], "force": [0.0, total / points]}
                    for i, x in enumerate(xs)]
    return Session(parse_design(raw, str(path)))


def pull(session, loads, total: float, steps_per_load: int, snapshot: float | None) -> dict:
    """Walk the load factor through loads / total; axial tip displacement per load."""
    model, solver = session.model, session.solver
    markers = model.term("markers")
    tip_dy, tips, status, its, a, shape = [], [], "converged", 0, 0.0, None
    for F in loads:
        report = solver.solve(steps_per_load, a, F / total)
        its += report.newton_iterations
        if not report.converged:                 # a failed solve is never an equilibrium
            status = f"load {F:g} N: {report.status}"
            break
        a = F / total
        d = markers.positions(model.u.x.array)[0] - markers.X[0]
        tip_dy.append(float(d[1]))
        tips.append(d.tolist())
        if snapshot is not None and np.isclose(F, snapshot):
            shape = model.u.x.array.copy()
    return {"loads": list(loads[:len(tip_dy)]), "tip_displacement": tip_dy, "tip": tips,
            "status": status, "iterations": its, "shape": shape}


def run(size: float = 1.0, loads=DEFAULT_LOADS, snapshot: float | None = None, points: int = 5,
        at_y: float = 96.0, steps_per_load: int = 1, conditions=tuple(CONDITIONS), out: Path | None = None) -> dict:
    """Pull every condition through the loads; writes CSV/PNG into out if given."""
    loads = tuple(float(F) for F in loads)
    total = max(loads)
    snapshot = total if snapshot is None else float(snapshot)
    results, sessions = {}, {}
    for key in conditions:
        name, label = CONDITIONS[key]
        t0 = time.perf_counter()
        session = build(name, size, total, points, at_y)
        r = pull(session, loads, total, steps_per_load, snapshot)
        r.update(label=label, design=name, time=time.perf_counter() - t0)
        results[key], sessions[key] = r, session
    res = {"params": dict(size=size, loads=list(loads), snapshot=snapshot, points=points, at_y=at_y),
           "conditions": results}
    if out is not None:
        write_outputs(Path(out), res, {key: s.model for key, s in sessions.items()})
    for key, r in results.items():
        r.pop("shape")
        sessions[key].close()
    return res


# -- files ---------------------------------------------------------------------------------------
def write_csv(path: Path, res: dict) -> None:
    from skelfem.io.files import write_text

    lines = ["condition,load_N,tip_axial_displacement_mm,tip_dx_mm,tip_dy_mm,status"]
    for key, r in res["conditions"].items():
        for F, dy, tip in zip(r["loads"], r["tip_displacement"], r["tip"]):
            lines.append(f"{key},{F:.6g},{dy:.6g},{tip[0]:.6g},{tip[1]:.6g},{r['status']}")

    write_text(path, "\n".join(lines) + "\n")


def write_outputs(out: Path, res: dict, models: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from skelfem.io.files import atomic_write
    from skelfem.viz.plots import plot_deformed

    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "pull_test.csv", res)
    conds, snap = res["conditions"], res["params"]["snapshot"]
    colors = {"neither": "#c44e52", "bones": "#4c72b0", "bones_ligaments": "#55a868"}
    fig, ax = plt.subplots(figsize=(6.2, 4.2), dpi=110)
    for key, r in conds.items():
        ax.plot(r["loads"], r["tip_displacement"], "o-", ms=4, color=colors.get(key), label=r["label"])
        if snap in r["loads"]:
            ax.plot([snap], [r["tip_displacement"][r["loads"].index(snap)]], "o", ms=10, mfc="none",
                    color=colors.get(key))
    ax.set_xlabel("tip load [N]")
    ax.set_ylabel("axial tip displacement [mm]")
    ax.set_title(f"Pull test: tip displacement vs load (circles: shapes at {snap:g} N)", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    atomic_write(out / "pull_test.png", lambda tmp: fig.savefig(tmp, format="png"))
    plt.close(fig)

    fig, axes = plt.subplots(1, len(models), figsize=(3.8 * len(models), 5.4), dpi=110, sharey=True)
    for ax, (key, model) in zip(np.atleast_1d(axes), models.items()):
        r = conds[key]
        if r["shape"] is None:
            ax.set_title(f"{r['label']}\n({r['status']})", fontsize=9)
            continue
        model.u.x.array[:] = r["shape"]
        dy = r["tip_displacement"][r["loads"].index(snap)]
        plot_deformed(None, model, f"{r['label']}\n{snap:g} N: tip +{dy:.2f} mm", ax=ax)
        if ax.get_legend():
            ax.get_legend().remove()
    fig.suptitle(f"Pull test: the three fingers at {snap:g} N", fontsize=11)
    fig.tight_layout()
    atomic_write(out / "pull_shapes.png", lambda tmp: fig.savefig(tmp, format="png"))
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "pull_test")
    p.add_argument("--size", type=float, default=1.0, help="mesh size, mm")
    p.add_argument("--loads", type=float, nargs="+", default=list(DEFAULT_LOADS), help="tip loads, N")
    p.add_argument("--snapshot", type=float, default=None, help="load of the shapes panel (default: largest)")
    a = p.parse_args(argv)
    t0 = time.perf_counter()
    res = run(size=a.size, loads=a.loads, snapshot=a.snapshot, out=a.out)
    ok = True
    for key, r in res["conditions"].items():
        ok &= r["status"] == "converged"
        disp = "  ".join(f"{F:g} N: {d:.3f}" for F, d in zip(r["loads"], r["tip_displacement"]))
        say(f"{r['label']:18s} {disp} mm  ({r['status']}, {r['iterations']} Newton its, {r['time']:.1f} s)")
    say(f"wrote {a.out}/pull_test.csv, pull_test.png, pull_shapes.png in {time.perf_counter() - t0:.1f} s")
    return 0 if ok else 2


if __name__ == "__main__":
    raise SystemExit(main())
