"""Adaptive against uniform refinement: marker error against DOFs and wall time, P1 and P2.

    python studies/adaptive.py [--designs finger thumb finger_tapered_fillet] [--tol-designs ...]
                               [--ref-size 0.3] [--rounds 3] [--levels 4] [--out studies/output/adaptive]
                               [--figures studies/figures] [--reuse-references]

For each design (geometry/<name>.toml) a reference is solved with P2 on a
much finer mesh (--ref-size, graded at finite anchors and clamped corners as
the --tol ladder's meshes are), with a twin at 0.95 of its size whose
difference is the reference's own scatter (kept in
OUT/<design>/reference.json and read back with --reuse-references). Then,
for P1 and P2:

* ``uniform``: the --tol ladder's meshes, 2h, h, h/2, ... (h the design's
  [mesh] size; --levels meshes for P2, one more for P1; uniform h with the
  ladder's fixed zones at anchors and clamped corners scaled with it), each
  warm-started from the last;
* ``adaptive``: skelfem.adapt's rounds (three meshes of one size field
  each, indicators, a new field), driven past any tolerance (tol 1e-9) for
  --rounds rounds.

Every mesh's tip error against the reference is recorded with its DOFs and
the wall time the method had spent when that answer was there (all meshes
before it, meshing, indicators and solves; the reference checks are not
timed), and with the method's own estimate where it has one (the adaptive
rounds' last mesh; the uniform ladder's from its third mesh on: the
answers a method can give, which the figure and the summary count), so the
estimate's effectivity (estimate / error) can be read too. Each adaptive
round aims at REDUCTION times the last estimate (a curve, not a stop). Then
``--tol`` itself (P2) for each of --tols on each of --tol-designs, uniform
and adaptive, as the command runs it: final DOFs, time, estimate, ``met``
and the true error.
run(**params) returns the rows; main(argv) prints them and writes
adaptive.json and adaptive.png into --out.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from skelfem.io.files import copy_figure, say

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "studies" / "output" / "adaptive"
DESIGNS = ("finger", "thumb", "finger_tapered_fillet")
MARKER = "tip"
REDUCTION = 0.25          # each adaptive round aims at a quarter of the last estimate (P2: one uniform halving)
TOLS = (0.1, 0.05)        # --tol runs (P2): uniform ladder against adaptive rounds
TOL_DESIGNS = DESIGNS


def _design(name: str, size: float, degree: int):
    from skelfem.design import load_design
    return load_design(ROOT / "geometry" / f"{name}.toml", [f"mesh.size={size!r}", f"mesh.degree={degree}"])


def _first_size(name: str) -> float:
    """The --tol ladder's first size: twice the design's own [mesh] size."""
    from skelfem.design import load_design
    return 2.0 * float(load_design(ROOT / "geometry" / f"{name}.toml").mesh.size)


def _tip(result) -> np.ndarray:
    return np.asarray(result.markers[MARKER]["position"], dtype=float)


def _graded(session, h0: float):
    """The --tol ladder's fixed zones for the design (accuracy.ladder_zones at its first size h0), or None."""
    from skelfem.accuracy.ladder import ladder_zones
    return ladder_zones(session.model, session.design, h0)


def _edit(session, name: str, h: float, degree: int, zones, h0: float) -> None:
    """Mesh the design at size h, graded as the ladder grades it (the zones scaled by h / h0)."""
    session.edit(_design(name, h, degree), size=None if zones is None else zones.scaled(h / h0))


def reference(name: str, size: float, out: Path | None, reuse: bool) -> dict:
    """The P2 tip at the reference size, graded as the ladder's meshes are (zones scaled to size), and its
    twin at accuracy.TWIN * size: ``scatter`` = |tip_twin - tip| is the reference's own mesh-to-mesh
    scatter. Solved, or read back from out/<name>/reference.json (reuse)."""
    from skelfem import Session
    from skelfem.accuracy.ladder import TWIN

    path = None if out is None else Path(out) / name / "reference.json"
    if reuse and path is not None and path.exists():
        ref = json.loads(path.read_text())
        if ref.get("size") == size and "scatter" in ref:
            say(f"{name}: reference read back from {path}", flush=True)
            return ref
    t = time.perf_counter()
    h0 = _first_size(name)

    def solved(s, h):
        _edit(s, name, h, 2, zones, h0)
        r = s.solve()
        if not r.converged:
            raise RuntimeError(f"{name}: the reference solve at h = {h:g} mm failed ({r.status})")
        return r

    with Session(_design(name, h0, 2)) as s:
        zones = _graded(s, h0)
        r = solved(s, size)
        ref = {"design": name, "size": size, "dofs": int(r.dofs), "tip": _tip(r).tolist(),
               "time": time.perf_counter() - t, "graded": zones is not None}
        ref["scatter"] = float(np.linalg.norm(_tip(solved(s, TWIN * size)) - _tip(r)))
    if path is not None:
        from skelfem.io.files import write_json
        path.parent.mkdir(parents=True, exist_ok=True)
        write_json(path, ref)
    return ref


