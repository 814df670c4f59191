"""Solver stability: success, iterations and time over bone/silicone stiffness ratio x contraction x strategy.

    python studies/stability.py [--out studies/output/stability] [--figures studies/figures] [--quick]

The design is geometry/finger.toml (silicone E = 0.1 MPa, three bones, five
cables) at mesh size ``size``; the bones' Young's modulus is set to
ratio x E_silicone, the flexor's contraction to u. Strategies
(``[solver].line_search``):

* ``none``: Newton with full steps,
* ``residual``: PETSc's backtracking on |grad Pi|,
* ``energy``: Armijo backtracking on Pi with the det F > 0 guard (what the
  default ``auto`` picks for designs with bones, such as this one),
* ``curved``: the energy line search along the geodesic-acceleration curve,
  with a watchdog and steps limited to 1 rad (what ``auto`` picks without bones),
* ``trust_region``: PETSc's newtontr.

Each runs in two load-stepping modes:

* ``steps = 1``: one Newton solve at the full load, no step cutting
  (``max_cuts = 0``): the strategy alone;
* ``steps = 4``: four load steps with the solver's adaptive cutting (a failed
  step is retried with half the increment, up to 8 times): what users get.

A case succeeds when the solver reports convergence; a converged state is
also checked to be the same equilibrium as the energy strategy's (tip within
``agree_mm``) and to have det F > 0 (the solver guarantees the latter).
The study picks the strategy with the most successes, ties broken by total
time. run(**params) returns the numbers; main(argv) writes cases.csv,
summary.json and stability.png.

Slender bodies that rotate a lot (``run_slender``, every strategy, default
settings: one load step with the solver's cutting): a cantilever strip
3 x 120 mm under a dead tip load with P L^2 / (E'I) = 1, 3, 10 (P2, h =
0.75), a strip 4 x 100 mm curled by a tendon at 1.2 mm from its axis to half
a circle and to a full one (P2, h = 0.5), and finger_soft.toml (no bones)
at flexor contractions 16 and 24 mm. Written to slender.csv and the
summary's "slender" entry.
"""
from __future__ import annotations

import argparse
import copy
import time
import tomllib
from pathlib import Path

import numpy as np
from skelfem.io.files import copy_figure, say

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "studies" / "output" / "stability"
FINGER = ROOT / "geometry" / "finger.toml"

STRATEGIES = ("none", "residual", "energy", "curved", "trust_region")
RATIOS = (1.0, 10.0, 1e2, 1e3, 1e4, 1e5, 1e6)
CONTRACTIONS = (4.0, 8.0, 16.0)
STEPPING = (1, 4)
DEMO_CONTRACTION = 8.0


def finger_dict(ratio: float, contraction: float, strategy: str, steps: int, size: float) -> dict:
    """finger.toml with E_bone = ratio * E_silicone, the flexor at `contraction`, the given solver."""
    with open(FINGER, "rb") as f:
        d = copy.deepcopy(tomllib.load(f))
    d.setdefault("name", "finger")
    silicone = d["body"]["material"]
    for bone in d.get("bones", []):
        d["materials"][bone["material"]]["E"] = ratio * d["materials"][silicone]["E"]
    next(c for c in d["cables"] if c["name"] == "flexor")["contraction"] = contraction
    d["mesh"]["size"] = size
    d["solver"] = {**d.get("solver", {}), "line_search": strategy, "steps": steps}
    return d


def solve_case(ratio: float, contraction: float, strategy: str, steps: int, size: float) -> dict:
    """One solve; steps = 1 means no load stepping and no step cutting."""
    from skelfem import Session
    from skelfem.design import parse_design

    session = Session(parse_design(finger_dict(ratio, contraction, strategy, steps, size), "finger.toml"))
    if steps == 1:
        session.solver.stepper.max_cuts = 0
    t0 = time.perf_counter()
    try:
        result = session.solve(steps)
        converged, status = bool(result.converged), result.status
        its, load_steps, min_j = result.newton_iterations, result.load_steps, result.min_jacobian
    except Exception as exc:          # a PETSc error inside a strategy is a failure of that strategy
        converged, status, its, load_steps, min_j = False, f"error: {type(exc).__name__}", 0, 0, float("nan")
    row = {"ratio": ratio, "contraction": contraction, "strategy": strategy, "steps": steps,
           "converged": converged, "status": status, "newton_iterations": its, "load_steps": load_steps,
           "time": time.perf_counter() - t0, "min_jacobian": min_j, "dofs": session.dofs}
    if converged:                     # a failed solve is never reported as an equilibrium
        tip = result.markers["tip"]["position"]
        row.update(tip_x=float(tip[0]), tip_y=float(tip[1]))
    session.close()
    return row


