"""Soft IK along horizontal and vertical target lines on the four-tendon finger (paper, Fig. 11).

    python studies/ik_trajectories.py [--out studies/output/ik_trajectories] [--size 2.0]
                                      [--targets 13] [--random 20]

The tip of geometry/finger4.toml reaches a curved band: bending with one
flexor or extensor sweeps it along an arc through the rest position (10, 99),
co-contraction shortens the finger and moves it down, until near y ~ 82
(mesh size 2) the co-contracted finger is about to buckle. The horizontal line
(y = 88, x from -25 to 35) lies inside the band but its left end needs the
distal flexor slack, where Soft IK (a local method) can stop a little short;
the vertical line (x = 10, y from 97 to 82) ends at the buckling limit. The
study reports the reachable part of each line. Each line starts from
the unactuated finger and warm-starts every target from the previous pose.

A third part draws `random` targets by forward-simulating contractions
u_c ~ U(0, u_max) from rest and solves Soft IK for each from rest, to measure
forward solves, errors and time per target.

run(**params) returns the numbers; main(argv) also writes paths.png,
contractions.png, horizontal.csv, vertical.csv, random.csv and summary.json.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from skelfem.analysis.control import line_targets, pose_indices
from skelfem.viz.plots import draw_track
from skelfem.io.files import say

ROOT = Path(__file__).resolve().parents[1]
DESIGN = ROOT / "geometry" / "finger4.toml"
LINES = {"horizontal": ((-25.0, 88.0), (35.0, 88.0)),
         "vertical": ((10.0, 97.0), (10.0, 82.0))}


def build(size: float):
    """Session and Soft IK for the finger's tip at mesh size `size`."""
    from skelfem import Session
    from skelfem.analysis.control import SoftIK

    session = Session(DESIGN, [f"mesh.size={size}"])
    return session, SoftIK(session, "tip")


def rest(ik) -> None:
    """Back to the unactuated finger (x = 0 is its equilibrium)."""
    ik.model.u.x.array[:] = 0.0
    ik.u = np.zeros_like(ik.u)
    ik.settle(1)


def track_line(ik, ends, targets: int):
    """Soft IK along one line from rest; returns (results, poses shown in the picture)."""
    from skelfem.analysis.control import track

    rest(ik)
    points = line_targets(np.asarray(ends, dtype=float), targets)
    show, poses = pose_indices(len(points)), []

    def keep(i, res):
        if i in show:
            poses.append(ik.model.u.x.array.copy())
    return track(ik, points, keep), poses


def random_targets(ik, count: int, u_max: float, seed: int):
    """Targets of random contractions, then Soft IK for each from rest."""
    from skelfem.analysis.sensitivity import set_contractions
    rng = np.random.default_rng(seed)
    rows = []
    for _ in range(count):
        u_true = rng.uniform(0.0, u_max, len(ik.u))
        ik.model.u.x.array[:] = 0.0
        set_contractions(ik.model, u_true)
        report = ik.solver.solve(ik.session.design.solver.steps)
        if not report.converged:
            continue                                   # not an admissible pose: draw again next time
        target = ik.position()
        rest(ik)
        rows.append((u_true, ik.solve(target)))
    return rows


def _line_numbers(ik, results) -> dict:
    reached = [r for r in results if r.reached]
    err = np.array([r.error for r in results])
    solves = np.array([r.forward_solves for r in results])
    return {
        "targets": len(results), "reached": len(reached),
        "reachable_from": [float(v) for v in reached[0].target] if reached else None,
        "reachable_to": [float(v) for v in reached[-1].target] if reached else None,
        "max_error_reached": float(max((r.error for r in reached), default=np.nan)),
        "max_error": float(err.max()), "max_error_relative": float(err.max() / ik.length),
        "forward_solves": {"total": int(solves.sum()), "median": float(np.median(solves)),
                           "max": int(solves.max())},
        "seconds_per_target": float(np.median([r.time for r in results])),
    }


def _random_numbers(ik, rows) -> dict:
    if not rows:
        return {"targets": 0}
    res = [r for _, r in rows]
    solves = np.array([r.forward_solves for r in res])
    err = np.array([r.error for r in res])
    secs = np.array([r.time for r in res])
    return {"targets": len(res), "reached": int(sum(r.reached for r in res)),
            "forward_solves": {"min": int(solves.min()), "median": float(np.median(solves)),
                               "max": int(solves.max())},
            "error": {"median": float(np.median(err)), "max": float(err.max())},
            "seconds_per_target": {"median": float(np.median(secs)), "max": float(secs.max())}}


def run(size: float = 2.0, targets: int = 13, random: int = 20, u_max: float = 12.0, seed: int = 0,
        out: Path | None = None) -> dict:
    """Track both lines and solve the random targets; write the files into out if given."""
    t0 = time.perf_counter()
    session, ik = build(size)
    lines = {name: track_line(ik, ends, targets) for name, ends in LINES.items()}
    rows = random_targets(ik, random, u_max, seed) if random else []
    numbers = {"size": size, "dofs": session.dofs, "body_extent": ik.length, "tol": ik.tol,
               **{name: _line_numbers(ik, res) for name, (res, _) in lines.items()},
               "random": _random_numbers(ik, rows)}
    if out is not None:
        _write(Path(out), ik, lines, rows, numbers)
    session.close()
    numbers["seconds"] = time.perf_counter() - t0
    return numbers


