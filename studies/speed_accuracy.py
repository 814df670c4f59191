"""Speed against accuracy: marker error vs wall time for P1 and P2 triangles over mesh sizes.

    python studies/speed_accuracy.py [--out studies/output/speed_accuracy] [--figures studies/figures] [--quick]

Problems (2D, plane strain):

* ``finger``: geometry/finger.toml at its demo contraction (8 mm), marker ``tip``.
  The pin region is narrowed to the base edge (y <= 0.01 mm): the file's box
  reaches y = 0.5 mm, so on meshes with h <= 0.5 the lowest lateral facets
  fall inside it and are pinned too, which changes the problem with h.
* ``strip``: a 100 x 10 mm silicone strip (E = 1 MPa, nu = 0.3, 10 mm deep)
  pinned at its base, one straight tendon at offset d = 3 mm from the axis
  anchored in a stiff cap at the tip, marker at the tip. Beam theory: a
  uniform moment T d bends the strip into an arc of curvature
  kappa = T d / (E' I), E' = E / (1 - nu^2), I = t w^3 / 12.
* ``strip_nu0.499``: the same with nearly incompressible silicone, where P1
  triangles lock (lambda / mu = 2 nu / (1 - 2 nu) = 499).
* ``strip_point_anchor`` (not run by default): the tendon anchored in the
  silicone at the tip surface. A point force on an elastic continuum has a
  log-singular displacement in 2D, so the anchor sinks a little further at
  every refinement and the tension drifts by a constant amount per halving
  of h: no convergence rate, no Richardson.

Every problem with bones (the finger's three, the strips' cap) is solved
twice per mesh: with its bones elastic, as written, and with every bone
``rigid = true`` (skelfem.terms.rigid), so rigid against elastic bones can
be read on one chart; the reference is always the elastic finest P2.

Error of a case: |x_marker - x_ref| (mm), x_ref from the finest P2 mesh; the
reference's own error is estimated by Richardson extrapolation from the
three finest P2 meshes (observed order p from their differences). Wall time
is meshing + model set-up + Newton solve, after an untimed warm-up that fills
the FFCx cache. On a shared machine compare times within one run only.

run(**params) returns the numbers; main(argv) writes cases.csv, summary.json
and speed_accuracy.png into the output folder.
"""
from __future__ import annotations

import argparse
import copy
import json
import math
import time
import tomllib
from pathlib import Path

import numpy as np
from skelfem.io.files import copy_figure, say

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "studies" / "output" / "speed_accuracy"
FINGER = ROOT / "geometry" / "finger.toml"

DEFAULT_SIZES = {
    "finger": {1: (4.0, 2.0, 1.0, 0.7, 0.5, 0.35), 2: (4.0, 2.0, 1.0, 0.7, 0.5)},
    "strip": {1: (4.0, 2.0, 1.0, 0.5, 0.35), 2: (4.0, 2.0, 1.0, 0.7, 0.5)},
    "strip_nu0.499": {1: (4.0, 2.0, 1.0, 0.5, 0.35), 2: (4.0, 2.0, 1.0, 0.7, 0.5)},
}
QUICK_SIZES = {"strip": {1: (4.0, 2.0), 2: (4.0, 2.0, 1.0)}, "strip_nu0.499": {1: (4.0, 2.0), 2: (4.0, 2.0, 1.0)}}

# strip geometry and material (mm, MPa, N/mm)
L, W, THICK, D_OFF, E_STRIP, K_CABLE, CONTRACTION = 100.0, 10.0, 10.0, 3.0, 1.0, 1.0, 0.6
CAP = 5.0      # stiff cap [W/2 -/+ 4.5] x [L - CAP, L - 0.5] holding the tendon's anchor


