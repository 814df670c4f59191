"""``skelfem optimize-design``: a 2D design optimised with its exact gradients (skelfem.analysis.design_optimize).

    skelfem optimize-design DESIGN --task TASK.toml [--out DIR] [--set KEY=VALUE ...]

The task file (skelfem.design.design_task) names the design variables with
their bounds, the objectives and the fabrication constraints; it is checked
against the design before anything is meshed (bad input: one ``error:``
line, exit 1, nothing written). Writes ``optimized.toml`` (the best design,
the original file's comments kept), ``history.csv`` (per evaluation: solves
so far, objective, gradient norm, constraint violation) and
``optimize_design.json`` (``start``, ``optimum`` and ``fresh`` objective
values: the start design's, the optimiser's best, and the best design meshed
anew and solved fresh with its error estimate; ``evaluations``: forward
solves; ``variables`` with start and final values; ``clearances``; ``status``).
Exit 2 when the start design cannot be solved.

Every evaluation is kept beside the output folder in
``.<out name>.optimize-design-partial.json`` (:class:`Checkpoint`): an
interrupted run of the same design and task resumes from it, and the file
goes once the result is published.
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from pathlib import Path

from . import common as cli
from ..io import outdir
from ..io.files import FORMAT, read_bounded, write_csv, write_json, write_text

MAX_CHECKPOINT_BYTES = 64 * 2 ** 20


def add_parsers(subparsers) -> None:
    p = subparsers.add_parser("optimize-design", help="optimise a 2D design's bones, outlines, cable routes and "
                                                      "materials with exact gradients")
    cli.common_arguments(p)
    p.add_argument("--task", type=Path, required=True,
                   help="task file (TOML): [[variables]], [[objectives]], [constraints]")
    p.set_defaults(handler=optimize_design_command)


class Checkpoint:
    """The evaluations of a run so far, kept beside the output folder so that an interrupted run resumes.

    ``.<out name>.optimize-design-partial.json`` holds a key over the design as overridden and the task (its
    budget aside: a run resumed with a larger budget goes on) and one entry per evaluation (the scaled
    variables, the objective and its gradient, or why the trial design was refused, and the solves it took).
    A run with the same key retraces the optimiser's path through them without solving
    (skelfem.analysis.design_optimize.Evaluations) and goes on from where the last one stopped; any other
    run starts afresh. The file is removed once the run's results are published."""

    def __init__(self, out: Path, design, task):
        target = Path(os.path.realpath(out))
        self.path = target.parent / f".{target.name}.optimize-design-partial.json"
        key = {"design": design.raw, "variables": repr(task.variables), "objectives": repr(task.objectives),
               "constraints": repr(task.constraints)}
        self.key = hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()
        self.entries: list = []
        try:
            data = json.loads(read_bounded(self.path, MAX_CHECKPOINT_BYTES, "checkpoint"))
            if isinstance(data, dict) and data.get("key") == self.key and isinstance(data.get("entries"), list):
                self.entries = [self._checked(e, len(task.variables)) for e in data["entries"]]
        except (OSError, ValueError, KeyError, TypeError):
            self.entries = []             # none, another run's or a broken checkpoint: start over
        self.resumed = len(self.entries)

    @staticmethod
    def _checked(e: dict, n: int) -> dict:
        x = [float(v) for v in e["x"]]
        if len(x) != n or not isinstance(e["solves"], int):
            raise ValueError("not an entry of this task")
        if e["refused"] is None:
            g = [float(v) for v in e["g"]]
            if len(g) != n:
                raise ValueError("not an entry of this task")
            return {"x": x, "J": float(e["J"]), "g": g, "refused": None, "solves": e["solves"]}
        return {"x": x, "J": None, "g": None, "refused": str(e["refused"]), "solves": e["solves"]}

    def add(self, entry: dict) -> None:
        self.entries.append(entry)
        write_json(self.path, {"key": self.key, "entries": self.entries})

    def remove(self) -> None:
        try:
            self.path.unlink()
        except FileNotFoundError:
            pass