# -- files ------------------------------------------------------------------------------------------
def _result_row(r, names, prefix: str = "") -> dict:
    """One IK result as CSV fields: target, achieved position, error, contractions, solves, time."""
    axes = "xyz"[:len(r.target)]
    return {**{f"target_{a}": float(v) for a, v in zip(axes, r.target)},
            **{a: float(v) for a, v in zip(axes, r.position)},
            "error": float(r.error), "reached": int(r.reached),
            **{f"{prefix}{n}": float(u) for n, u in zip(names, r.contractions)},
            "forward_solves": int(r.forward_solves), "seconds": round(float(r.time), 4)}


def _write(out: Path, ik, lines: dict, rows, numbers: dict) -> None:
    from skelfem.io.files import write_csv, write_json

    out.mkdir(parents=True, exist_ok=True)
    axes = "xyz"[:ik.model.dim]
    position = [f"target_{a}" for a in axes] + list(axes) + ["error", "reached"]
    tail = ["forward_solves", "seconds"]
    for name, (results, _) in lines.items():
        table = [{"step": i, **_result_row(r, ik.names)} for i, r in enumerate(results)]
        write_csv(out / f"{name}.csv", ["step"] + position + ik.names + tail, table)
    table = [{"target": i, **{f"u_true_{n}": float(v) for n, v in zip(ik.names, u)},
              **_result_row(r, ik.names, "u_")} for i, (u, r) in enumerate(rows)]
    write_csv(out / "random.csv", ["target"] + [f"u_true_{n}" for n in ik.names] + position
              + [f"u_{n}" for n in ik.names] + tail, table)
    write_json(out / "summary.json", numbers)
    _plot_paths(out / "paths.png", ik, lines, numbers)
    _plot_contractions(out / "contractions.png", ik, lines)


# -- pictures ---------------------------------------------------------------------------------------
def _plot_paths(path: Path, ik, lines: dict, numbers: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from skelfem.io.files import atomic_write

    fig, axes = plt.subplots(1, len(lines), figsize=(6 * len(lines), 7.5), dpi=110)
    for ax, (name, (results, poses)) in zip(np.atleast_1d(axes), lines.items()):
        n = numbers[name]
        draw_track(ax, ik.model, results, poses,
                    f"{name} line: {n['reached']}/{n['targets']} targets within {ik.tol:.2g} mm\n"
                    f"max error of reached {n['max_error_reached']:.2g} mm")
    fig.suptitle("finger4: Soft IK along target lines (after the paper's Fig. 11)", fontsize=11)
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))
    plt.close(fig)


def _plot_contractions(path: Path, ik, lines: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from skelfem.io.files import atomic_write

    fig, axes = plt.subplots(1, len(lines), figsize=(6 * len(lines), 3.8), dpi=110, sharey=True)
    for ax, (name, (results, _)) in zip(np.atleast_1d(axes), lines.items()):
        u = np.array([r.contractions for r in results])
        steps = np.arange(len(results))
        for j, tendon in enumerate(ik.names):
            ax.plot(steps, u[:, j], "o-", ms=3, label=tendon)
        for i, r in enumerate(results):
            if not r.reached:
                ax.axvspan(i - 0.5, i + 0.5, color="0.85", zorder=0)
        ax.set_xlabel("target (step)")
        ax.set_title(f"{name} line (grey: not reached)", fontsize=10)
        ax.grid(alpha=0.3)
    np.atleast_1d(axes)[0].set_ylabel("contraction u [mm]")
    np.atleast_1d(axes)[0].legend(fontsize=8)
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "ik_trajectories")
    p.add_argument("--size", type=float, default=2.0, help="mesh size, mm")
    p.add_argument("--targets", type=int, default=13, help="targets per line")
    p.add_argument("--random", type=int, default=20, help="random reachable targets (0: skip)")
    p.add_argument("--u-max", type=float, default=12.0, help="random contractions are drawn from [0, u_max] mm")
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args(argv)
    res = run(a.size, a.targets, a.random, a.u_max, a.seed, a.out)
    say(f"finger4 at mesh size {a.size} mm ({res['dofs']} DOFs), tol {res['tol']:.3g} mm")
    for name in LINES:
        n = res[name]
        say(f"  {name:10s}: {n['reached']}/{n['targets']} reached, from {n['reachable_from']} to "
              f"{n['reachable_to']}; max error of reached {n['max_error_reached']:.3g} mm; forward solves "
              f"median {n['forward_solves']['median']:g}, max {n['forward_solves']['max']}; "
              f"{n['seconds_per_target']:.2f} s per target (median)")
    r = res["random"]
    if r["targets"]:
        say(f"  random    : {r['reached']}/{r['targets']} reached; forward solves min/median/max "
              f"{r['forward_solves']['min']}/{r['forward_solves']['median']:g}/{r['forward_solves']['max']}; "
              f"error median {r['error']['median']:.3g}, max {r['error']['max']:.3g} mm; "
              f"{r['seconds_per_target']['median']:.2f} s per target (median), max "
              f"{r['seconds_per_target']['max']:.2f} s")
    say(f"files in {a.out} ({res['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
