"""``skelfem optimize-design``: a 2D design optimised with its exact gradients (skelfem.analysis.design_optimize).

    skelfem optimize-design DESIGN --task TASK.toml [--out DIR] [--set KEY=VALUE ...]

The task file (skelfem.design.design_task) names the design variables with
their bounds and the objectives; it is checked against the design before
anything is meshed (bad input: one ``error:`` line, exit 1, nothing
written). Writes ``optimized.toml`` (the best design, the original file's
comments kept), ``history.csv`` (evaluation, objective, gradient norm) and
``optimize_design.json`` (``start``, ``optimum`` and ``fresh`` objective
values: the start design's, the optimiser's best, and the best design meshed
anew and solved fresh; ``evaluations``: forward solves; ``variables`` with
start and final values; ``status``). Exit 2 when the start design cannot be
solved.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

from . import common as cli
from ..io import outdir
from ..io.files import FORMAT, write_csv, write_json, write_text


def add_parsers(subparsers) -> None:
    p = subparsers.add_parser("optimize-design", help="optimise a 2D design's bones, outlines, cable routes and "
                                                      "materials with exact gradients")
    cli.common_arguments(p)
    p.add_argument("--task", type=Path, required=True, help="task file (TOML): [[variables]], [[objectives]]")
    p.set_defaults(handler=optimize_design_command)


def optimize_design_command(args) -> int:
    from mpi4py import MPI

    from ..analysis.design_optimize import Stop, TaskObjective, optimize_design
    from ..design.design_task import load_task
    from ..design.spec import DesignError
    from ..editor.savefile import render

    t0 = time.perf_counter()
    if MPI.COMM_WORLD.size > 1:
        raise cli.InputError(f"{args.design}: optimize-design runs on one MPI process (got {MPI.COMM_WORLD.size})")
    design = cli.load(args)
    try:
        task = load_task(args.task, design)
    except DesignError as exc:
        raise cli.InputError(str(exc)) from None
    design, session = cli.prepare(args, kind="optimize-design")
    if not args.verbose:
        cli.log.setLevel(logging.WARNING)
    with session:
        first = session.solve()
        if not first.converged:
            cli.error(f"{design.name}: the start design does not solve ({first.status}); nothing written to "
                      f"{args.out}")
            return cli.EXIT_SOLVE
        def progress(solves: int, objective: float) -> None:
            if not args.quiet:
                print(f"  {solves:4d} solves: objective {objective:.6g}", flush=True)

        try:
            opt = optimize_design(session, task, progress)
        except ValueError as exc:          # what the design gradient does not cover, found on the model
            raise cli.InputError(f"{args.design}: {exc}") from None
    if opt.evaluations == 0 or opt.objective != opt.objective:
        cli.error(f"{design.name}: {opt.status}; nothing written to {args.out}")
        return cli.EXIT_SOLVE
    from ..design.parse import parse_design
    from ..session import Session
    best = parse_design(opt.raw, str(args.design))
    fresh_session = Session(best)
    try:
        fresh = TaskObjective(None, task).value(fresh_session)
    except Stop as exc:
        fresh, opt.status = float("nan"), f"{opt.status}; {exc}"
    finally:
        fresh_session.close()
    text = render(Path(args.design).read_text(), opt.raw)
    result = {"format": FORMAT, "design": design.name, "task": str(args.task), "status": opt.status,
              "start": opt.start_objective, "optimum": opt.objective, "fresh": fresh,
              "fresh_relative_difference": abs(fresh - opt.objective) / max(abs(opt.objective), 1e-300),
              "evaluations": opt.evaluations,
              "variables": [{"key": k, "start": float(a), "final": float(b)}
                            for k, a, b in zip(opt.keys, opt.start, opt.best)],
              "time": round(time.perf_counter() - t0, 3)}
    rows = [{"evaluation": e, "objective": j, "gradient_norm": g} for e, j, g in opt.history]
    with outdir.publish(args.out, kind="optimize-design") as stage:
        stage.run(write_text, stage.path / "optimized.toml", text)
        stage.run(write_csv, stage.path / "history.csv", ["evaluation", "objective", "gradient_norm"], rows)
        stage.run(write_json, stage.path / "optimize_design.json", result)
    if not args.quiet:
        print(f"{design.name}: objective {opt.start_objective:.6g} -> {opt.objective:.6g} in {opt.evaluations} "
              f"solves (fresh mesh: {fresh:.6g}); {opt.status}")
        for k, a, b in zip(opt.keys, opt.start, opt.best):
            print(f"  {k}: {a:.6g} -> {b:.6g}")
        print(f"  results in {args.out}/ (optimized.toml, history.csv, optimize_design.json)")
    return cli.EXIT_OK