def check_agreement(rows: list[dict], agree_mm: float) -> None:
    """Mark converged cases whose tip differs from the energy strategy's (same ratio, contraction)."""
    ref = {(r["ratio"], r["contraction"]): (r["tip_x"], r["tip_y"]) for r in rows
           if r["strategy"] == "energy" and r["converged"]}
    for r in rows:
        key = (r["ratio"], r["contraction"])
        if r["converged"] and key in ref:
            r["tip_deviation"] = float(np.hypot(r["tip_x"] - ref[key][0], r["tip_y"] - ref[key][1]))
            r["same_equilibrium"] = bool(r["tip_deviation"] <= agree_mm)
        else:
            r["tip_deviation"], r["same_equilibrium"] = float("nan"), None


def summarise(rows: list[dict], ratios, contractions) -> dict:
    """Successes per strategy and stepping, the picked strategy, and the default's coverage."""
    per = {}
    for s in STRATEGIES:
        mine = [r for r in rows if r["strategy"] == s]
        if not mine:
            continue
        ok = [r for r in mine if r["converged"]]
        per[s] = {"successes": len(ok), "cases": len(mine),
                  "by_steps": {str(n): sum(r["converged"] for r in mine if r["steps"] == n)
                               for n in sorted({r["steps"] for r in mine})},
                  "total_time": float(sum(r["time"] for r in mine)),
                  "median_iterations": float(np.median([r["newton_iterations"] for r in ok])) if ok else None,
                  "other_equilibrium": sum(1 for r in ok if r.get("same_equilibrium") is False),
                  "failures": sorted({r["status"] for r in mine if not r["converged"]})}
    picked = min(per, key=lambda s: (-per[s]["successes"], per[s]["total_time"])) if per else None
    demo = [r for r in rows if r["strategy"] == "energy" and r["contraction"] == DEMO_CONTRACTION]
    coverage = {str(n): bool(all(r["converged"] for r in demo if r["steps"] == n)
                             and {r["ratio"] for r in demo if r["steps"] == n} == set(ratios))
                for n in sorted({r["steps"] for r in demo})}
    return {"strategies": per, "picked": picked, "default": "energy", "picked_is_default": picked == "energy",
            "energy_converges_over_all_ratios_at_demo_contraction": coverage,
            "ratios": list(ratios), "contractions": list(contractions)}


def run(ratios=RATIOS, contractions=CONTRACTIONS, strategies=STRATEGIES, stepping=STEPPING, size: float = 3.0,
        agree_mm: float = 0.05, out: Path | None = None, progress=print, slender=()) -> dict:
    """Solve the whole grid (and the slender cases named in `slender`); returns {"cases": [...], "summary": {...}}."""
    solve_case(1e3, 1.0, "energy", 1, size)     # warm-up: FFCx cache, imports
    rows = []
    for strategy in strategies:
        for steps in stepping:
            for ratio in ratios:
                for u in contractions:
                    r = solve_case(ratio, u, strategy, steps, size)
                    rows.append(r)
                    if progress:
                        progress(f"{strategy:12s} steps={steps} ratio={ratio:<7.0e} u={u:<4g} "
                                 f"{'ok  ' if r['converged'] else 'FAIL'} {r['status']:20s} "
                                 f"{r['newton_iterations']:4d} its {r['load_steps']:3d} steps {r['time']:6.2f} s")
    check_agreement(rows, agree_mm)
    result = {"cases": rows, "summary": summarise(rows, ratios, contractions), "size": size}
    if slender:
        result["slender"] = run_slender(slender, strategies, progress)
        result["summary"]["slender"] = summarise_slender(result["slender"])
    if out is not None:
        write_outputs(Path(out), result)
    return result