# -- problems ------------------------------------------------------------------------------------------
def strip_dict(size: float, degree: int, nu: float = 0.3, cap: bool = True) -> dict:
    """The tendon strip as a design dictionary (skelfem.design.parse_design)."""
    x_t = W / 2 + D_OFF
    d = {
        "format": 1, "name": "strip", "dim": 2, "thickness": THICK,
        "mesh": {"size": size, "degree": degree},
        "materials": {"silicone": {"E": E_STRIP, "nu": nu}, "cap": {"E": 1000.0 * E_STRIP, "nu": 0.35}},
        "body": {"outline": [[0, 0], [W, 0], [W, L], [0, L]], "material": "silicone"},
        "cables": [{"name": "flexor", "kind": "tendon", "path": [[x_t, 0], [x_t, L - CAP / 2 if cap else L]],
                    "stiffness": K_CABLE, "contraction": CONTRACTION}],
        "pins": [{"name": "base", "region": [[-1, -1], [W + 1, 1e-6]], "kind": "fixed"}],
        "markers": {"tip": [W / 2, L]},
    }
    if cap:
        d["bones"] = [{"name": "cap", "outline": [[0.5, L - CAP], [W - 0.5, L - CAP], [W - 0.5, L - 0.5],
                                                  [0.5, L - 0.5]], "material": "cap"}]
    return d


def finger_dict(size: float, degree: int) -> dict:
    """geometry/finger.toml with the pin box narrowed to the base edge (see the module docstring)."""
    with open(FINGER, "rb") as f:
        d = tomllib.load(f)
    d = copy.deepcopy(d)
    d.setdefault("name", "finger")
    d["mesh"] = {"size": size, "degree": degree}
    for pin in d["pins"]:
        (x0, y0), (x1, _) = pin["region"]
        pin["region"] = [[x0, y0], [x1, 0.01]]
    return d


PROBLEMS = {
    "finger": lambda h, p: finger_dict(h, p),
    "strip": lambda h, p: strip_dict(h, p, 0.3),
    "strip_nu0.499": lambda h, p: strip_dict(h, p, 0.499),
    "strip_point_anchor": lambda h, p: strip_dict(h, p, 0.3, cap=False),
}
NU = {"strip": 0.3, "strip_nu0.499": 0.499, "strip_point_anchor": 0.3}


# -- one case ------------------------------------------------------------------------------------------------
def circle_curvature(points: np.ndarray) -> float:
    """Curvature 1/R of the least-squares circle x^2 + y^2 + a x + b y + c = 0 through points."""
    x, y = points[:, 0], points[:, 1]
    A = np.column_stack([x, y, np.ones_like(x)])
    a, b, c = np.linalg.lstsq(A, -(x * x + y * y), rcond=None)[0]
    return 1.0 / math.sqrt(max(a * a / 4 + b * b / 4 - c, 1e-300))


def strip_beam_check(model, nu: float) -> dict:
    """Mid-span curvature of the deformed axis (circle fit, y in [30, 70]) against kappa = T d / (E' I)."""
    from skelfem.mesh.points import interpolation_matrix
    ys = np.linspace(30.0, 70.0, 41)
    X = np.column_stack([np.full_like(ys, W / 2), ys])
    x = X + (interpolation_matrix(model.V, X) @ model.u.x.array).reshape(-1, 2)
    tendon = model.terms_in("cables")[0]
    T = tendon.cable.tension(model.u.x.array, tendon.rest_length)
    kappa_beam = T * D_OFF / (E_STRIP / (1 - nu ** 2) * THICK * W ** 3 / 12)
    return {"tension": T, "kappa": circle_curvature(x), "kappa_beam": kappa_beam}


def solve_case(problem: str, degree: int, size: float, rigid: bool = False) -> dict:
    """Mesh, set up and solve one case (rigid: every bone rigid); returns its numbers and wall times."""
    from skelfem import Session
    from skelfem.design import parse_design

    d = PROBLEMS[problem](size, degree)
    for bone in d.get("bones", []) if rigid else []:
        bone["rigid"] = True
    design = parse_design(d, f"{problem}.toml")
    t0 = time.perf_counter()
    session = Session(design)                 # mesh, then model and Newton solver ("compile")
    setup = dict(session.timings)
    t2 = time.perf_counter()
    result = session.solve()
    t3 = time.perf_counter()
    session.close()
    row = {"problem": problem, "degree": degree, "size": size, "dofs": session.dofs,
           "bones": ("rigid" if rigid else "elastic") if d.get("bones") else None,
           "converged": bool(result.converged), "status": result.status,
           "newton_iterations": result.newton_iterations,
           "time_mesh": setup["mesh"], "time_setup": setup["compile"], "time_solve": t3 - t2,
           "time": t3 - t0}
    if result.converged:        # a failed solve is never reported as an equilibrium
        tip = result.markers["tip"]
        cable = next(iter(result.cables.values()))
        row.update(x=float(tip["position"][0]), y=float(tip["position"][1]),
                   displacement=float(np.linalg.norm(tip["displacement"])), tension=float(cable["tension"]))
        if problem in NU:
            beam = strip_beam_check(session.model, NU[problem])
            row.update(kappa=beam["kappa"], kappa_beam=beam["kappa_beam"],
                       kappa_ratio=beam["kappa"] / beam["kappa_beam"])
    return row


