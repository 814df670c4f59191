"""Design optimisation with exact gradients and fabrication constraints against a gradient-free search.

The task (default: studies/finger_reach_task.toml on geometry/finger.toml: 11 variables, two
contractions, four fabrication clearances) is minimised twice from the hand-made design:

* with exact design gradients: SLSQP with the constraints' exact Jacobian
  (skelfem.analysis.design_optimize, as ``skelfem optimize-design`` runs it);
* without: SciPy's COBYLA (gradient-free, with the same constraints and the bounds as constraints, the
  same scaling), at most `max_gradient_free` evaluations.

Reported: the objective at the start and at each optimum, the improvement, the evaluations and solves
each method needed (a solve is one equilibrium of one contraction; an evaluation solves every
contraction), the solves COBYLA needed to first reach the gradient run's optimum at a design that
meets the constraints (None: never within its budget), the constraints' margins at the optimum, the
optimum meshed anew and solved fresh with its error estimate, and whether ``skelfem fabricate``'s
planning pass accepts the optimum. `python studies/design_optimize_finger.py [--min-entry-angle 30]
[--out DIR]` writes design_optimize_finger.json and optimized.toml there (``--min-entry-angle``: the task
with that constraint too, which keeps fabricate from sheathing the flexor's channel).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np


def _gradient_free(d, t, max_evaluations: int, target: float) -> dict:
    """COBYLA over the task's scaled variables; the solves it took to reach target while feasible."""
    from scipy.optimize import minimize

    from skelfem import Session
    from skelfem.analysis.design_gradient import DesignGradient
    from skelfem.analysis.design_optimize import (FEASIBLE, DesignConstraints, objective_of, override_text,
                                                  target_sets)
    start = np.array([v.start for v in t.variables])
    width = np.array([v.upper - v.lower for v in t.variables])
    lower = (np.array([v.lower for v in t.variables]) - start) / width
    upper = (np.array([v.upper for v in t.variables]) - start) / width
    solves, trace, t0 = [0], [], time.perf_counter()
    with Session(d) as session:
        dg = DesignGradient(session, [v.key for v in t.variables])
        clear = DesignConstraints(t, dg.handles, width)
        worst = [0.0]

        def f(x):
            total = 0.0
            for settings, members in target_sets(t):
                try:
                    result = dg.solve(x * width, overrides=[override_text(k, v) for k, v in settings])
                except ValueError:                  # a design the rules or the morph refuse
                    return 2.0 * worst[0]
                solves[0] += 1
                if not result.converged:
                    return 2.0 * worst[0]
                total += sum(o.weight * objective_of(o, tg).value(session.model) for o, tg in members)
            worst[0] = max(worst[0], total)
            trace.append((solves[0], total, float(clear.values(x).min()), x * width))
            return total

        cons = [{"type": "ineq", "fun": clear.values},
                {"type": "ineq", "fun": lambda x: x - lower}, {"type": "ineq", "fun": lambda x: upper - x}]
        res = minimize(f, np.zeros(len(start)), method="COBYLA", constraints=cons,
                       options={"maxiter": max_evaluations, "rhobeg": 0.05, "tol": 1e-6})
    feasible = [(s, j, p) for s, j, c, p in trace if c >= -FEASIBLE]
    best = min(feasible, key=lambda item: item[1], default=(0, float("nan"), np.zeros(len(start))))
    return {"objective": best[1], "solves": solves[0], "evaluations": len(trace), "status": str(res.message),
            "time_s": time.perf_counter() - t0,
            "solves_to_reach_gradient_optimum": next((s for s, j, _ in feasible if j <= target), None),
            "variables": {v.key: float(v.start + dp) for v, dp in zip(t.variables, best[2])},
            "raw": dg.handles.raw(best[2])}


def _fabricates(raw, source) -> dict:
    from skelfem.design.parse import parse_design
    from skelfem.fabricate.plan import plan
    from skelfem.fabricate.surfaces import FabricationError
    try:
        p = plan(parse_design(raw, source))
    except FabricationError as exc:
        return {"ok": False, "why": str(exc)}
    return {"ok": True, "notes": list(p.notes)}