def uniform(name: str, degree: int, levels: int, tip_ref: np.ndarray) -> list[dict]:
    """The --tol ladder 2h, h, h/2, ... (uniform h, graded by the ladder's fixed zones, warm-started),
    one row per mesh."""
    from skelfem import Session
    from skelfem.accuracy import ladder as accuracy

    h0 = _first_size(name)
    rows, ladder, spent = [], [], 0.0
    t = time.perf_counter()
    session = Session(_design(name, h0, degree))
    try:
        zones = _graded(session, h0)
        for k in range(levels):
            if k:
                t = time.perf_counter()
            if k or zones is not None:
                _edit(session, name, h0 / 2 ** k, degree, zones, h0)
            r = session.solve()
            spent += time.perf_counter() - t
            if not r.converged:
                break
            ladder.append(accuracy.next_level(ladder, h0 / 2 ** k, r, 0.0))
            lv = ladder[-1] = accuracy.judged(ladder)           # the estimate --tol would give
            rows.append({"design": name, "method": "uniform", "degree": degree, "mesh": k + 1,
                         "dofs": int(r.dofs), "max_size": h0 / 2 ** k,
                         "min_size": h0 / 2 ** k if zones is None else zones.scaled(2.0 ** -k).smallest,
                         "time": spent, "error": float(np.linalg.norm(_tip(r) - tip_ref)),
                         "estimate": lv.estimate if k >= 2 else None})
    finally:
        session.close()
    return rows


def adaptive(name: str, degree: int, rounds: int, tip_ref: np.ndarray) -> list[dict]:
    """skelfem.adapt's rounds driven past any tolerance; one row per mesh."""
    from skelfem import Session
    from skelfem.accuracy.adapt import refine_adaptive

    h0 = _first_size(name)
    rows = []
    paused = [0.0]                         # time spent here, in the callback, is not the method's

    def on_level(rec, session):
        t = time.perf_counter()
        r_tip = session.model.term("markers")
        tip = r_tip.positions(session.model.u.x.array)[list(session.design.markers).index(MARKER)]
        rows.append({"design": name, "method": "adaptive", "degree": degree,
                     "mesh": 3 * (rec["round"] - 1) + rec["mesh"], "round": rec["round"],
                     "dofs": rec["dofs"], "min_size": rec["min_size"], "max_size": rec["max_size"],
                     "time": t - t0 - paused[0], "error": float(np.linalg.norm(tip - tip_ref)),
                     "estimate": rec["estimate"] if rec["mesh"] == 3 else None})
        paused[0] += time.perf_counter() - t

    t0 = time.perf_counter()
    session = Session(_design(name, h0, degree))
    try:
        refine_adaptive(session, 1e-9, degree=degree, max_rounds=rounds, on_level=on_level, reduction=REDUCTION)
    finally:
        session.close()
    return rows