# -- analysis ---------------------------------------------------------------------------------------------------
def richardson(sizes, points) -> dict:
    """Observed order and error of the finest of three solutions x(h1), x(h2), x(h3), h1 > h2 > h3.

    With x(h) = x* + C h^p:  |x1 - x2| / |x2 - x3| = (h1^p - h2^p) / (h2^p - h3^p), solved for p
    by bisection; then the error of x3 is |x2 - x3| h3^p / (h2^p - h3^p). When the differences do
    not shrink (no asymptotic range), p is undefined and the error of x3 is bounded
    conservatively by the largest difference among the three.
    """
    h1, h2, h3 = sizes
    x1, x2, x3 = (np.asarray(p, float) for p in points)
    d12, d23 = float(np.linalg.norm(x1 - x2)), float(np.linalg.norm(x2 - x3))
    conservative = max(d12, d23, float(np.linalg.norm(x1 - x3)))

    def ratio(p):
        return (h1 ** p - h2 ** p) / (h2 ** p - h3 ** p)
    target = d12 / d23 if d23 > 0 else math.inf
    lo, hi = 0.25, 8.0
    if not (ratio(lo) < target < ratio(hi)):
        return {"order": None, "error": conservative, "method": "spread (no asymptotic range)",
                "differences": [d12, d23]}
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ratio(mid) < target else (lo, mid)
    p = 0.5 * (lo + hi)
    err = d23 * h3 ** p / (h2 ** p - h3 ** p)
    return {"order": p, "error": err, "method": "richardson", "differences": [d12, d23],
            "extrapolated": (x3 + (x3 - x2) * h3 ** p / (h2 ** p - h3 ** p)).tolist()}


def fit_power(h, values) -> dict | None:
    """values ~ C h^r by least squares in log-log; None with fewer than two points."""
    h, v = np.asarray(h, float), np.asarray(values, float)
    ok = (h > 0) & (v > 0) & np.isfinite(v)
    if ok.sum() < 2:
        return None
    r, logC = np.polyfit(np.log(h[ok]), np.log(v[ok]), 1)
    return {"C": float(np.exp(logC)), "r": float(r), "points": int(ok.sum())}


def pareto_front(rows, floor: float = 0.0) -> list[int]:
    """Indices of the cases no other case beats in both time and error, fastest first.

    Errors below ``floor`` (the reference's own error) count as ``floor``:
    the data cannot rank them.
    """
    pts = [(r["time"], max(r["error"], floor), i) for i, r in enumerate(rows)
           if np.isfinite(r.get("error", np.nan))]
    pts.sort()
    front, best = [], math.inf
    for t, e, i in pts:
        if e < best:
            front.append(i)
            best = e
    return front


