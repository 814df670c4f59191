"""How fast a live Session answers: a warm re-solve after a parameter change, and an edit.

On a design (default: the demo, geometry/finger.toml) a Session solves once,
then, repeated `repeats` times and reported as medians:

* set: a tendon's contraction changes by `delta` mm (a live parameter: no
  re-mesh, no recompile, no new matrix) and the equilibrium is re-solved
  warm from the last one;
* edit: one vertex of the first bone moves by `delta` mm in x (re-mesh,
  new model, the last solution carried over as the start) and is re-solved;
* moved nodes: the same edit with ``morph=True`` (the editor's drafts: the
  mesh's nodes follow the bone, no meshing);
* same mesh: the flexor's sketch end moves by `delta` mm in y (outlines
  unchanged: the model is rebuilt on the same mesh);
* cold: the same bone edit solved from rest, for comparison.

Prints and returns Newton iterations and wall times; `python studies/session_speed.py`.
"""
from __future__ import annotations

import argparse
import copy
import json
import time

import numpy as np


def _tendon(design) -> str:
    return next(c.name for c in design.cables if c.kind == "tendon")


def run(design="geometry/finger.toml", delta: float = 1.0, repeats: int = 5, overrides=()) -> dict:
    from skelfem import Session

    s = Session(design, overrides)
    first = s.solve()
    tendon = _tendon(s.design)
    key = f"cables.{tendon}.contraction"
    u0 = s.design.cable(tendon).contraction
    sets, edits, colds = [], [], []
    raw = copy.deepcopy(s.design.raw)
    for k in range(repeats):
        t0 = time.perf_counter()
        s.set({key: u0 + delta * (1 if k % 2 == 0 else 0)})
        r = s.solve()
        sets.append((time.perf_counter() - t0, r.newton_iterations, r.converged))
    s.set({key: u0})
    s.solve()
    for k in range(repeats):
        moved = copy.deepcopy(raw)
        moved["bones"][0]["outline"][0][0] += delta * (1 if k % 2 == 0 else 0)
        t0 = time.perf_counter()
        s.edit(moved)
        r = s.solve()
        edits.append((time.perf_counter() - t0, r.newton_iterations, r.converged))
    morphs, kept = [], []
    for k in range(repeats):
        d = copy.deepcopy(raw)
        d["bones"][0]["outline"][0][0] += delta * (1 if k % 2 == 0 else 0)
        t0 = time.perf_counter()
        how = s.edit(d, morph=True)
        r = s.solve()
        morphs.append((time.perf_counter() - t0, r.newton_iterations, r.converged and how != "re-meshed"))
    s.edit(raw)
    s.solve()
    cable = next(i for i, c in enumerate(raw["cables"]) if c["name"] == tendon)
    for k in range(repeats):
        d = copy.deepcopy(raw)
        d["cables"][cable]["path"][-1][1] += delta * (1 if k % 2 == 0 else 0)
        t0 = time.perf_counter()
        how = s.edit(d)
        r = s.solve()
        kept.append((time.perf_counter() - t0, r.newton_iterations, r.converged and how == "same mesh"))
    cold = Session(raw)
    for k in range(min(repeats, 3)):
        moved = copy.deepcopy(raw)
        moved["bones"][0]["outline"][0][0] += delta
        t0 = time.perf_counter()
        cold.edit(moved)
        cold.solved = False
        r = cold.solve()
        colds.append((time.perf_counter() - t0, r.newton_iterations, r.converged))
    cold.close()
    s.close()

    def summary(rows):
        return {"time_median": float(np.median([t for t, _, _ in rows])),
                "newton_iterations_median": float(np.median([n for _, n, _ in rows])),
                "newton_iterations_max": int(max(n for _, n, _ in rows)),
                "all_converged": bool(all(c for _, _, c in rows))}
    return {"design": str(design), "dofs": first.dofs, "delta": delta, "repeats": repeats,
            "first_solve": {"newton_iterations": first.newton_iterations, "time": first.timings["total"]},
            "set_contraction": summary(sets), "edit_bone_vertex": summary(edits),
            "edit_bone_vertex_moved_nodes": summary(morphs), "edit_cable_path_same_mesh": summary(kept),
            "edit_bone_vertex_cold": summary(colds)}


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("design", nargs="?", default="geometry/finger.toml")
    p.add_argument("--delta", type=float, default=1.0)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--set", dest="overrides", action="append", default=[])
    a = p.parse_args(argv)
    out = run(a.design, a.delta, a.repeats, a.overrides)
    print(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