def tol_runs(name: str, tols, tip_ref: np.ndarray) -> list[dict]:
    """``--tol`` as the command runs it (P2), uniform ladder and adaptive rounds: one row per (tol, method)."""
    from skelfem import Session
    from skelfem.accuracy import ladder, tol as accuracy
    from skelfem.design import load_design

    rows = []
    for tol in tols:
        for method in ("uniform", "adaptive"):
            t = time.perf_counter()
            with Session(ladder.first_level(load_design(ROOT / "geometry" / f"{name}.toml"))) as session:
                result, a = accuracy.refine(session, tol, adaptive=method == "adaptive")
                spent = time.perf_counter() - t
            failed = None if result.converged else a["stop"]          # no equilibrium: no error to measure
            rows.append({"design": name, "method": method, "tol": tol, "dofs": int(a["dofs"]), "time": spent,
                         "meshes": len(a["levels"]), "estimate": a["estimated_error"], "met": bool(a["met"]),
                         "ladder_dofs": [lv["dofs"] for lv in a["levels"] if not lv.get("twin")],
                         "error": float("nan") if failed else float(np.linalg.norm(_tip(result) - tip_ref)),
                         "min_size": a.get("min_size", a["size"]), "max_size": a.get("max_size", a["size"]),
                         "failed": failed})
            r = rows[-1]
            if failed:
                say(f"  --tol {tol:g} {method:8s}: FAILED after {r['meshes']} meshes ({r['time']:.2f} s): {failed}",
                    flush=True)
                continue
            say(f"  --tol {tol:g} {method:8s}: {r['dofs']:7d} DOFs ({r['meshes']} meshes, h {r['min_size']:.3g}.."
                f"{r['max_size']:.3g}), {r['time']:6.2f} s, estimate {r['estimate']:.3g} mm "
                f"({'met' if r['met'] else 'NOT met'}), error {r['error']:.3g} mm "
                f"(effectivity {r['estimate'] / max(r['error'], 1e-12):.2f})", flush=True)
    return rows


def run(designs=DESIGNS, ref_size: float = 0.3, rounds: int = 3, levels: int = 4, degrees=(1, 2),
        out: Path | None = None, reuse: bool = False, tols=TOLS, tol_designs=TOL_DESIGNS) -> dict:
    """Rows for every (design, method, degree, mesh), the --tol runs, and each design's reference."""
    rows, refs, tol_rows = [], {}, []
    for name in designs:
        ref = refs[name] = reference(name, ref_size, out, reuse)
        say(f"{name}: reference P2 h = {ref_size:g} ({ref['dofs']} DOFs, {ref['time']:.1f} s), "
            f"its own scatter {ref['scatter']:.2g} mm", flush=True)
        tip_ref = np.asarray(ref["tip"], float)
        for degree in degrees:
            uniform(name, degree, 1, tip_ref)             # compiles the forms: not timed below
            for method in ("uniform", "adaptive"):
                mine = uniform(name, degree, levels + (degree == 1), tip_ref) if method == "uniform" \
                    else adaptive(name, degree, rounds, tip_ref)
                rows += mine
                for r in mine:
                    est = "" if r["estimate"] is None else f", estimate {r['estimate']:.3g} mm"
                    say(f"  P{degree} {method:8s} mesh {r['mesh']:2d}: {r['dofs']:7d} DOFs, h {r['min_size']:.3g}.."
                        f"{r['max_size']:.3g} mm, {r['time']:6.2f} s, error {r['error']:.3g} mm{est}", flush=True)
        if name in tol_designs:
            tol_rows += tol_runs(name, tols, tip_ref)
    result = {"rows": rows, "tol_runs": tol_rows, "references": refs, "ref_size": ref_size}
    result["summary"] = summary(rows, refs)
    if out is not None:
        write_outputs(Path(out), result)
    return result


def cheapest(rows: list[dict], tol: float) -> dict | None:
    """The first answer of a method with error <= tol: its DOFs and the time spent to get there."""
    ok = [r for r in rows if r["error"] <= tol]
    return None if not ok else {"dofs": ok[0]["dofs"], "time": ok[0]["time"], "error": ok[0]["error"]}


def answer(row: dict) -> bool:
    """Whether the method can answer with this mesh, an estimate in hand: the uniform ladder from its
    third mesh on, the adaptive rounds' finest meshes (M_1; the coarser two only estimate)."""
    return row["mesh"] >= 3 if row["method"] == "uniform" else row["mesh"] % 3 == 0


def summary(rows: list[dict], refs: dict | None = None) -> dict:
    """Per design and method, over the answers (``answer``): DOFs and time to reach 0.5, 0.1, 0.05,
    0.02 mm ("not measurable" below twice the reference's own scatter), and the smallest error."""
    out = {}
    for key in sorted({(r["design"], r["method"], r["degree"]) for r in rows}):
        mine = sorted((r for r in rows if (r["design"], r["method"], r["degree"]) == key and answer(r)),
                      key=lambda r: r["time"])
        floor = 2.0 * (refs or {}).get(key[0], {}).get("scatter", 0.0)
        out[f"{key[0]} {key[1]} P{key[2]}"] = {
            "reach": {f"{tol:g}": cheapest(mine, tol) if tol > floor else "not measurable"
                      for tol in (0.5, 0.1, 0.05, 0.02)},
            "best_error": min(r["error"] for r in mine),
            "effectivity": [r["estimate"] / r["error"] for r in mine if r["estimate"] and r["error"] > 0]}
    return out


