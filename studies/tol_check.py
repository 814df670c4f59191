"""Does ``skelfem simulate --tol`` meet its tolerance, and does its estimate know how far off it is?

    python studies/tol_check.py [--designs ...] [--tols 0.5 0.1 0.05] [--ref-size 0.25] [--ref-size-3d 0.841]
                                [--reuse-references] [--adaptive]

For each design it solves a much finer reference (P2 at --ref-size, 3D
designs at --ref-size-3d, graded at finite anchors and clamped corners as
the --tol ladder's meshes are: skelfem.accuracy.ladder_zones) and each tolerance with the command itself
(``python -m skelfem simulate``, one process per run, as a user runs it),
then reports the final mesh, the estimate, the marker error against the
reference, the effectivity (estimate / error), and wall times (each run's
own ``timings.total`` from result.json: for --tol every mesh of its ladder,
not the interpreter's start-up).
With --adaptive each tolerance runs ``--tol TOL --adaptive`` instead (rows
in tol_check_adaptive.csv). run(**params) returns the rows; main(argv)
prints them and writes tol_check.csv.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from skelfem.io.files import say, write_csv

ROOT = Path(__file__).resolve().parents[1]
DESIGNS = ("finger_bones", "thumb", "finger_tapered_fillet", "post3d", "finger_soft")
# bundled; a tendon ending in silicone; a tapered body, filleted bones; 3D; bundled, no bones (an anchored bend)


def _run(cmd: list, what: str, out: Path, failed_ok: bool = False) -> tuple[dict, float]:
    """Run cmd in its own process (one thread for BLAS); (out's result.json, the run's total time in s).
    failed_ok: a failed solve (exit 2, result.json with ``converged: false``) is returned, not raised."""
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    res = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if res.returncode != 0 and not (failed_ok and res.returncode == 2 and (out / "result.json").exists()):
        raise RuntimeError(f"{what}: exit {res.returncode}: {res.stderr.strip()[-2000:]}")
    result = json.loads((out / "result.json").read_text())
    return result, float(result["timings"]["total"])


def _simulate(design: str, out: Path, *extra: str) -> tuple[dict, float]:
    """`skelfem simulate` in its own process; (result.json, the run's total time in s)."""
    cmd = [sys.executable, "-m", "skelfem", "simulate", str(ROOT / "geometry" / f"{design}.toml"), "--out", str(out),
           "-q", "--no-picture", *extra]
    return _run(cmd, f"{design} {extra}", out, failed_ok=True)


def _markers(res: dict) -> np.ndarray:
    return np.array([m["position"] for m in res["markers"].values()])


def _dim(design: str) -> int:
    import tomllib
    return int(tomllib.loads((ROOT / "geometry" / f"{design}.toml").read_text()).get("dim", 2))


def _reference(design: str, out: Path, h_ref: float, reuse: bool) -> tuple[dict, float]:
    """The P2 reference at h_ref: solved, or read back from an earlier run's folder (reuse)."""
    folder = out / design / "reference"
    if reuse and (folder / "result.json").exists():
        ref = json.loads((folder / "result.json").read_text())
        if ref.get("degree") == 2 and ref["converged"] and _uncertainty(ref) is not None:   # by solve_reference
            say(f"{design}: reference read back from {folder}", flush=True)
            return ref, float(ref["timings"]["total"])
    return _run([sys.executable, __file__, "--reference", design, str(h_ref), str(folder)], f"{design} reference",
                folder)


def _uncertainty(ref: dict) -> float | None:
    """The reference's own error, as far as it is known: its twin's scatter (2D) or its estimate (3D)."""
    r = ref.get("reference", {})
    return r.get("scatter", r.get("estimate"))


def _converged(res, design: str, h: float):
    """res, or a RuntimeError saying which reference solve failed and why."""
    if not res.converged:
        raise RuntimeError(f"{design}: the reference solve at h = {h:g} mm failed ({res.status})")
    return res


def solve_reference(design: str, h_ref: float, folder: Path) -> None:
    """P2 at h_ref, graded near finite anchors and clamped corners as the --tol ladder's meshes are
    (accuracy.ladder_zones of its first level, scaled to h_ref): result.json in folder (its own process,
    run by _reference).

    3D designs: a mesh much finer than the ladder's last does not fit this machine, so the reference
    is extrapolated: P2 at 2 h_ref, sqrt 2 h_ref and h_ref (warm), and Richardson's extrapolation of
    the markers with the rate observed on those three (skelfem.accuracy, sizes measured by DOFs);
    ``reference.estimate`` is the finest mesh's own estimated error, the extrapolation's size.
    2D designs: a twin at accuracy.TWIN h_ref is solved too; ``reference.scatter`` = max |x_twin - x_ref|
    is the reference's own mesh-to-mesh scatter, below which no error against it is measured.
    """
    import time

    from skelfem import Session
    from skelfem.design import resources
    from skelfem.accuracy.ladder import TWIN, first_level, ladder_zones, next_level
    from skelfem.design import load_design

    t0 = time.perf_counter()
    d = load_design(ROOT / "geometry" / f"{design}.toml")
    h0 = float(first_level(d).mesh.size)
    resources.FORCED = True                 # a reference may be larger than a user's run (as --force)
    sizes = [2.0 * h_ref, 2.0 ** 0.5 * h_ref, h_ref] if d.dim == 3 else [h_ref]
    levels = []
    with Session(d, ["mesh.degree=2", f"mesh.size={sizes[0]}"]) as s:
        zones = ladder_zones(s.model, d, h0)
        for h in sizes:
            s.edit(load_design(ROOT / "geometry" / f"{design}.toml", ["mesh.degree=2", f"mesh.size={h}"]),
                   size=None if zones is None else zones.scaled(h / h0))
            res = _converged(s.solve(), design, h)
            levels.append(next_level(levels, h, res, 0.0))
        result = res.to_dict()
        if d.dim == 2:
            h = TWIN * h_ref
            s.edit(load_design(ROOT / "geometry" / f"{design}.toml", ["mesh.degree=2", f"mesh.size={h}"]),
                   size=None if zones is None else zones.scaled(h / h0))
            twin = np.array([m["position"] for m in _converged(s.solve(), design, h).markers.values()])
    result["timings"]["total"] = time.perf_counter() - t0
    result["reference"] = {"size": h_ref, "graded": zones is not None}
    if d.dim == 2:
        result["reference"]["scatter"] = float(np.linalg.norm(twin - levels[-1].markers, axis=1).max())
    if len(levels) == 3:
        a, b = levels[-2], levels[-1]
        rho = a.h / b.h
        extrapolated = b.markers + (b.markers - a.markers) / (rho ** b.rate - 1.0)
        for name, x in zip(result["markers"], extrapolated):
            marker = result["markers"][name]
            marker["position"] = x.tolist()
            marker["displacement"] = (x - np.asarray(marker["reference"], dtype=float)).tolist()
        result["reference"].update({"extrapolated_from": [lv.dofs for lv in levels], "rate": b.rate,
                                    "estimate": b.estimate, "finest": b.markers.tolist()})
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "result.json").write_text(json.dumps(result))


