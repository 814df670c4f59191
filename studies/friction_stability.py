"""Solver stability with Coulomb friction: every line search over friction coefficient x contact stiffness.

    python studies/friction_stability.py [--out studies/output/friction_stability] [--figures studies/figures]

Three families of frictional contact, each solved from rest in one load
step with default settings (the solver's step cutting on) by every line
search (``[solver].line_search``, see studies/stability.py):

* ``finger on a wall``: geometry/finger.toml (three bones, mesh 3 mm),
  flexor contracted by 8 mm, curling onto a ground (a wall at x = -8 mm,
  normal +x) of penalty stiffness k in {10, 1e3, 1e5} N/mm^3 and mu in
  {0, 0.25, 0.5, 1, 2}: the fingertip slides along the wall (mu < mu at which
  it would stick) while the lagged normal force is iterated;
* ``block on a slope``: a 20 x 5 mm soft block (E = 100 kPa) on a floor under
  gravity tilted by 20 deg (tan 20 deg = 0.36), held back by a soft spring
  pin, k in {100, 1e4}, mu in {0, 0.25, 0.5, 1, 2}: slides for mu < 0.36,
  sticks above;
* ``pinch``: the two-pad pinch of a rigid box (objects: IPC barrier and
  object friction, tests/test_objects.py), pads moved in by 0.45 mm with
  gravity off, mu in {0.25, 0.5, 1, 2}. A rigid object needs the energy or
  curved line search: the others are refused when the model is built
  (counted apart, as refused).

A converged state is compared with the energy line search's (marker within
``agree_mm``). Writes cases.csv, summary.json and friction_stability.png;
run(**params) returns the rows and the summary.
"""
from __future__ import annotations

import argparse
import copy
import math
import time
import tomllib
from pathlib import Path

import numpy as np
from skelfem.io.files import copy_figure, say

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "studies" / "output" / "friction_stability"
FINGER = ROOT / "geometry" / "finger.toml"
STRATEGIES = ("none", "residual", "energy", "curved", "trust_region")
MUS = (0.0, 0.25, 0.5, 1.0, 2.0)
AGREE_MM = 0.01                    # a converged marker farther than this from the energy search's: wrong
FIELDS = ["case", "mu", "stiffness", "strategy", "converged", "status", "newton_iterations", "time", "marker_x",
          "marker_y", "off_energy"]


def finger_on_wall(mu: float, k: float, size: float = 3.0) -> tuple[dict, str]:
    with open(FINGER, "rb") as f:
        d = tomllib.load(f)
    d["mesh"]["size"] = size
    next(c for c in d["cables"] if c["name"] == "flexor")["contraction"] = 8.0
    d["grounds"] = [{"name": "wall", "point": [-8.0, 0.0], "normal": [1.0, 0.0], "stiffness": k, "friction": mu}]
    return d, "tip"


def block_on_slope(mu: float, k: float, theta: float = 20.0) -> tuple[dict, str]:
    th = math.radians(theta)
    g = 9.81
    d = {"format": 1, "name": "block", "dim": 2, "thickness": 10.0, "mesh": {"size": 1.0, "degree": 1},
         "materials": {"m": {"E": 0.1, "nu": 0.3, "density": 1e4}},
         "body": {"outline": [[0, 0], [20, 0], [20, 5], [0, 5]], "material": "m"},
         "pins": [{"name": "pull", "region": [[19.9, -1], [21, 6]], "kind": "spring", "stiffness": 1e-3 / 50.0}],
         "grounds": [{"name": "floor", "point": [0, 0], "normal": [0, 1], "stiffness": k, "friction": mu}],
         "gravity": {"acceleration": [-g * math.sin(th), -g * math.cos(th)]},
         "markers": {"c": [10, 2.5]}}
    return d, "c"


def pinch(mu: float, k: float | None = None) -> tuple[dict, str]:
    box = [[7.5, 2], [32.5, 2], [32.5, 22], [7.5, 22]]
    d = {"format": 1, "name": "pinch", "dim": 2, "thickness": 10.0, "mesh": {"size": 1.5, "degree": 1},
         "materials": {"soft": {"E": 0.01, "nu": 0.3, "density": 1000.0},
                       "pla": {"E": 1000.0, "nu": 0.35, "density": 500.0}},
         "body": {"outline": [[0, 0], [6, 0], [6, 8], [7, 8], [7, 16], [6, 16], [6, 30], [34, 30], [34, 16],
                              [33, 16], [33, 8], [34, 8], [34, 0], [40, 0], [40, 36], [0, 36]], "material": "soft"},
         "pins": [{"name": "top", "region": [[-1, 35.99], [41, 37]], "kind": "fixed"},
                  {"name": "left", "region": [[-1, -1], [0.01, 30]], "kind": "fixed", "move": [0.45, 0]},
                  {"name": "right", "region": [[39.99, -1], [41, 30]], "kind": "fixed", "move": [-0.45, 0]}],
         "objects": [{"name": "box", "outline": box, "material": "pla"}],
         "contact": {"dhat": 0.2, "friction": mu}, "markers": {"box": [20.0, 12.0]},
         "solver": {"max_iterations": 300}}
    return d, "box"


