"""How honest is ``--estimate``? Effectivity of every observable's error bar against fine references.

    python studies/estimate_effectivity.py [--cases strip_bones ...] [--keep] [--out studies/output/...]
    python studies/estimate_effectivity.py --sweep block3d block3d_in_bone block3d_anchor3

Each case is a design that is not one of the bundled files (built here):
``strip_bones`` (2D, a soft strip with two rigid bones bent by a tendon),
``strip_buried`` (2D, the tendon ends in silicone: a finite anchor),
``strip_p2`` (2D, P2, estimated with P3; ``strip_p2_coarse``: the same at
h = 4 mm, 2.5 cells across the strip, where it fails), ``pinch`` (2D, the bundled
gripper's fingers closed 3.5 mm on its box with contact friction mu 0.8 and
a 2 mm mesh, references 2x and 4x finer), ``block3d`` (3D, a soft block with a bone and a
tendon ending on its top in silicone), ``block3d_buried`` (3D, the tendon ends inside it):
both ends are finite anchors of 0.53 mm (the default 1 % of the diagonal) on
cells of 3 mm; ``block3d_in_bone`` (the tendon ends in the bone),
``block3d_anchor3`` (a 3 mm anchor), ``beam3d`` (a slender beam, nu = 0.48,
three cells across, the tendon ending in a tip bone) and ``finger3d`` (a
soft cylinder, nu = 0.49, four cells across, with a bone where the tendon
ends), references at 1.5x and 3x finer.

``--sweep`` measures effectivity against h instead: the design at P1 on three
sizes against one P2 reference (SWEEP), into estimate_effectivity_h.json.

For each: the solve at the case's mesh with ``estimate=True`` (skelfem.estimate),
and two references of degree 2 at h / R and h / (2 R) (R = 4 in 2D, 2 in 3D).
The true error of an observable is |J_ref - J_h| with the finer reference;
the references' own difference is its uncertainty, and an observable is
*measurable* when its true error is at least three times that and above a
floor of 1e-6 of the observable's scale (pins' reactions of a design
with nothing else holding it are round-off). The effectivity is
estimate / true error. Also reported: the solve's and the estimate's wall
times (the estimate's form compilation separately: it is paid once per
degree and machine, FFCx's cache).

run(cases) returns the rows; main(argv) prints them and writes
estimate_effectivity.json and .csv.
"""
from __future__ import annotations

import argparse
import copy
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
MEASURABLE = 3.0          # true error / reference uncertainty needed to count a row
FLOOR = 1e-6              # relative to the observable's scale: below it, round-off


def strip(length=60.0, width=10.0, size=2.0, degree=1, end=None, contraction=3.0, bones=True):
    """A soft strip standing on its pinned base; a tendon at an offset, ending at the top or at `end` (mm)."""
    x_t = width * 0.8
    top = length if end is None else end
    d = {
        "format": 1, "name": "strip", "dim": 2, "thickness": 10.0,
        "mesh": {"size": size, "degree": degree},
        "materials": {"soft": {"E": 0.2, "nu": 0.45}, "hard": {"E": 2000.0, "nu": 0.35}},
        "body": {"outline": [[0, 0], [width, 0], [width, length], [0, length]], "material": "soft"},
        "cables": [{"name": "flexor", "kind": "tendon", "path": [[x_t, 0], [x_t, top]],
                    "stiffness": 5.0, "contraction": contraction}],
        "pins": [{"name": "base", "region": [[-1, -1], [width + 1, 1e-6]], "kind": "fixed"}],
        "markers": {"tip": [width / 2, length], "mid": [width / 2, length / 2]},
    }
    if bones:
        d["bones"] = [{"name": "b1", "outline": [[2, 8], [6.5, 8], [6.5, 26], [2, 26]], "material": "hard"},
                      {"name": "b2", "outline": [[2, 32], [6.5, 32], [6.5, 54], [2, 54]], "material": "hard"}]
    return d


