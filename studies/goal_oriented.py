"""Goal-oriented against uniform refinement: DOFs to reach 1 % error in a tendon's tension.

    python studies/goal_oriented.py [--cases strip2d block3d] [--rounds 3] [--out studies/output/goal_oriented]

Two designs that are not bundled files, each a tendon ending in silicone (a
finite anchor: the tension's error sits at the anchor): ``strip2d`` (a
10 x 60 mm strip, P2) and ``block3d`` (a 10 x 30 x 10 mm block, P2). For each:

* a reference: P2 on a uniform mesh finer than any below (``REF``), and
  the one before it (their difference is the reference's own uncertainty);
* ``uniform``: P2 on uniform meshes h_0, h_0 / q, h_0 / q^2, ... (q = 2 in 2D,
  sqrt 2 in 3D), no grading anywhere;
* ``goal``: the adaptive rounds of ``--tol cables.flexor.tension=TOL
  --adaptive`` (skelfem.accuracy.adapt with the tension's adjoint weighting
  the indicators), driven past any tolerance for --rounds rounds, each round
  aiming at a quarter of the last estimate, started from uniform meshes
  (``graded=False``: without the a-priori zones that ``--tol`` puts at
  anchors, so that what is measured is what the indicators find).

Every mesh's tension error |T - T_ref| is recorded with its DOFs. The DOFs
to reach 1 % of the tension: for uniform refinement interpolated (log-log)
between the two meshes that bracket it (in uniform's favour: no such mesh
was made), for goal-oriented the smallest mesh the rounds made whose error
is within it; their ratio is reported.
run(cases) returns the rows; main(argv) prints them and writes goal_oriented.json.
"""
from __future__ import annotations

import argparse
import copy
import json
import math
import sys
from pathlib import Path


ROOT = Path(__file__).resolve().parents[1]
GOAL = 0.01                     # 1 % of the tension
REDUCTION = 0.25


def strip2d(size: float) -> dict:
    return {"format": 1, "name": "strip2d", "dim": 2, "thickness": 10.0,
            "mesh": {"size": size, "degree": 2},
            "materials": {"soft": {"E": 0.2, "nu": 0.45}},
            "body": {"outline": [[0, 0], [10, 0], [10, 60], [0, 60]], "material": "soft"},
            "cables": [{"name": "flexor", "kind": "tendon", "path": [[8, 0], [8, 40]], "stiffness": 5.0,
                        "contraction": 3.0}],
            "pins": [{"name": "base", "region": [[-1, -1], [11, 1e-6]], "kind": "fixed"}],
            "markers": {"tip": [5, 60]}}


def block3d(size: float) -> dict:
    return {"format": 1, "name": "block3d", "dim": 3, "mesh": {"size": size, "degree": 2},
            "materials": {"soft": {"E": 0.2, "nu": 0.45}},
            "body": {"solids": [{"box": {"min": [0, 0, 0], "max": [10, 30, 10]}}], "material": "soft"},
            "cables": [{"name": "flexor", "kind": "tendon", "path": [[8, 0, 5], [8, 20, 5]], "stiffness": 5.0,
                        "contraction": 1.5}],
            "pins": [{"name": "base", "region": [[-1, -1, -1], [11, 1e-6, 11]], "kind": "fixed"}],
            "markers": {"tip": [5, 30, 5]}}


CASES = {   # builder, first uniform size, uniform sizes' ratio, number of uniform meshes, reference sizes,
            # the goal-oriented rounds' design size (their first mesh is twice it, graded at the anchor)
    "strip2d": (strip2d, 4.0, 2.0, 4, (0.25, 0.125), 8.0),
    "block3d": (block3d, 4.0, math.sqrt(2.0), 4, (1.0, 0.8), 8.0),
}


def _tension(d: dict) -> tuple[float, int]:
    from skelfem.design.parse import parse_design
    from skelfem.session import Session
    with Session(parse_design(copy.deepcopy(d), d["name"])) as s:
        r = s.solve()
        if not r.converged:
            raise RuntimeError(f"{d['name']} h = {d['mesh']['size']}: {r.status}")
        return r.tension("flexor"), r.dofs


def uniform(build, h0: float, q: float, n: int, T_ref: float) -> list[dict]:
    rows = []
    for k in range(n):
        T, dofs = _tension(build(h0 / q ** k))
        rows.append({"method": "uniform", "mesh": k + 1, "dofs": dofs, "tension": T, "error": abs(T - T_ref)})
        print(f"    uniform h = {h0 / q ** k:.3g}: {dofs} DOFs, error {abs(T - T_ref):.3g} N", file=sys.stderr)
    return rows