def _fresh(raw, source, task):
    """(J, its error estimate) of a design meshed anew and solved fresh, or (nan, nan, why)."""
    from ..analysis.design_optimize import Stop, TaskObjective
    from ..design.parse import parse_design
    from ..session import Session
    fresh_session = Session(parse_design(raw, source))
    try:
        return (*TaskObjective(None, task).value(fresh_session, estimate=True), "")
    except Stop as exc:
        return float("nan"), float("nan"), str(exc)
    finally:
        fresh_session.close()


def optimize_design_command(args) -> int:
    from mpi4py import MPI

    from ..analysis.design_optimize import optimize_design
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
    checkpoint = Checkpoint(args.out, design, task)
    if not args.verbose:
        cli.log.setLevel(logging.WARNING)
    with session:
        first = session.solve()
        if not first.converged:
            cli.error(f"{design.name}: the start design does not solve ({first.status}); nothing written to "
                      f"{args.out}")
            return cli.EXIT_SOLVE
        if checkpoint.resumed and not args.quiet:
            print(f"  resuming: {checkpoint.resumed} evaluations of an interrupted run are read back", flush=True)

        def progress(solves: int, objective: float) -> None:
            if not args.quiet:
                print(f"  {solves:4d} solves: objective {objective:.6g}", flush=True)

        try:
            opt = optimize_design(session, task, progress, known=list(checkpoint.entries), record=checkpoint.add)
        except ValueError as exc:          # what the design gradient does not cover, found on the model
            raise cli.InputError(f"{args.design}: {exc}") from None
    if opt.evaluations == 0 or opt.objective != opt.objective:
        cli.error(f"{design.name}: {opt.status}; nothing written to {args.out}")
        return cli.EXIT_SOLVE
    fresh, fresh_error, why = _fresh(opt.raw, str(args.design), task)
    if why:
        opt.status = f"{opt.status}; {why}"
    result = _summary(design, args, task, opt, fresh, fresh_error, checkpoint.resumed, time.perf_counter() - t0)
    rows = [{"solves": s, "objective": j, "gradient_norm": g, "constraint_violation": v}
            for s, j, g, v in opt.history]
    text = render(Path(args.design).read_text(), opt.raw)
    with outdir.publish(args.out, kind="optimize-design") as stage:
        stage.run(write_text, stage.path / "optimized.toml", text)
        stage.run(write_csv, stage.path / "history.csv", ["solves", "objective", "gradient_norm",
                                                           "constraint_violation"], rows)
        stage.run(write_json, stage.path / "optimize_design.json", result)
    checkpoint.remove()
    if not args.quiet:
        print(f"{design.name}: objective {opt.start_objective:.6g} -> {opt.objective:.6g} in {opt.evaluations} "
              f"solves (fresh mesh: {fresh:.6g} +- {fresh_error:.2g}); {opt.status}")
        for k, a, b in zip(opt.keys, opt.start, opt.best):
            print(f"  {k}: {a:.6g} -> {b:.6g}")
        print(f"  results in {args.out}/ (optimized.toml, history.csv, optimize_design.json)")
    return cli.EXIT_OK


def _summary(design, args, task, opt, fresh, fresh_error, resumed, seconds) -> dict:
    return {"format": FORMAT, "design": design.name, "task": str(args.task), "status": opt.status,
            "start": opt.start_objective, "optimum": opt.objective, "fresh": fresh,
            "fresh_error_estimate": fresh_error,
            "fresh_relative_difference": abs(fresh - opt.objective) / max(abs(opt.objective), 1e-300),
            "evaluations": opt.evaluations, "gradient_evaluations": len(opt.history),
            "resumed_after": resumed,
            "constraints": dict(task.constraints), "clearances": opt.clearances,
            "variables": [{"key": k, "start": float(a), "final": float(b)}
                          for k, a, b in zip(opt.keys, opt.start, opt.best)],
            "time": round(seconds, 3)}