def block3d(size=3.0, degree=1, end=None, anchor=None, in_bone=False):
    """A soft 3D block (12 x 50 x 12 mm) on its pinned base, a bone inside, a tendon at an offset ending at the
    top or at `end` (mm) in silicone, with a finite anchor of radius `anchor` (default: 1 % of the diagonal,
    0.53 mm), or (in_bone) through the bone, ending in it at y = 38 mm: no finite anchor."""
    top = 50.0 if end is None else end
    d = {
        "format": 1, "name": "block3d", "dim": 3, "mesh": {"size": size, "degree": degree},
        "materials": {"soft": {"E": 0.2, "nu": 0.45}, "hard": {"E": 2000.0, "nu": 0.35}},
        "body": {"solids": [{"box": {"min": [0, 0, 0], "max": [12, 50, 12]}}], "material": "soft"},
        "bones": [{"name": "b1", "solids": [{"box": {"min": [2, 20, 3], "max": [7, 40, 9]}}], "material": "hard"}],
        "cables": [{"name": "flexor", "kind": "tendon", "path": [[10, 0, 6], [10, top, 6]],
                    "stiffness": 5.0, "contraction": 2.0}],
        "pins": [{"name": "base", "region": [[-1, -1, -1], [13, 1e-6, 13]], "kind": "fixed"}],
        "markers": {"tip": [6, 50, 6]},
    }
    if anchor is not None:
        d["cables"][0]["anchor_radius"] = anchor
    if in_bone:
        d["cables"][0]["path"] = [[5, 0, 6], [5, 38, 6]]
    return d


def beam3d(size=2.0, degree=1):
    """A slender soft beam (6 x 60 x 6 mm) on its pinned base, a bone at its tip where the tendon ends."""
    return {
        "format": 1, "name": "beam3d", "dim": 3, "mesh": {"size": size, "degree": degree},
        "materials": {"soft": {"E": 0.5, "nu": 0.48}, "hard": {"E": 2000.0, "nu": 0.35}},
        "body": {"solids": [{"box": {"min": [0, 0, 0], "max": [6, 60, 6]}}], "material": "soft"},
        "bones": [{"name": "tip", "solids": [{"box": {"min": [1, 52, 1], "max": [5, 58, 5]}}], "material": "hard"}],
        "cables": [{"name": "flexor", "kind": "tendon", "path": [[4.5, 0, 3], [4.5, 55, 3]],
                    "stiffness": 5.0, "contraction": 2.0}],
        "pins": [{"name": "base", "region": [[-1, -1, -1], [7, 1e-6, 7]], "kind": "fixed"}],
        "markers": {"tip": [3, 60, 3], "mid": [3, 30, 3]},
    }


def finger3d(size=2.5, degree=1):
    """A finger-like soft cylinder (radius 5 mm, 50 mm long) with a cylindrical bone near its tip, where a
    tendon 2 mm off the axis ends."""
    return {
        "format": 1, "name": "finger3d", "dim": 3, "mesh": {"size": size, "degree": degree},
        "materials": {"soft": {"E": 0.3, "nu": 0.49}, "hard": {"E": 3000.0, "nu": 0.35}},
        "body": {"solids": [{"cylinder": {"from": [0, 0, 0], "to": [0, 50, 0], "radius": 5.0}}], "material": "soft"},
        "bones": [{"name": "distal", "solids": [{"cylinder": {"from": [0, 30, 0], "to": [0, 46, 0], "radius": 3.0}}],
                   "material": "hard"}],
        "cables": [{"name": "flexor", "kind": "tendon", "path": [[2, 0, 0], [2, 40, 0]],
                    "stiffness": 5.0, "contraction": 2.0}],
        "pins": [{"name": "base", "region": [[-6, -1, -6], [6, 1e-6, 6]], "kind": "fixed"}],
        "markers": {"tip": [0, 50, 0]},
    }


def _gripper(size: float, degree: int) -> dict:
    import tomllib
    d = tomllib.loads((ROOT / "geometry" / "gripper.toml").read_text())
    d["mesh"] = {**d.get("mesh", {}), "size": size, "degree": degree}
    for c in d["cables"]:
        if c["name"] in ("left_flexor", "right_flexor"):
            c["contraction"] = 3.5
    d.setdefault("contact", {})["friction"] = 0.8
    return d


def _mesh(d: dict, size: float, degree: int) -> dict:
    d = copy.deepcopy(d)
    d["mesh"] = {**d.get("mesh", {}), "size": size, "degree": degree}
    return d


