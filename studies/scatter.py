"""How much does an answer scatter from mesh to mesh at (nearly) one size?

    python studies/scatter.py [--design geometry/finger_bones.toml] [--sizes 0.80 0.81 ... 0.88]
                              [--set KEY=VALUE ...] [--out studies/output/scatter]

The design is solved with P2 on graded meshes of the given sizes, graded at
its finite anchors and clamped corners as the --tol ladder grades them (skelfem.accuracy:
ladder_zones of the ladder's first level, scaled to each size), each solve
warm-started from the last. Sizes this close give meshes of nearly one
resolution but a different triangulation each, so the spread of the markers
is the scatter that Richardson's e = C h^r cannot see and the --tol twin
measures. run(**params) returns the rows and the standard deviation and range
of every marker coordinate; main(argv) prints them and writes scatter.json.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SIZES = tuple(round(0.80 + 0.01 * k, 2) for k in range(9))


def run(design=ROOT / "geometry" / "finger_bones.toml", sizes=SIZES, sets=()) -> dict:
    from skelfem import Session
    from skelfem.accuracy.ladder import at_size, first_level, ladder_zones
    from skelfem.design import load_design
    d = load_design(design, list(sets))
    h0 = float(first_level(d).mesh.size)
    rows = []
    with Session(at_size(d, h0)) as s:
        zones = ladder_zones(s.model, d, h0)
        for h in sizes:
            s.edit(at_size(d, h), size=None if zones is None else zones.scaled(h / h0))
            r = s.solve()
            if not r.converged:
                raise RuntimeError(f"h = {h}: the solve failed ({r.status})")
            rows.append({"size": float(h), "dofs": int(r.dofs), "iterations": int(r.newton_iterations),
                         "markers": {k: list(map(float, m["position"])) for k, m in r.markers.items()}})
    x = np.array([[p for m in row["markers"].values() for p in m] for row in rows])   # (sizes, markers x dim)
    return {"design": Path(design).name, "sets": list(sets), "rows": rows,
            "std": x.std(axis=0).tolist(), "range": np.ptp(x, axis=0).tolist()}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--design", type=Path, default=ROOT / "geometry" / "finger_bones.toml")
    p.add_argument("--sizes", nargs="+", type=float, default=list(SIZES))
    p.add_argument("--set", dest="sets", action="append", default=[])
    p.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "scatter")
    a = p.parse_args(argv)
    res = run(a.design, a.sizes, a.sets)
    for row in res["rows"]:
        print(f"h = {row['size']:.3f} mm, {row['dofs']} DOFs, {row['iterations']} iterations: "
              + ", ".join(f"{k} {np.round(v, 5).tolist()}" for k, v in row["markers"].items()))
    print(f"standard deviation {np.round(res['std'], 5).tolist()} mm, range {np.round(res['range'], 5).tolist()} mm")
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "scatter.json").write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
