"""A 2D reference graded at the bones' corners, and its twin: how much of a reference's scatter the corners make.

    python studies/corner_reference.py [--design geometry/finger_bones.toml] [--sizes 0.25 0.2375]
                                       [--fraction 0.25] [--radius 1.0] [--answer RESULT_JSON ...]
                                       [--out studies/output/corner_reference]

P2 on each size h, graded at finite anchors and clamped corners as the --tol ladder grades
(skelfem.accuracy.ladder_zones of its first level, scaled to h) and at every
corner of a bone outline that turns by more than MIN_TURN degrees: size
fraction x h within ``radius`` mm of the corner (Gmsh Ball fields, growing
0.3 mm per mm beyond). Silicone squeezed against a bone's corner has a
strain singularity that every mesh samples differently (the README's
"scatter"); grading there makes the fine meshes agree better. Reported:
each solve's DOFs, Newton iterations and markers, the scatter
max |x_1 - x_2| between the first two sizes (the reference's own
uncertainty, as studies/tol_check.py measures it), and for each --answer
(a result.json, e.g. of a --tol run) its marker error against the first
size, the effectivity of its ``accuracy.estimated_error`` and whether the
error is measurable (more than twice the scatter). run(**params) returns
the numbers; main(argv) prints them and writes corner_reference.json.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
MIN_TURN = 20.0          # degrees: a vertex of a bone outline turning more than this is a corner


def corners(design, min_turn: float = MIN_TURN) -> np.ndarray:
    """(n, 2) the vertices of the bone outlines whose outline turns by more than min_turn degrees."""
    out = []
    for bone in design.bones:
        P = np.asarray(bone.outline, float)
        u = P - np.roll(P, 1, axis=0)                       # edge into each vertex
        v = np.roll(P, -1, axis=0) - P                      # edge out of it
        cos = np.einsum("ij,ij->i", u, v) / (np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1))
        out.append(P[np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))) > min_turn])
    return np.concatenate(out) if out else np.zeros((0, 2))


def zones(design, model, fraction: float, radius: float):
    """The ZoneField of the ladder's first level (its anchor and clamped-corner zones) plus a zone at every
    bone corner."""
    from skelfem.accuracy.ladder import first_level, ladder_zones
    from skelfem.mesh.geometry import ZoneField
    h0 = float(first_level(design).mesh.size)
    C = corners(design)
    bones = ZoneField.around(C, np.full(len(C), radius), np.full(len(C), fraction * h0), h0)
    return bones.merged(ladder_zones(model, design, h0)), h0


def _markers(result: dict) -> np.ndarray:
    return np.array([m["position"] for m in result["markers"].values()], dtype=float)


def run(design=ROOT / "geometry" / "finger_bones.toml", sizes=(0.25, 0.2375), fraction: float = 0.25,
        radius: float = 1.0, answers=()) -> dict:
    from skelfem import Session
    from skelfem.design import resources
    from skelfem.design import load_design
    d = load_design(design)
    if d.dim != 2:
        raise ValueError("corner grading is for 2D designs")
    resources.FORCED = True                 # a reference may be larger than a user's run (as --force)
    rows = []
    with Session(d, ["mesh.degree=2", f"mesh.size={sizes[0]}"]) as s:
        field, h0 = zones(d, s.model, fraction, radius)
        for h in sizes:
            t = time.perf_counter()
            s.edit(load_design(design, ["mesh.degree=2", f"mesh.size={h}"]), size=field.scaled(h / h0))
            r = s.solve()
            if not r.converged:
                raise RuntimeError(f"h = {h}: the solve failed ({r.status})")
            rows.append({"size": float(h), "dofs": int(r.dofs), "iterations": int(r.newton_iterations),
                         "seconds": time.perf_counter() - t,
                         "markers": {k: list(map(float, m["position"])) for k, m in r.markers.items()}})
    x = [np.array(list(row["markers"].values()), dtype=float) for row in rows]
    scatter = float(np.max(np.linalg.norm(x[1] - x[0], axis=1))) if len(x) > 1 else None
    checked = []
    for path in answers:
        res = json.loads(Path(path).read_text())
        err = float(np.max(np.linalg.norm(_markers(res) - x[0], axis=1)))
        est = (res.get("accuracy") or {}).get("estimated_error")
        checked.append({"answer": str(path), "error": err, "estimate": est,
                        "effectivity": est / err if est is not None and err > 0 else None,
                        "measurable": scatter is not None and err > 2.0 * scatter})
    return {"design": Path(design).name, "fraction": fraction, "radius": radius, "corners": len(corners(d)),
            "rows": rows, "scatter": scatter, "answers": checked}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--design", type=Path, default=ROOT / "geometry" / "finger_bones.toml")
    p.add_argument("--sizes", nargs="+", type=float, default=[0.25, 0.2375])
    p.add_argument("--fraction", type=float, default=0.25)
    p.add_argument("--radius", type=float, default=1.0)
    p.add_argument("--answer", dest="answers", action="append", default=[], type=Path)
    p.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "corner_reference")
    a = p.parse_args(argv)
    res = run(a.design, a.sizes, a.fraction, a.radius, a.answers)
    print(f"{res['design']}: {res['corners']} bone corners graded to {a.fraction:g} h within {a.radius:g} mm")
    for row in res["rows"]:
        where = ", ".join(f"{k} {np.round(v, 5).tolist()}" for k, v in row["markers"].items())
        print(f"  h = {row['size']:g} mm: {row['dofs']} DOFs, {row['iterations']} iterations, "
              f"{row['seconds']:.0f} s: {where}")
    if res["scatter"] is not None:
        print(f"  scatter between the first two: {res['scatter']:.3g} mm")
    for c in res["answers"]:
        eff = "-" if c["effectivity"] is None else f"{c['effectivity']:.2f}"
        print(f"  {c['answer']}: error {c['error']:.3g} mm, estimate {c['estimate']}, effectivity {eff}"
              f"{'' if c['measurable'] else ' (not measurable: within twice the scatter)'}")
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "corner_reference.json").write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