def analyse(problem: str, rows: list[dict]) -> dict:
    """Reference, errors, error and time models per degree, Pareto front, cheapest case per target."""
    p2 = sorted((r for r in rows if r["degree"] == 2 and r["converged"] and r.get("bones") != "rigid"),
                key=lambda r: -r["size"])
    if not p2:
        raise RuntimeError(f"{problem}: no converged P2 case for the reference")
    ref = p2[-1]
    x_ref = np.array([ref["x"], ref["y"]])
    rich = richardson([r["size"] for r in p2[-3:]], [[r["x"], r["y"]] for r in p2[-3:]]) \
        if len(p2) >= 3 else {"order": None, "error": float("nan"), "method": "too few P2 levels"}
    for r in rows:
        r["reference"] = r is ref
        r["error"] = float(np.linalg.norm([r["x"] - x_ref[0], r["y"] - x_ref[1]])) \
            if r["converged"] and r is not ref else float("nan")
        r["relative_error"] = r["error"] / ref["displacement"] if ref["displacement"] > 0 else float("nan")
    ref_err = rich["error"] if np.isfinite(rich["error"]) else 0.0
    models, rigid_models = {}, {}
    for p in (1, 2):
        for kind, out in (("elastic", models), ("rigid", rigid_models)):
            mine = [r for r in rows if r["degree"] == p and r["converged"]
                    and (r.get("bones") == "rigid") == (kind == "rigid")]
            resolved = [r for r in mine if np.isfinite(r["error"]) and r["error"] > 2 * ref_err]
            if mine:
                out[p] = {"error": fit_power([r["size"] for r in resolved], [r["error"] for r in resolved]),
                          "time": fit_power([r["size"] for r in mine], [r["time"] for r in mine])}
    front = pareto_front(rows, ref_err)
    targets = {}
    for rel in (0.01, 0.003, 0.001):
        ok = [r for r in rows if np.isfinite(r["error"]) and r["error"] <= rel * ref["displacement"]
              and r["error"] > 0]
        best = min(ok, key=lambda r: r["time"]) if ok else None
        targets[f"{rel:g}"] = None if best is None else {
            "degree": best["degree"], "size": best["size"], "error": best["error"], "time": best["time"],
            "bones": best.get("bones")}
    return {"reference": {"degree": 2, "size": ref["size"], "x": ref["x"], "y": ref["y"],
                          "displacement": ref["displacement"], "dofs": ref["dofs"], "time": ref["time"]},
            "reference_error": rich, "models": models, "rigid_models": rigid_models,
            "pareto": [{"degree": rows[i]["degree"], "size": rows[i]["size"], "error": rows[i]["error"],
                        "time": rows[i]["time"], "dofs": rows[i]["dofs"], "bones": rows[i].get("bones")}
                       for i in front],
            "cheapest_for_relative_error": targets}


def tol_rule(summary: dict, problem: str = "finger") -> dict:
    """Smallest-time (degree, h) with predicted error e_p(h) = C_p h^r_p <= tol, per fitted model."""
    models = summary[problem]["models"]
    return {str(p): {"C": m["error"]["C"], "r": m["error"]["r"],
                     "time_a": m["time"]["C"] if m["time"] else None,
                     "time_b": -m["time"]["r"] if m["time"] else None}
            for p, m in models.items() if m["error"]}


# -- driver --------------------------------------------------------------------------------------------------------
def run(problems=("finger", "strip", "strip_nu0.499"), sizes: dict | None = None, out: Path | None = None,
        progress=print, rigid: bool = True) -> dict:
    """Solve every (problem, degree, size), and with rigid bones too where the problem has bones (rigid);
    returns {"cases": [...], "summary": {problem: ...}}."""
    sizes = sizes or DEFAULT_SIZES
    cases, summary = [], {}
    for problem in problems:
        grid = sizes.get(problem, DEFAULT_SIZES.get(problem))
        rows = []
        kinds = (False, True) if rigid and PROBLEMS[problem](1.0, 1).get("bones") else (False,)
        for degree in (1, 2):
            for kind in kinds:
                solve_case(problem, degree, max(grid[degree]), kind)          # warm-up: FFCx cache, imports
                for h in sorted(grid[degree], reverse=True):
                    row = solve_case(problem, degree, h, kind)
                    rows.append(row)
                    if progress:
                        where = f"tip ({row['x']:.4f}, {row['y']:.4f})" if row["converged"] else row["status"]
                        progress(f"{problem:14s} P{degree} {'rigid ' if kind else ''}h={h:<5g} {row['dofs']:7d} DOFs"
                                 f"  {row['time']:7.2f} s  {row['newton_iterations']:3d} its  {where}")
        summary[problem] = analyse(problem, rows)
        cases += rows
    result = {"cases": cases, "summary": summary}
    if "finger" in summary:
        result["tol_rule"] = tol_rule(summary)
    if out is not None:
        write_outputs(Path(out), result)
    return result


CSV_FIELDS = ("problem", "degree", "bones", "size", "dofs", "converged", "status", "newton_iterations", "time",
              "time_mesh", "time_setup", "time_solve", "x", "y", "displacement", "tension", "error",
              "relative_error", "reference", "kappa", "kappa_beam", "kappa_ratio")