CASES = {"finger on a wall": (finger_on_wall, (10.0, 1e3, 1e5), MUS),
         "block on a slope": (block_on_slope, (100.0, 1e4), MUS),
         "pinch": (pinch, (None,), MUS[1:])}


def solve(case: str, mu: float, k, strategy: str) -> dict:
    from skelfem import Session
    from skelfem.design import parse_design
    build = CASES[case][0]
    d, marker = build(mu, k)
    d = copy.deepcopy(d)
    d["solver"] = {**d.get("solver", {}), "line_search": strategy}
    t0 = time.perf_counter()
    try:
        session = Session(parse_design(d, f"{case}.toml"))
    except ValueError as exc:             # a strategy the model refuses (rigid objects need energy or curved)
        return {"case": case, "mu": mu, "stiffness": k if k is not None else float("nan"), "strategy": strategy,
                "converged": False, "status": f"refused: {exc}", "newton_iterations": 0,
                "time": time.perf_counter() - t0, "marker_x": float("nan"), "marker_y": float("nan"),
                "off_energy": float("nan")}
    try:
        with session as s:
            r = s.solve()
            converged, status, its = bool(r.converged), r.status, r.newton_iterations
            pos = r.markers[marker]["position"] if converged else [float("nan")] * 2
    except Exception as exc:              # a PETSc error inside a strategy is a failure of that strategy
        converged, status, its, pos = False, f"error: {type(exc).__name__}", 0, [float("nan")] * 2
    return {"case": case, "mu": mu, "stiffness": k if k is not None else float("nan"), "strategy": strategy,
            "converged": converged, "status": status, "newton_iterations": its, "time": time.perf_counter() - t0,
            "marker_x": float(pos[0]), "marker_y": float(pos[1]), "off_energy": float("nan")}


def summarise(rows: list[dict], agree_mm: float) -> dict:
    def key(r):
        return r["case"], r["mu"], None if r["stiffness"] != r["stiffness"] else r["stiffness"]    # NaN: none
    ref = {key(r): r for r in rows if r["strategy"] == "energy" and r["converged"]}
    for r in rows:
        e = ref.get(key(r))
        if r["converged"] and e is not None:
            r["off_energy"] = float(np.hypot(r["marker_x"] - e["marker_x"], r["marker_y"] - e["marker_y"]))
    out = {}
    for s in dict.fromkeys(r["strategy"] for r in rows):
        refused = sorted({r["status"] for r in rows if r["strategy"] == s and r["status"].startswith("refused")})
        mine = [r for r in rows if r["strategy"] == s and not r["status"].startswith("refused")]
        good = [r for r in mine if r["converged"] and not r["off_energy"] > agree_mm]
        fails = [f"{r['case']}, mu {r['mu']:g}" + (f", k {r['stiffness']:g}" if r["stiffness"] == r["stiffness"]
                                                    else "") + f": {r['status']}"
                 for r in mine if r not in good]
        its = [r["newton_iterations"] for r in good]
        out[s] = {"cases": len(mine), "successes": len(good), "failures": fails, "refused": refused,
                  "refused_cases": len([r for r in rows if r["strategy"] == s]) - len(mine),
                  "iterations_median": float(np.median(its)) if its else None,
                  "iterations_max": int(max(its)) if its else None,
                  "time": float(sum(r["time"] for r in mine))}
    return out