E_SOFT, NU_SOFT, THICK = 1.0, 0.3, 10.0


def elastica_dict(alpha: float, L=120.0, h=3.0, size=0.75) -> dict:
    """A cantilever strip under a dead transverse tip load P L^2 / (E'I) = alpha (plane strain E')."""
    P = alpha * E_SOFT / (1 - NU_SOFT ** 2) * THICK * h ** 3 / 12 / L ** 2
    return {"format": 1, "name": "elastica", "dim": 2, "thickness": THICK, "mesh": {"size": size, "degree": 2},
            "materials": {"soft": {"E": E_SOFT, "nu": NU_SOFT}},
            "body": {"outline": [[0, 0], [L, 0], [L, h], [0, h]], "material": "soft"},
            "pins": [{"name": "base", "region": [[-1, -1], [1e-6, h + 1]], "kind": "fixed"}],
            "loads": [{"name": "tip", "at": [L, h / 2], "force": [0.0, -P]}],
            "markers": {"tip": [L, h / 2]}}


def curl_dict(contraction: float, L=100.0, h=4.0, d=1.2, size=0.5) -> dict:
    """A strip clamped at one end, curled by a tendon at d from its axis (7.3 mm: half a circle)."""
    return {"format": 1, "name": "curl", "dim": 2, "thickness": THICK, "mesh": {"size": size, "degree": 2},
            "materials": {"soft": {"E": E_SOFT, "nu": NU_SOFT}},
            "body": {"outline": [[0, 0], [h, 0], [h, L], [0, L]], "material": "soft"},
            "cables": [{"name": "flexor", "kind": "tendon", "path": [[h / 2 + d, 0], [h / 2 + d, L]],
                        "stiffness": 100.0, "contraction": contraction}],
            "pins": [{"name": "base", "region": [[-1, -1], [h + 1, 1e-6]], "kind": "fixed"}],
            "markers": {"tip": [h / 2, L]}}


def soft_finger_dict(contraction: float) -> dict:
    with open(ROOT / "geometry" / "finger_soft.toml", "rb") as f:
        d = copy.deepcopy(tomllib.load(f))
    next(c for c in d["cables"] if c["name"] == "flexor")["contraction"] = contraction
    return d


SLENDER = {"elastica PL²/EI=1": lambda: elastica_dict(1.0), "elastica PL²/EI=3": lambda: elastica_dict(3.0),
           "elastica PL²/EI=10": lambda: elastica_dict(10.0), "curl ½ circle": lambda: curl_dict(7.3),
           "curl full circle": lambda: curl_dict(14.6), "finger_soft u=16": lambda: soft_finger_dict(16.0),
           "finger_soft u=24": lambda: soft_finger_dict(24.0)}


def solve_slender(case: str, strategy: str) -> dict:
    """One slender case at default settings with the given line search."""
    from skelfem import Session
    from skelfem.design import parse_design

    d = SLENDER[case]()
    d["solver"] = {**d.get("solver", {}), "line_search": strategy}
    t0 = time.perf_counter()
    try:
        with Session(parse_design(d, f"{case}.toml")) as session:
            result = session.solve()
            converged, status, its = bool(result.converged), result.status, result.newton_iterations
            attempts = len(result.attempts)
            tip = result.markers["tip"]["position"] if converged else [float("nan")] * 2
    except Exception as exc:          # a PETSc error inside a strategy is a failure of that strategy
        converged, status, its, attempts, tip = False, f"error: {type(exc).__name__}", 0, 0, [float("nan")] * 2
    return {"case": case, "strategy": strategy, "converged": converged, "status": status,
            "newton_iterations": its, "attempts": attempts, "time": time.perf_counter() - t0,
            "tip_x": float(tip[0]), "tip_y": float(tip[1])}