def run(designs=DESIGNS, tols=(0.5, 0.1, 0.05), ref_size: float = 0.25, ref_size_3d: float = 0.841,
        out: Path | None = None, reuse: bool = False, adaptive: bool = False) -> list[dict]:
    """For each design a P2 reference (ref_size, or ref_size_3d for 3D designs) and one --tol run per tol
    (``--tol TOL --adaptive`` with adaptive)."""
    out = Path(out or ROOT / "studies" / "output" / "tol_check")
    rows = []
    for design in designs:
        h_ref = ref_size_3d if _dim(design) == 3 else ref_size
        ref, t_ref = _reference(design, out, h_ref, reuse)
        u_ref = float(_uncertainty(ref))
        say(f"{design}: reference P2 ({ref['dofs']} DOFs): {t_ref:.1f} s, its own error about {u_ref:.2g} mm",
            flush=True)
        for tol in tols:
            res, t = _simulate(design, out / design / f"tol_{tol:g}{'_adaptive' * adaptive}", "--tol", str(tol),
                               *(["--adaptive"] if adaptive else []))
            a = res["accuracy"]
            failed = None if res["converged"] else a.get("stop", res["status"])   # no equilibrium to compare
            err = float(np.linalg.norm(_markers(res) - _markers(ref), axis=1).max()) if not failed else float("nan")
            est = float("nan") if a.get("estimated_error") is None else a["estimated_error"]
            rows.append({"design": design, "tol": tol, "degree": a.get("degree", 2), "size": a.get("size"),
                         "estimated_error": est, "error_vs_reference": err,
                         "effectivity": float("nan") if failed else est / err if err > 0 else float("inf"),
                         "reported_met": bool(a["met"]), "met": err <= tol, "meshes": len(a["levels"]),
                         "reference_uncertainty": u_ref, "measurable": err > 2.0 * u_ref,
                         "time": t, "reference_time": t_ref, "dofs": res["dofs"], "reference_dofs": ref["dofs"],
                         "bones": None if not a.get("bones") else "rigid" if a["bones"]["rigid"] else "elastic",
                         "bones_difference": (a.get("bones") or {}).get("difference"),
                         "failed": failed, "method": "adaptive" if adaptive else "uniform"})
            r = rows[-1]
            if failed:
                say(f"  tol {tol:g} mm{' adaptive' * adaptive}: FAILED after {r['meshes']} meshes: {failed} "
                    f"({t:.1f} s)", flush=True)
                continue
            where = (f"h={a['min_size']:.3g}..{a['max_size']:.3g}" if adaptive and "min_size" in a
                     else f"h={r['size']:g}")
            say(f"  tol {tol:g} mm{' adaptive' * adaptive}: P{r['degree']} {where} "
                f"({r['dofs']} DOFs, {r['meshes']} meshes), "
                f"estimated {est:.3g} mm ({'met' if r['reported_met'] else 'NOT met'}), actual {err:.3g} mm "
                f"(reference +- {u_ref:.2g}), effectivity {r['effectivity']:.2f}"
                f"{'' if r['measurable'] else ' (error below twice the reference uncertainty)'}, "
                f"{r['bones'] or 'no'} bones, "
                f"{t:.1f} s ({t / t_ref:.2f} of the reference)", flush=True)
    return rows


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["--reference"]:
        solve_reference(argv[1], float(argv[2]), Path(argv[3]))
        return 0
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--designs", nargs="+", default=list(DESIGNS))
    p.add_argument("--tols", nargs="+", type=float, default=[0.5, 0.1, 0.05])
    p.add_argument("--ref-size", type=float, default=0.25, help="reference mesh size of 2D designs (P2)")
    p.add_argument("--ref-size-3d", type=float, default=0.841, help="reference mesh size of 3D designs (P2)")
    p.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "tol_check")
    p.add_argument("--reuse-references", action="store_true",
                   help="read each design's reference back from OUT/DESIGN/reference if it is there")
    p.add_argument("--adaptive", action="store_true", help="run --tol --adaptive (tol_check_adaptive.csv)")
    a = p.parse_args(argv)
    rows = run(a.designs, a.tols, a.ref_size, a.ref_size_3d, a.out, a.reuse_references, a.adaptive)
    a.out.mkdir(parents=True, exist_ok=True)
    table = a.out / f"tol_check{'_adaptive' * a.adaptive}.csv"
    write_csv(table, list(rows[0]), rows)
    eff = [r["effectivity"] for r in rows if not r["failed"]] or [float("nan")]
    failed = sum(bool(r["failed"]) for r in rows)
    say(f"{sum(r['met'] for r in rows)}/{len(rows)} tolerances met ({sum(r['reported_met'] for r in rows)} "
        f"reported met{f', {failed} failed' if failed else ''}); effectivity {min(eff):.2f} to {max(eff):.2f}; "
        f"table in {table}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