def plot(path: Path, rows: list[dict]) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    rows = [r for r in rows if not str(r["status"]).startswith("refused")]      # refused: not drawn
    cases = list(dict.fromkeys(r["case"] for r in rows))
    strategies = list(dict.fromkeys(r["strategy"] for r in rows))
    fig, axes = plt.subplots(1, len(cases), figsize=(4.2 * len(cases), 3.6), squeeze=False)
    colours = dict(zip(STRATEGIES, ["#7f7f7f", "#d62728", "#1f77b4", "#2ca02c", "#9467bd"]))
    top = max([r["newton_iterations"] for r in rows if r["converged"]] + [10])
    for ax, case in zip(axes[0], cases):
        ks = list(dict.fromkeys(r["stiffness"] for r in rows if r["case"] == case))
        for s in strategies:
            for j, k in enumerate(ks):
                mine = [r for r in rows if r["case"] == case and r["strategy"] == s and
                        (r["stiffness"] == k or (k != k and r["stiffness"] != r["stiffness"]))]
                x = np.array([r["mu"] for r in mine]) * (1 + 0.03 * (strategies.index(s) - 2))
                y = [r["newton_iterations"] if r["converged"] else np.nan for r in mine]
                style = ["-", "--", ":"][j % 3]
                label = s if j == 0 else None
                ax.plot(x + 0.02, y, style, marker="o", ms=3, color=colours.get(s, "k"), label=label)
                bad = [xx + 0.02 for xx, r in zip(x, mine) if not r["converged"]]
                ax.plot(bad, [1.6 * top] * len(bad), "x", color=colours.get(s, "k"), ms=6)
        ks_text = ", ".join(f"{k:g}" for k in ks if k == k)
        ax.set_title(f"{case}" + (f"\nk = {ks_text} N/mm³ (—, --, :)" if ks_text else ""), fontsize=9)
        ax.set_xscale("symlog", linthresh=0.25)
        ax.set_yscale("log")
        ax.set_xlabel("mu")
        ax.axhline(1.25 * top, color="0.8", lw=0.8)
        ax.text(0.02, 0.97, "failed (x)", fontsize=7, color="0.4", transform=ax.transAxes, va="top")
    axes[0][0].set_ylabel("Newton iterations")
    axes[0][0].legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run(cases=tuple(CASES), strategies=STRATEGIES, mus=None, stiffnesses=None, agree_mm: float = AGREE_MM,
        out: Path | None = None, figures: Path | None = None, progress=print) -> dict:
    """Every (case, mu, stiffness, strategy); mus/stiffnesses: subsets (default: each case's own)."""
    rows = []
    for case in cases:
        _, ks, case_mus = CASES[case]
        for k in (ks if stiffnesses is None else [k for k in ks if k in stiffnesses or k is None]):
            for mu in (case_mus if mus is None else [m for m in case_mus if m in mus]):
                for s in strategies:
                    r = solve(case, mu, k, s)
                    rows.append(r)
                    if progress:
                        progress(f"{case:17s} mu={mu:<5g} k={'' if k is None else f'{k:g}':6s} {s:12s} "
                                 f"{'ok  ' if r['converged'] else 'FAIL'} {r['status']:36s} "
                                 f"{r['newton_iterations']:5d} its {r['time']:6.2f} s")
    return write(rows, agree_mm, out, figures)


def write(rows: list[dict], agree_mm: float, out: Path | None, figures: Path | None) -> dict:
    """The summary of the rows; with out, cases.csv, summary.json and the figure (copied to figures)."""
    result = {"rows": rows, "summary": summarise(rows, agree_mm), "agree_mm": agree_mm}
    if out is not None:
        from skelfem.io.files import write_csv, write_json
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        write_csv(out / "cases.csv", FIELDS, rows)
        write_json(out / "summary.json", {"agree_mm": agree_mm, "strategies": result["summary"]})
        plot(out / "friction_stability.png", rows)
        copy_figure(out / "friction_stability.png", figures)
    return result


def read_rows(path: Path) -> list[dict]:
    """cases.csv back as rows (to redraw the figure without solving again)."""
    import csv
    out = []
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            row = dict(r)
            for k in ("mu", "stiffness", "time", "marker_x", "marker_y", "off_energy"):
                row[k] = float(r[k]) if r[k] not in ("", None) else float("nan")
            row["newton_iterations"] = int(float(r["newton_iterations"]))
            row["converged"] = r["converged"] in ("True", "true", "1")
            out.append(row)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=OUT)
    p.add_argument("--figures", type=Path, default=ROOT / "studies" / "figures")
    p.add_argument("--from-csv", action="store_true",
                   help="no solves: summarise and draw the last cases.csv again")
    a = p.parse_args(argv)
    if a.from_csv:
        res = write(read_rows(a.out / "cases.csv"), AGREE_MM, a.out, a.figures)
    else:
        res = run(out=a.out, figures=a.figures)
    for s, v in res["summary"].items():
        say(f"{s:12s} {v['successes']}/{v['cases']} converged, median {v['iterations_median']} its, "
            f"{v['time']:.1f} s; failed: {'; '.join(v['failures']) or 'none'}"
            + (f"; refused {v['refused_cases']}" if v["refused_cases"] else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
