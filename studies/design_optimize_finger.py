"""Design optimisation with exact gradients against a gradient-free search, on the same task.

The task (default: studies/finger_reach_task.toml on geometry/finger.toml) is minimised twice from
the hand-made design:

* with exact design gradients: L-BFGS-B (skelfem.analysis.design_optimize, as ``skelfem
  optimize-design`` runs it);
* without: SciPy's Nelder-Mead with the same bounds and scaling, at most `max_gradient_free`
  objective evaluations.

Reported: the objective at the start and at each optimum, the improvement, the solves each method
needed (a solve is one equilibrium of one target; the gradient's adjoint solves are counted apart),
the solves Nelder-Mead needed to first reach the gradient run's optimum (None: never within its
budget), and the times. `python studies/design_optimize_finger.py [--out DIR]`.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def run(design="geometry/finger.toml", task="studies/finger_reach_task.toml", max_gradient_free: int = 150,
        out=None) -> dict:
    from scipy.optimize import minimize

    from skelfem import Session
    from skelfem.analysis.design_gradient import DesignGradient
    from skelfem.analysis.design_optimize import objective_of, optimize_design, override_text
    from skelfem.design.design_task import load_task
    from skelfem.design.parse import load_design

    d = load_design(design)
    t = load_task(task, d)
    t0 = time.perf_counter()
    with Session(d) as session:
        opt = optimize_design(session, t)
    grad_time = time.perf_counter() - t0

    start = np.array([v.start for v in t.variables])
    width = np.array([v.upper - v.lower for v in t.variables])
    bounds = list(zip((np.array([v.lower for v in t.variables]) - start) / width,
                      (np.array([v.upper for v in t.variables]) - start) / width))
    t1 = time.perf_counter()
    solves, trace = [0], []
    with Session(d) as session:
        dg = DesignGradient(session, [v.key for v in t.variables])

        def f(x):
            total = 0.0
            for objective in t.objectives:
                for target in objective.targets:
                    result = dg.solve(x * width, overrides=[override_text(k, v) for k, v in target.set])
                    solves[0] += 1
                    if not result.converged:
                        return 1e30
                    total += objective.weight * objective_of(objective, target).value(session.model)
            trace.append((solves[0], total))
            return total

        res = minimize(f, np.zeros(len(start)), method="Nelder-Mead", bounds=bounds,
                       options={"maxfev": max_gradient_free, "xatol": 1e-6, "fatol": 1e-9})
    free_time = time.perf_counter() - t1
    reached = next((s for s, j in trace if j <= opt.objective), None)
    out_data = {
        "design": str(design), "task": str(task), "start": opt.start_objective,
        "gradient": {"objective": opt.objective, "solves": opt.evaluations, "status": opt.status,
                     "improvement": 1.0 - opt.objective / opt.start_objective, "time_s": grad_time,
                     "variables": {k: float(v) for k, v in zip(opt.keys, opt.best)}},
        "gradient_free": {"objective": float(res.fun), "solves": solves[0], "status": str(res.message),
                          "improvement": 1.0 - float(res.fun) / opt.start_objective, "time_s": free_time,
                          "solves_to_reach_gradient_optimum": reached},
    }
    if out is not None:
        Path(out).mkdir(parents=True, exist_ok=True)
        (Path(out) / "design_optimize_finger.json").write_text(json.dumps(out_data, indent=2))
    return out_data


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--design", default="geometry/finger.toml")
    ap.add_argument("--task", default="studies/finger_reach_task.toml")
    ap.add_argument("--max-gradient-free", type=int, default=150)
    ap.add_argument("--out", default="studies/output/design_optimize_finger")
    args = ap.parse_args(argv)
    r = run(args.design, args.task, args.max_gradient_free, args.out)
    g, f = r["gradient"], r["gradient_free"]
    print(f"start objective {r['start']:.6g}")
    print(f"gradient (L-BFGS-B): {g['objective']:.6g} ({100 * g['improvement']:.1f} % better) in {g['solves']} solves, "
          f"{g['time_s']:.1f} s; {g['status']}")
    print(f"gradient-free (Nelder-Mead): {f['objective']:.6g} ({100 * f['improvement']:.1f} % better) in "
          f"{f['solves']} solves, {f['time_s']:.1f} s; reached the gradient optimum after "
          f"{f['solves_to_reach_gradient_optimum']} solves")


if __name__ == "__main__":
    main()