def goal(build, h0: float, rounds: int, T_ref: float) -> list[dict]:
    from skelfem.accuracy.adapt import refine_adaptive
    from skelfem.accuracy.targets import Targets
    from skelfem.design.parse import parse_design
    from skelfem.estimate import observables_of
    from skelfem.session import Session
    rows = []

    def on_level(rec, session):
        T = observables_of(session.model)["cables.flexor.tension"]
        rows.append({"method": "goal", "round": rec["round"], "mesh": rec["mesh"], "dofs": int(rec["dofs"]),
                     "tension": T, "error": abs(T - T_ref)})
        print(f"    goal round {rec['round']} mesh {rec['mesh']}: {rec['dofs']} DOFs, error {abs(T - T_ref):.3g} N",
              file=sys.stderr)
    d = build(h0)                                  # the first round's coarsest mesh: 2x this size
    with Session(parse_design(d, d["name"])) as s:
        targets = Targets((("cables.flexor.tension", 1e-9),), int(d["dim"]))
        refine_adaptive(s, targets, 2, on_level=on_level, reduction=REDUCTION, max_rounds=rounds, graded=False)
    return rows


def dofs_to_reach(rows: list[dict], target: float) -> float | None:
    """DOFs where the error curve (in mesh order) first falls to `target`: log-log interpolation."""
    pts = sorted((r["dofs"], r["error"]) for r in rows)
    for (n0, e0), (n1, e1) in zip(pts, pts[1:]):
        if e0 <= target:
            return float(n0)
        if e1 <= target < e0 and e1 > 0:
            t = math.log(e0 / target) / math.log(e0 / e1)
            return float(math.exp(math.log(n0) + t * math.log(n1 / n0)))
    return float(pts[0][0]) if pts and pts[0][1] <= target else None


def smallest_meeting(rows: list[dict], target: float) -> float | None:
    """The DOFs of the smallest mesh whose error is at most `target` (None if none is)."""
    meeting = [r["dofs"] for r in rows if r["error"] <= target]
    return float(min(meeting)) if meeting else None


def run_case(name: str, rounds: int, known: dict | None = None) -> dict:
    """known: an earlier run's result of this case (its reference is reused when its sizes match)."""
    build, h0, q, n, refs, h_goal = CASES[name]
    ref = (known or {}).get("reference", {})
    if ref.get("sizes") == list(refs):
        T_ref, dofs_ref, unc = ref["tension"], ref["dofs"], ref["uncertainty"]
    else:
        T1, _ = _tension(build(refs[0]))
        T_ref, dofs_ref = _tension(build(refs[1]))
        unc = abs(T_ref - T1)
    target = GOAL * abs(T_ref)
    uni = uniform(build, h0, q, n, T_ref)
    go = goal(build, h_goal, rounds, T_ref)
    # uniform: interpolated between its meshes (in its favour); goal: the smallest mesh it made that meets it
    n_uni, n_goal = dofs_to_reach(uni, target), smallest_meeting(go, target)
    return {"case": name, "reference": {"tension": T_ref, "dofs": dofs_ref, "uncertainty": unc, "sizes": list(refs)},
            "target_error": target, "uniform": uni, "goal": go, "dofs_uniform": n_uni, "dofs_goal": n_goal,
            "ratio": None if not (n_uni and n_goal) else n_uni / n_goal}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=list(CASES), choices=list(CASES))
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "goal_oriented")
    args = ap.parse_args(argv)
    earlier = args.out / "goal_oriented.json"
    known = {c["case"]: c for c in json.loads(earlier.read_text())} if earlier.exists() else {}
    out = [c for c in known.values() if c["case"] not in args.cases]
    for name in args.cases:
        print(f"  {name}", file=sys.stderr, flush=True)
        res = run_case(name, args.rounds, known.get(name))
        out.append(res)
        ref = res["reference"]
        print(f"{name}: 1 % of {ref['tension']:.4g} N (reference +- {ref['uncertainty']:.2g}): "
              f"uniform {res['dofs_uniform']} DOFs, goal-oriented {res['dofs_goal']} DOFs, ratio {res['ratio']}")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "goal_oriented.json").write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
