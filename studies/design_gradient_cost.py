"""What an exact design gradient costs against one Newton solve, with 4 and with 40 design variables.

On a design (default: geometry/finger.toml) a DesignGradient (skelfem.analysis.design_gradient) is
set up over the first n of a list of handles (bone poses and vertices, the flexor's end, the body's
tip vertices, the materials' E), the equilibrium solved, and the gradient of a marker-target
objective taken `repeats` times; reported as medians:

* solve_cold: the design solved from rest (a fresh Session's first solve, the mesh and forms built);
* solve_warm: the design re-solved after a 0.05 mm step of the first handle (what an optimiser pays
  per iteration);
* gradient: the adjoint gradient (the Hessian assembled and factorised at the converged state, one
  back-substitution, the shape derivative's vectors, the cables traced, the morph's transpose),
  and its parts (factorise, adjoint_solve, assemble).

The gradient's first call compiles the shape-derivative forms (FFCx, cached on disk after it): that
call is reported apart (first_gradient) and left out of the medians.
`python studies/design_gradient_cost.py [--size 1.0] [--out DIR]`.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

FIRST = ["bones.middle.angle", "bones.distal.offset.x", "cables.flexor.path[2].x", "materials.ecoflex.E"]
MORE = ([f"bones.{b}.{k}" for b in ("proximal", "middle", "distal") for k in ("offset.x", "offset.y")]
        + ["bones.proximal.angle", "bones.distal.angle", "materials.pla.E", "cables.flexor.path[2].y"]
        + [f"bones.{b}.outline[{i}].{a}" for b, n in (("proximal", 4), ("middle", 4)) for i in range(n) for a in "xy"]
        + [f"body.outline[{i}].{a}" for i in (3, 4, 5, 6, 7) for a in "xy"]
        + ["bones.distal.outline[0].x", "bones.distal.outline[1].x", "bones.distal.outline[2].y"])
HANDLES = tuple(dict.fromkeys(FIRST + MORE))      # 42 distinct variables; the first n are used


def run(design="geometry/finger.toml", size: float | None = None, counts=(4, 40), repeats: int = 5,
        out=None) -> dict:
    from skelfem import Session
    from skelfem.analysis.design_gradient import DesignGradient, MarkerTarget

    overrides = [f"mesh.size={size}"] if size else []
    rows = []
    for n in counts:
        keys = list(HANDLES[:n])
        t0 = time.perf_counter()
        session = Session(design, overrides)
        t1 = time.perf_counter()
        first = session.solve()
        cold = time.perf_counter() - t1
        dg = DesignGradient(session, keys)
        dg.solve()
        tip = first.markers["tip"]["position"] if "tip" in first.markers else None
        objective = MarkerTarget("tip", tuple(np.asarray(tip) + [-5.0, -5.0]))
        t2 = time.perf_counter()
        dg.gradient(objective)
        first_gradient = time.perf_counter() - t2
        warm, grads, parts = [], [], []
        step = np.zeros(n)
        step[0] = 0.05
        for k in range(repeats):
            t3 = time.perf_counter()
            result = dg.solve(step * (k % 2 == 0))
            warm.append((time.perf_counter() - t3, result.newton_iterations))
            t4 = time.perf_counter()
            dg.gradient(objective)
            grads.append(time.perf_counter() - t4)
            parts.append(dict(dg.timings))
        dofs = session.dofs
        session.close()
        row = {"variables": n, "dofs": dofs,
               "setup_s": t1 - t0, "solve_cold_s": cold, "newton_iterations_cold": first.newton_iterations,
               "solve_warm_s": float(np.median([w[0] for w in warm])),
               "newton_iterations_warm": int(np.median([w[1] for w in warm])),
               "first_gradient_s": first_gradient, "gradient_s": float(np.median(grads)),
               "factorise_s": float(np.median([p["factorise"] for p in parts])),
               "adjoint_solve_s": float(np.median([p["adjoint_solve"] for p in parts])),
               "assemble_s": float(np.median([p["assemble"] for p in parts]))}
        row["gradient_over_cold_solve"] = row["gradient_s"] / row["solve_cold_s"]
        row["gradient_over_warm_solve"] = row["gradient_s"] / row["solve_warm_s"]
        rows.append(row)
    res = {"design": str(design), "size": size, "repeats": repeats, "rows": rows}
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "design_gradient_cost.json").write_text(json.dumps(res, indent=2))
    return res


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--design", default="geometry/finger.toml")
    ap.add_argument("--size", type=float, default=None)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", default="studies/output/design_gradient_cost")
    args = ap.parse_args(argv)
    res = run(args.design, args.size, repeats=args.repeats, out=args.out)
    print(f"{'variables':>9} {'cold solve':>10} {'warm solve':>10} {'gradient':>9} {'grad/cold':>9} "
          f"{'grad/warm':>9}  (s; gradient = factorise + adjoint solve + assemble)")
    for r in res["rows"]:
        print(f"{r['variables']:>9} {r['solve_cold_s']:>10.3f} {r['solve_warm_s']:>10.3f} {r['gradient_s']:>9.3f} "
              f"{r['gradient_over_cold_solve']:>9.2f} {r['gradient_over_warm_solve']:>9.2f}  "
              f"({r['factorise_s']:.3f} + {r['adjoint_solve_s']:.3f} + {r['assemble_s']:.3f})")


if __name__ == "__main__":
    main()