def write_outputs(out: Path, result: dict) -> None:
    from skelfem.io.files import write_csv, write_json

    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "cases.csv", CSV_FIELDS, result["cases"])
    write_json(out / "summary.json", json.loads(json.dumps(
        {k: v for k, v in result.items() if k != "cases"}, default=_jsonable)))
    plot(out / "speed_accuracy.png", result)


def _jsonable(v):
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    raise TypeError(type(v))


def plot(path: Path, result: dict) -> None:
    """One panel per problem: error vs wall time, P1 and P2, Pareto front, reference error band."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from skelfem.io.files import atomic_write

    problems = list(result["summary"])
    fig, axes = plt.subplots(1, len(problems), figsize=(5.0 * len(problems), 4.4), dpi=110, squeeze=False)
    style = {1: dict(marker="o", color="#1f5fbf"), 2: dict(marker="s", color="#d9822b")}
    for ax, problem in zip(axes[0], problems):
        rows = [r for r in result["cases"] if r["problem"] == problem and np.isfinite(r.get("error", np.nan))]
        s = result["summary"][problem]
        for p in (1, 2):
            for kind in ("elastic", "rigid"):
                mine = sorted((r for r in rows
                               if r["degree"] == p and (r.get("bones") == "rigid") == (kind == "rigid")),
                              key=lambda r: r["time"])
                if not mine:
                    continue
                rigid = kind == "rigid"
                ax.loglog([r["time"] for r in mine], [r["error"] for r in mine], ls="--" if rigid else "-", lw=0.8,
                          ms=5, label=f"P{p}" + (" rigid bones" if rigid else ""),
                          **{**style[p], **({"mfc": "none"} if rigid else {})})
                for r in mine:
                    ax.annotate(f"{r['size']:g}", (r["time"], r["error"]), textcoords="offset points",
                                xytext=(4, -9 if rigid else 3), fontsize=7, color=style[p]["color"])
        front = s["pareto"]
        ax.step([q["time"] for q in front], [q["error"] for q in front], where="post", color="k", lw=1.6,
                alpha=0.5, label="Pareto front")
        ref_err = s["reference_error"]["error"]
        if np.isfinite(ref_err) and ref_err > 0:
            ax.axhspan(1e-300, ref_err, color="0.85", zorder=0,
                       label=f"below the reference's error ({s['reference_error']['method'].split(' ')[0]})")
        errors = [r["error"] for r in rows]
        ax.set_ylim(0.5 * min(errors + [ref_err if ref_err > 0 else np.inf]), 2.0 * max(errors))
        ax.set_xlabel("wall time: mesh + set-up + solve [s]")
        ax.set_ylabel("marker error vs finest P2 [mm]")
        ax.set_title(f"{problem}: tip moves {s['reference']['displacement']:.2f} mm\n"
                     f"(labels: mesh size h in mm; reference P2 h={s['reference']['size']:g})", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=OUT, help="output folder")
    ap.add_argument("--figures", type=Path, default=None, help="also copy speed_accuracy.png here (README)")
    ap.add_argument("--problems", nargs="+", default=["finger", "strip", "strip_nu0.499"], choices=list(PROBLEMS))
    ap.add_argument("--quick", action="store_true", help="strips only, coarse meshes (seconds)")
    a = ap.parse_args(argv)
    problems = [p for p in a.problems if p in QUICK_SIZES] if a.quick else a.problems
    res = run(problems, QUICK_SIZES if a.quick else None, a.out)
    for problem, s in res["summary"].items():
        say(f"{problem}: reference P2 h={s['reference']['size']:g}, tip moves {s['reference']['displacement']:.3f} mm, "
              f"reference error {s['reference_error']['error']:.2g} mm ({s['reference_error']['method']})")
        for kind, models in (("", s["models"]), (" rigid bones", s["rigid_models"])):
            for p, m in models.items():
                if m["error"]:
                    say(f"  P{p}{kind}: error ~ {m['error']['C']:.3g} h^{m['error']['r']:.2f} mm, "
                        f"time ~ {m['time']['C']:.3g} h^{m['time']['r']:.2f} s")
        say("  Pareto: " + ", ".join(f"P{q['degree']}{' rigid' if q['bones'] == 'rigid' else ''} h={q['size']:g} "
                                       f"({q['error']:.2g} mm, {q['time']:.2f} s)"
                                       for q in s["pareto"]))
    copy_figure(a.out / "speed_accuracy.png", a.figures)
    say(f"outputs in {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