def run(design="geometry/finger.toml", task="studies/finger_reach_task.toml", max_gradient_free: int = 400,
        out=None, max_evaluations: int | None = None, min_entry_angle: float | None = None) -> dict:
    from skelfem import Session
    from skelfem.analysis.design_optimize import TaskObjective, optimize_design
    from skelfem.design.design_task import load_task
    from skelfem.design.parse import load_design, parse_design

    d = load_design(design)
    t = load_task(task, d)
    if max_evaluations is not None:
        t = dataclasses.replace(t, max_evaluations=max_evaluations)
    if min_entry_angle is not None:          # the task as if its [constraints] had min_entry_angle too
        t = dataclasses.replace(t, constraints=t.constraints + (("min_entry_angle", float(min_entry_angle)),))
    t0 = time.perf_counter()
    with Session(d) as session:
        opt = optimize_design(session, t)
    grad_time = time.perf_counter() - t0
    with Session(parse_design(opt.raw, str(design))) as fresh_session:
        fresh, fresh_error = TaskObjective(None, t).value(fresh_session, estimate=True)
    free = _gradient_free(d, t, max_gradient_free, opt.objective)
    free["fabricate"] = _fabricates(free.pop("raw"), str(design))
    free["improvement"] = 1.0 - free["objective"] / opt.start_objective
    out_data = {
        "design": str(design), "task": str(task), "constraints": dict(t.constraints), "start": opt.start_objective,
        "gradient": {"objective": opt.objective, "solves": opt.evaluations, "evaluations": len(opt.history),
                     "status": opt.status, "improvement": 1.0 - opt.objective / opt.start_objective,
                     "time_s": grad_time, "clearances": opt.clearances,
                     "variables": {k: float(v) for k, v in zip(opt.keys, opt.best)},
                     "fresh": fresh, "fresh_error_estimate": fresh_error,
                     "fresh_relative_difference": abs(fresh - opt.objective) / abs(opt.objective),
                     "fabricate": _fabricates(opt.raw, str(design))},
        "gradient_free": free,
    }
    if out is not None:
        from skelfem.editor.savefile import render
        Path(out).mkdir(parents=True, exist_ok=True)
        (Path(out) / "design_optimize_finger.json").write_text(json.dumps(out_data, indent=2))
        (Path(out) / "optimized.toml").write_text(render(Path(design).read_text(), opt.raw))
    return out_data


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--design", default="geometry/finger.toml")
    ap.add_argument("--task", default="studies/finger_reach_task.toml")
    ap.add_argument("--max-gradient-free", type=int, default=400)
    ap.add_argument("--min-entry-angle", type=float, default=None,
                    help="add this [constraints] min_entry_angle (degrees) to the task")
    ap.add_argument("--out", default="studies/output/design_optimize_finger")
    args = ap.parse_args(argv)
    r = run(args.design, args.task, args.max_gradient_free, args.out, min_entry_angle=args.min_entry_angle)
    g, f = r["gradient"], r["gradient_free"]
    print(f"start objective {r['start']:.6g}")
    print(f"gradient (SLSQP): {g['objective']:.6g} ({100 * g['improvement']:.1f} % better) in {g['evaluations']} "
          f"evaluations, {g['solves']} solves, {g['time_s']:.1f} s; {g['status']}")
    print(f"  fresh mesh {g['fresh']:.6g} +- {g['fresh_error_estimate']:.3g} "
          f"({100 * g['fresh_relative_difference']:.2f} % off); clearances {g['clearances']}; "
          f"fabricate: {g['fabricate']['ok']}")
    print(f"gradient-free (COBYLA): {f['objective']:.6g} ({100 * f['improvement']:.1f} % better) in "
          f"{f['evaluations']} evaluations, {f['solves']} solves, {f['time_s']:.1f} s; reached the gradient "
          f"optimum after {f['solves_to_reach_gradient_optimum']} solves")


if __name__ == "__main__":
    main()