def run_slender(cases=tuple(SLENDER), strategies=STRATEGIES, progress=print) -> list[dict]:
    rows = []
    for case in cases:
        for strategy in strategies:
            r = solve_slender(case, strategy)
            rows.append(r)
            if progress:
                progress(f"{case:20s} {strategy:12s} {'ok  ' if r['converged'] else 'FAIL'} {r['status']:20s} "
                         f"{r['newton_iterations']:5d} its {r['attempts']:3d} attempts {r['time']:7.2f} s")
    return rows


def summarise_slender(rows: list[dict]) -> dict:
    per = {}
    for s in STRATEGIES:
        mine = [r for r in rows if r["strategy"] == s]
        if mine:
            per[s] = {"successes": sum(r["converged"] for r in mine), "cases": len(mine),
                      "iterations": {r["case"]: (r["newton_iterations"] if r["converged"] else None) for r in mine},
                      "total_time": float(sum(r["time"] for r in mine))}
    return per


SLENDER_FIELDS = ("case", "strategy", "converged", "status", "newton_iterations", "attempts", "time", "tip_x", "tip_y")


CSV_FIELDS = ("strategy", "steps", "ratio", "contraction", "converged", "status", "newton_iterations",
              "load_steps", "time", "min_jacobian", "tip_x", "tip_y", "tip_deviation", "same_equilibrium", "dofs")


def write_outputs(out: Path, result: dict) -> None:
    from skelfem.io.files import write_csv, write_json

    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "cases.csv", CSV_FIELDS, result["cases"])
    if result.get("slender"):
        write_csv(out / "slender.csv", SLENDER_FIELDS, result["slender"])
    write_json(out / "summary.json", {"size": result["size"], **result["summary"]})
    plot(out / "stability.png", result)


SHORT = {"line_search_failed": "LS", "max_iterations": "MAX", "diverged": "DIV", "inverted_elements": "INV",
         "trust_region_collapsed": "TR", "linear_solve_failed": "LIN"}


