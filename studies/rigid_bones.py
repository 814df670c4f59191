"""Rigid bones against stiff elastic bones: accuracy (the 1/E_bone limit), unknowns and time.

    python studies/rigid_bones.py [--design geometry/finger.toml] [--size 0.45] [--exponents 0 1 2 3]
                                  [--repeats 3] [--out studies/output/rigid_bones]

The design is solved once with every bone ``rigid = true`` and once per
E_bone = E0 x 10^k (E0: each bone material's own E) with elastic bones, on
the same mesh. Reported: the marker distance |x_elastic - x_rigid| per k and
the slope of its log against log E_bone (-1 when the elastic bones' own
strain is what separates them), the Newton unknowns (DOFs; with rigid bones
the free DOFs plus 3 per bone in 2D, 6 in 3D), the Newton matrix's nonzeros,
the cells the elastic form integrates over, Newton iterations and the
median wall time of a cold solve (from rest; mesh and compilation excluded)
over ``repeats``, that time per iteration, and the median time (and
iterations) of warm re-solves after each tendon's contraction changes by 5 %
(the editor's live edit). run(**params) returns the numbers; main(argv) prints them
and writes rigid_bones.json.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
FINGER = ROOT / "geometry" / "finger.toml"


def _warm(s, repeats: int) -> tuple[list, list]:
    """Times and Newton iterations of re-solves after each tendon's contraction changes by 5 %
    (up, then back down: the editor's live edit), warm-started from the last solution."""
    live = {k: v for k, v in s.model.parameters().items() if k.endswith(".contraction") and v}
    times, iterations = [], []
    for i in range(2 * max(repeats, 1)):
        s.set({k: v * (1.05 if i % 2 == 0 else 1.0) for k, v in live.items()})
        t0 = time.perf_counter()
        r = s.solve()
        times.append(time.perf_counter() - t0)
        iterations.append(int(r.newton_iterations))
        if not r.converged:
            raise RuntimeError(f"a warm re-solve failed ({r.status})")
    return times, iterations


def _solve(design, overrides, repeats: int) -> dict:
    from skelfem import Session
    from skelfem.design import load_design
    with Session(load_design(design, overrides)) as s:
        times, r = [], None
        for _ in range(max(repeats, 1)):
            s.solved = False                                   # cold: from rest every time
            t0 = time.perf_counter()
            r = s.solve()
            times.append(time.perf_counter() - t0)
        warm, warm_its = _warm(s, repeats)
        model = s.model
        cells = model.mesh.topology.index_map(model.mesh.topology.dim).size_local
        rigid_cells = sum(len(model.tm.cell_tags.find(model.tm.tags[f"bone:{b.name}"]))
                          for b in s.design.bones if b.rigid)
        return {"converged": bool(r.converged), "iterations": int(r.newton_iterations),
                "markers": {k: v["position"] for k, v in r.markers.items()},
                "dofs": int(r.dofs),
                "unknowns": int(r.dofs - model.slaved.sum() + sum(b.m for b in model.rigid)),
                "nnz": int(s.solver.A.getInfo()["nz_used"]),
                "assembled_cells": int(cells - rigid_cells),
                "time": float(np.median(times)), "times": times,
                "per_iteration": float(np.median(times)) / max(int(r.newton_iterations), 1),
                "warm_time": float(np.median(warm)), "warm_iterations": warm_its,
                "residual_tail": [float(x) for x in r.residual_history[-1][-4:]],
                "bones": r.to_dict().get("bones")}


def run(design=FINGER, size: float | None = None, exponents=(0, 1, 2, 3), repeats: int = 1) -> dict:
    from skelfem.design import load_design
    d = load_design(design)
    base = [f"mesh.size={size}"] if size else []
    bones = [b.name for b in d.bones]
    rigid = _solve(design, base + [f"bones.{b}.rigid=true" for b in bones], repeats)
    out = {"design": str(design), "size": size or d.mesh.size, "rigid": rigid, "elastic": []}
    for k in exponents:
        sets = [f"materials.{m}.E={d.materials[m].E * 10.0 ** k!r}" for m in {b.material for b in d.bones}]
        e = _solve(design, base + sets, repeats)
        e["exponent"] = k
        e["E_bone"] = [d.materials[m].E * 10.0 ** k for m in sorted({b.material for b in d.bones})]
        e["marker_difference"] = max(float(np.linalg.norm(np.subtract(e["markers"][name], pos)))
                                     for name, pos in rigid["markers"].items())
        out["elastic"].append(e)
    diffs = [e["marker_difference"] for e in out["elastic"]]
    if len(diffs) >= 2:
        out["slope"] = float(np.polyfit(np.log(10.0) * np.array(exponents, float), np.log(diffs), 1)[0])
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--design", type=Path, default=FINGER)
    p.add_argument("--size", type=float, default=None)
    p.add_argument("--exponents", nargs="+", type=int, default=[0, 1, 2, 3])
    p.add_argument("--repeats", type=int, default=1)
    p.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "rigid_bones")
    a = p.parse_args(argv)
    r = run(a.design, a.size, a.exponents, a.repeats)
    rg = r["rigid"]
    print(f"{r['design']} h = {r['size']}: rigid bones: {rg['unknowns']} unknowns ({rg['dofs']} DOFs), "
          f"nnz {rg['nnz']}, {rg['assembled_cells']} cells assembled, {rg['iterations']} iterations, "
          f"{rg['time']:.3f} s ({1e3 * rg['per_iteration']:.1f} ms per iteration), warm re-solve "
          f"{rg['warm_time']:.3f} s ({rg['warm_iterations']} iterations); residual tail {rg['residual_tail']}")
    for e in r["elastic"]:
        print(f"  elastic E_bone = {e['E_bone']}: {e['unknowns']} unknowns, nnz {e['nnz']}, "
              f"{e['assembled_cells']} cells, {e['iterations']} iterations, {e['time']:.3f} s "
              f"({1e3 * e['per_iteration']:.1f} ms per iteration), warm re-solve {e['warm_time']:.3f} s "
              f"({e['warm_iterations']} iterations), "
              f"marker difference {e['marker_difference']:.3e} mm")
    if "slope" in r:
        print(f"  slope of log(difference) against log(E_bone): {r['slope']:.3f}")
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "rigid_bones.json").write_text(json.dumps(r, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