CASES = {   # name: (design dict at the case's mesh, reference refinement ratio R)
    "strip_bones": (lambda: strip(size=2.0), 4),
    "strip_buried": (lambda: strip(size=2.0, end=40.0, bones=False), 4),
    "strip_p2": (lambda: strip(size=2.0, degree=2), 4),
    "strip_p2_coarse": (lambda: strip(size=4.0, degree=2), 4),     # 2.5 cells across: where the estimate fails
    "pinch": (lambda: _gripper(2.0, 1), 2),
    "block3d": (lambda: block3d(size=3.0), 2),
    "block3d_buried": (lambda: block3d(size=3.0, end=35.0), 2),
    "block3d_in_bone": (lambda: block3d(size=3.0, in_bone=True), 2),     # no finite anchor
    "block3d_anchor3": (lambda: block3d(size=3.0, anchor=3.0), 2),      # an anchor as wide as a cell
    "beam3d": (lambda: beam3d(size=2.0), 1.5),
    "finger3d": (lambda: finger3d(size=2.5), 1.5),
}


def _solve(d: dict, estimate: bool = False):
    from skelfem.design.parse import parse_design
    from skelfem.session import Session
    with Session(parse_design(copy.deepcopy(d), d["name"])) as s:
        t0, c0 = time.perf_counter(), time.process_time()
        r = s.solve()
        t_solve = (time.perf_counter() - t0, time.process_time() - c0)
        if not r.converged:
            raise RuntimeError(f"{d['name']}: {r.status}")
        extra = {}
        if estimate:
            c0 = time.process_time()
            extra = s._estimate()
            extra["cpu_s"] = time.process_time() - c0
        return r.observables(), r.dofs, t_solve, extra


def _unit(name: str) -> str:
    """mm, rad or N: which observables share a scale (skelfem.observables' table)."""
    if name.startswith("markers.") or ".position." in name:
        return "mm"
    return "rad" if ".rotation" in name else "N"


def run_case(name: str) -> list[dict]:
    build, R = CASES[name]
    d = build()
    h, p = float(d["mesh"]["size"]), int(d["mesh"]["degree"])
    J, dofs, t_solve, est = _solve(d, estimate=True)
    ref1, dofs1, _, _ = _solve(_mesh(d, h / R, 2))
    ref2, dofs2, _, _ = _solve(_mesh(d, h / (2 * R), 2))
    info = est["estimate"]
    rows = []
    scale = {}
    for k, v in J.items():                          # the scale of a unit: its observables' largest value
        scale[_unit(k)] = max(scale.get(_unit(k), 0.0), abs(v), abs(ref2.get(k, 0.0)))
    for k, v in J.items():
        if k not in ref2 or (est["errors"] or {}).get(k) is None:
            continue
        true, unc = abs(ref2[k] - v), abs(ref2[k] - ref1[k])
        e = est["errors"][k]
        measurable = true >= MEASURABLE * unc and true > FLOOR * max(scale[_unit(k)], 1e-30)
        rows.append({"case": name, "observable": k, "value": v, "reference": ref2[k], "true_error": true,
                     "reference_uncertainty": unc, "estimate": e["error"], "discretisation": e["discretisation"],
                     "algebraic": e["algebraic"], "measurable": bool(measurable),
                     "effectivity": e["error"] / true if measurable else None,
                     "degree": p, "h": h, "dofs": dofs, "reference_dofs": dofs2,
                     "solve_s": round(t_solve[0], 3), "solve_cpu_s": round(t_solve[1], 3),
                     "estimate_s": info["seconds"]["algebraic"] + info["seconds"]["solve"],
                     "estimate_cpu_s": round(est["cpu_s"], 3),
                     "estimate_compile_s": info["seconds"]["compile"], "estimate_dofs": info["dofs"]})
    return rows


SWEEP = {   # name: (builder of size, P1 sizes, the reference's P2 sizes: the finer one is the reference)
    "block3d": (lambda h, p: block3d(size=h, degree=p), (3.0, 2.0, 1.5), (1.5, 1.0)),
    "block3d_in_bone": (lambda h, p: block3d(size=h, degree=p, in_bone=True), (3.0, 2.0, 1.5), (1.5, 1.0)),
    "block3d_anchor3": (lambda h, p: block3d(size=h, degree=p, anchor=3.0), (3.0, 2.0, 1.5), (1.5, 1.0)),
}