def plot(path: Path, result: dict) -> None:
    """A heatmap per strategy (columns) and stepping mode (rows): Newton iterations, failures marked."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    from skelfem.io.files import atomic_write

    rows = result["cases"]
    strategies = [s for s in STRATEGIES if any(r["strategy"] == s for r in rows)]
    stepping = sorted({r["steps"] for r in rows})
    ratios = sorted({r["ratio"] for r in rows})
    us = sorted({r["contraction"] for r in rows})
    slender = result.get("slender") or []
    cases = list(dict.fromkeys(r["case"] for r in slender))
    its_max = max([r["newton_iterations"] for r in rows + slender if r["converged"]] + [2])
    heights = [len(ratios)] * len(stepping) + ([len(cases)] if cases else [])
    fig, axes = plt.subplots(len(heights), len(strategies), squeeze=False, dpi=110,
                             gridspec_kw={"height_ratios": heights},
                             figsize=(2.7 * len(strategies) + 2.2, 0.42 * sum(heights) + 1.6))
    im = None
    for i, n in enumerate(stepping):
        for j, s in enumerate(strategies):
            ax = axes[i][j]
            grid = np.full((len(ratios), len(us)), np.nan)
            for r in rows:
                if r["strategy"] == s and r["steps"] == n and r["converged"]:
                    grid[ratios.index(r["ratio"]), us.index(r["contraction"])] = max(r["newton_iterations"], 1)
            im = ax.imshow(grid, origin="lower", aspect="auto", cmap="viridis_r",
                           norm=LogNorm(vmin=1, vmax=its_max))
            for r in rows:
                if r["strategy"] == s and r["steps"] == n:
                    y, x = ratios.index(r["ratio"]), us.index(r["contraction"])
                    if r["converged"]:
                        ax.text(x, y, str(r["newton_iterations"]), ha="center", va="center", fontsize=7,
                                color="w" if r["newton_iterations"] > its_max ** 0.5 else "k")
                    else:
                        ax.add_patch(plt.Rectangle((x - 0.5, y - 0.5), 1, 1, color="#c0392b"))
                        ax.text(x, y, SHORT.get(r["status"].split(" ")[0], r["status"][:4]), ha="center", va="center",
                                fontsize=7, color="w", fontweight="bold")
            ax.set_xticks(range(len(us)), [f"{u:g}" for u in us])
            ax.set_yticks(range(len(ratios)), [f"1e{int(round(np.log10(q)))}" for q in ratios])
            ok = sum(1 for r in rows if r["strategy"] == s and r["steps"] == n and r["converged"])
            total = sum(1 for r in rows if r["strategy"] == s and r["steps"] == n)
            ax.set_title(f"{s}, steps={n}: {ok}/{total}", fontsize=9)
            if i == len(stepping) - 1:
                ax.set_xlabel("contraction u [mm]")
            if j == 0:
                ax.set_ylabel("E_bone / E_silicone")
    if cases:
        for j, s in enumerate(strategies):
            ax = axes[len(stepping)][j]
            grid = np.full((len(cases), 1), np.nan)
            for r in slender:
                if r["strategy"] == s and r["converged"]:
                    grid[cases.index(r["case"]), 0] = max(r["newton_iterations"], 1)
            im = ax.imshow(grid, origin="upper", aspect="auto", cmap="viridis_r", norm=LogNorm(vmin=1, vmax=its_max))
            for r in slender:
                if r["strategy"] != s:
                    continue
                y = cases.index(r["case"])
                if r["converged"]:
                    ax.text(0, y, str(r["newton_iterations"]), ha="center", va="center", fontsize=7,
                            color="w" if r["newton_iterations"] > its_max ** 0.5 else "k")
                else:
                    ax.add_patch(plt.Rectangle((-0.5, y - 0.5), 1, 1, color="#c0392b"))
                    ax.text(0, y, SHORT.get(r["status"].split(" ")[0].rstrip(":"), r["status"][:4]), ha="center",
                            va="center", fontsize=7, color="w", fontweight="bold")
            ax.set_xticks([])
            ax.set_yticks(range(len(cases)), cases if j == 0 else [""] * len(cases), fontsize=7)
            ok = sum(1 for r in slender if r["strategy"] == s and r["converged"])
            ax.set_title(f"{s}, slender, default: {ok}/{len(cases)}", fontsize=9)
    fig.suptitle(f"finger.toml (h = {result['size']:g} mm): Newton iterations to converge; red = failure "
                 "(LS line search, MAX iterations, DIV diverged, INV inverted, TR trust region)", fontsize=9)
    fig.tight_layout(rect=(0, 0, 0.92, 0.95))
    cax = fig.add_axes((0.93, 0.15, 0.015, 0.7))
    fig.colorbar(im, cax=cax, label="Newton iterations")
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=OUT, help="output folder")
    ap.add_argument("--figures", type=Path, default=None, help="also copy stability.png here (README)")
    ap.add_argument("--size", type=float, default=3.0, help="mesh size, mm")
    ap.add_argument("--quick", action="store_true", help="three ratios, one contraction, h = 5 (seconds)")
    ap.add_argument("--no-slender", action="store_true", help="skip the slender large-rotation cases")
    a = ap.parse_args(argv)
    if a.quick:
        res = run(ratios=(1.0, 1e3, 1e6), contractions=(DEMO_CONTRACTION,), size=5.0, out=a.out,
                  slender=() if a.no_slender else ("elastica PL²/EI=3",))
    else:
        res = run(size=a.size, out=a.out, slender=() if a.no_slender else tuple(SLENDER))
    s = res["summary"]
    for name, p in s["strategies"].items():
        say(f"{name:12s} {p['successes']:3d}/{p['cases']} converged (by steps {p['by_steps']}), "
              f"median {p['median_iterations']} its, {p['total_time']:.1f} s; "
              f"failures: {', '.join(p['failures']) or '-'}")
    for name, p in s.get("slender", {}).items():
        say(f"slender {name:12s} {p['successes']}/{p['cases']} converged, {p['total_time']:.1f} s: {p['iterations']}")
    say(f"picked: {s['picked']} (default: {s['default']}); energy converges over all ratios at "
          f"u = {DEMO_CONTRACTION:g} mm: {s['energy_converges_over_all_ratios_at_demo_contraction']}")
    copy_figure(a.out / "stability.png", a.figures)
    say(f"outputs in {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