def write_outputs(out: Path, result: dict) -> None:
    from skelfem.io.files import write_json
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "adaptive.json", result)
    plot(out / "adaptive.png", result)


def plot(path: Path, result: dict) -> None:
    """Per design: tip error against DOFs (top) and against wall time (bottom), four methods."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from skelfem.io.files import atomic_write

    rows = result["rows"]
    designs = list(dict.fromkeys(r["design"] for r in rows))
    fig, axes = plt.subplots(2, len(designs), figsize=(4.6 * len(designs), 7.6), dpi=110, squeeze=False)
    colour = {1: "#1f5fbf", 2: "#d9822b"}
    for j, name in enumerate(designs):
        for method, ls, mk in (("uniform", "--", "o"), ("adaptive", "-", "s")):
            for degree in (1, 2):
                mine = sorted((r for r in rows if (r["design"], r["method"], r["degree"]) == (name, method, degree)),
                              key=lambda r: r["time"])
                mine = [r for r in mine if answer(r)]              # the answers, each with its estimate
                if not mine:
                    continue
                for ax, key in ((axes[0, j], "dofs"), (axes[1, j], "time")):
                    ax.loglog([r[key] for r in mine], [max(r["error"], 1e-6) for r in mine], ls=ls, marker=mk,
                              color=colour[degree], ms=5, lw=1.2, label=f"{method} P{degree}")
        ref = result["references"][name]
        axes[0, j].set_title(f"{name}: reference P2 h = {result['ref_size']:g} ({ref['dofs']} DOFs)", fontsize=9)
        for ax in axes[:, j]:               # errors below twice the reference's own scatter are not measured
            low, high = ax.get_ylim()
            ax.axhspan(low, 2.0 * max(ref["scatter"], 1e-9), color="0.85", zorder=0,
                       label="not measurable (2x reference scatter)")
            ax.set_ylim(low, high)
        axes[0, j].set_xlabel("DOFs of the answer")
        axes[1, j].set_xlabel("wall time spent to get the answer [s]")
        for ax in axes[:, j]:
            ax.set_ylabel("tip error vs reference [mm]")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=7)
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--designs", nargs="+", default=list(DESIGNS))
    p.add_argument("--ref-size", type=float, default=0.3, help="reference mesh size (P2, graded as the ladder), mm")
    p.add_argument("--rounds", type=int, default=3, help="adaptive rounds (three meshes each)")
    p.add_argument("--levels", type=int, default=4, help="uniform P2 meshes (P1: one more)")
    p.add_argument("--degrees", nargs="+", type=int, default=[1, 2], choices=[1, 2])
    p.add_argument("--tols", nargs="*", type=float, default=list(TOLS), help="--tol runs (P2), both methods")
    p.add_argument("--tol-designs", nargs="*", default=list(TOL_DESIGNS), help="the designs of the --tol runs")
    p.add_argument("--out", type=Path, default=OUT)
    p.add_argument("--figures", type=Path, default=None, help="also copy adaptive.png here (README)")
    p.add_argument("--reuse-references", action="store_true",
                   help="read each design's reference back from OUT/DESIGN/reference.json if it is there")
    a = p.parse_args(argv)
    res = run(a.designs, a.ref_size, a.rounds, a.levels, tuple(a.degrees), a.out, a.reuse_references, tuple(a.tols),
              tuple(a.tol_designs))
    for key, s in res["summary"].items():
        reach = ", ".join(f"{tol} mm: " + ("-" if v is None else v if isinstance(v, str) else
                                           f"{v['dofs']} DOFs {v['time']:.1f} s")
                          for tol, v in s["reach"].items())
        eff = s["effectivity"]
        say(f"{key}: best {s['best_error']:.3g} mm; reaches {reach}"
            + (f"; effectivity {min(eff):.2f}..{max(eff):.2f}" if eff else ""))
    copy_figure(a.out / "adaptive.png", a.figures)
    say(f"outputs in {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