def h_sweep(name: str) -> list[dict]:
    """Effectivity against h: the design at P1 on each size of SWEEP[name], estimated, against one reference (P2
    on the finest reference mesh; its change from the coarser one is its uncertainty)."""
    build, sizes, (h1, h2) = SWEEP[name]
    ref1, _, _, _ = _solve(build(h1, 2))
    ref2, dofs2, _, _ = _solve(build(h2, 2))
    rows = []
    for h in sizes:
        J, dofs, _, est = _solve(build(h, 1), estimate=True)
        for k in J:
            if k.startswith("pins") or k not in ref2:
                continue
            true, unc = abs(ref2[k] - J[k]), abs(ref2[k] - ref1[k])
            e = est["errors"][k]["error"]
            rows.append({"case": name, "h": h, "dofs": dofs, "observable": k, "value": J[k], "reference": ref2[k],
                         "reference_h": h2, "reference_dofs": dofs2, "true_error": true, "reference_uncertainty": unc,
                         "estimate": e, "measurable": bool(true >= MEASURABLE * unc),
                         "effectivity": e / true if true >= MEASURABLE * unc else None})
    return rows


def run(cases=tuple(CASES)) -> list[dict]:
    rows = []
    for name in cases:
        rows += run_case(name)
        print(f"  {name}: done", file=sys.stderr, flush=True)
    return rows


def summary(rows: list[dict]) -> dict:
    eff = np.array([r["effectivity"] for r in rows if r["measurable"]])
    key = [r["effectivity"] for r in rows if r["measurable"] and (r["observable"].startswith("markers.tip")
                                                                   or r["observable"].endswith(".tension"))]
    cost = {}
    for r in rows:
        cost[r["case"]] = {"dofs": r["dofs"], "solve_s": r["solve_s"], "estimate_s": r["estimate_s"],
                           "ratio": round(r["estimate_s"] / r["solve_s"], 2), "compile_s": r["estimate_compile_s"],
                           "ratio_cpu": round(r["estimate_cpu_s"] / r["solve_cpu_s"], 2)}
    return {"measurable": int(len(eff)), "rows": len(rows),
            "within_0.5_2": int(np.sum((eff >= 0.5) & (eff <= 2))),
            "within_0.33_3": int(np.sum((eff >= 1 / 3) & (eff <= 3))),
            "below_0.1": int(np.sum(eff < 0.1)),
            "tip_and_tension_within_0.5_2": f"{sum(0.5 <= e <= 2 for e in key)} of {len(key)}",
            "min": float(eff.min()) if len(eff) else None, "max": float(eff.max()) if len(eff) else None,
            "cost": cost}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=list(CASES), choices=list(CASES))
    ap.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "estimate_effectivity")
    ap.add_argument("--keep", action="store_true",
                    help="keep the rows of the cases not run from the output already there (re-run some cases)")
    ap.add_argument("--sweep", nargs="*", choices=list(SWEEP),
                    help="instead: effectivity against h on these designs (estimate_effectivity_h.json)")
    args = ap.parse_args(argv)
    if args.sweep:
        swept = [r for name in args.sweep for r in h_sweep(name)]
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "estimate_effectivity_h.json").write_text(json.dumps(swept, indent=1))
        for r in swept:
            eff = "   -  " if r["effectivity"] is None else f"{r['effectivity']:6.2f}"
            print(f"{r['case']:16s} h {r['h']:4g} {r['dofs']:6d} {r['observable']:24s} true {r['true_error']:9.3g} "
                  f"(ref +- {r['reference_uncertainty']:8.2g}) est {r['estimate']:9.3g} eff {eff}")
        return 0
    rows = run(args.cases)
    old = args.out / "estimate_effectivity.json"
    if args.keep and old.exists():
        kept = [r for r in json.loads(old.read_text())["rows"] if r["case"] not in args.cases]
        rows = [r for name in CASES for r in kept + rows if r["case"] == name]
    args.out.mkdir(parents=True, exist_ok=True)
    s = summary(rows)
    (args.out / "estimate_effectivity.json").write_text(json.dumps({"rows": rows, "summary": s}, indent=1))
    from skelfem.io.files import write_csv
    write_csv(args.out / "estimate_effectivity.csv", list(rows[0]) if rows else [], rows)
    for r in rows:
        eff = "   -  " if r["effectivity"] is None else f"{r['effectivity']:6.2f}"
        print(f"{r['case']:15s} {r['observable']:32s} {r['value']:11.5g} true {r['true_error']:9.3g} "
              f"(ref +- {r['reference_uncertainty']:8.2g}) est {r['estimate']:9.3g} eff {eff}")
    print(json.dumps(s, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
