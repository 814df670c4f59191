"""``skelfem sweep SWEEP.toml [--out DIR]``: run many variants of a design (see skelfem.jobs.sweep)."""
from __future__ import annotations

import logging
from pathlib import Path

from . import common as cli


def add_parsers(subparsers) -> None:
    p = subparsers.add_parser("sweep", help="run a batch of design variants (parallel under mpirun, resumable)")
    p.add_argument("sweep", type=Path, help="sweep file (TOML)")
    p.add_argument("--out", type=Path, default=None, help="output folder (default: results/<sweep name>)")
    p.add_argument("--force", action="store_true",
                   help="mesh cases even if their estimated size exceeds what this machine solves")
    p.add_argument("-q", "--quiet", action="store_true", help="print only errors")
    p.add_argument("-v", "--verbose", action="store_true", help="print each case's solver log")
    p.set_defaults(handler=sweep)


def exit_status(statuses: dict) -> int:
    """0 if every case converged; else 1 if a case had bad input (or an unusable folder), 3 if one
    hit an internal error, 2 if cases only failed to converge."""
    values = set(statuses.values())
    if values <= {"converged"}:
        return cli.EXIT_OK
    if values & {"bad_input", "bad_output"}:
        return cli.EXIT_INPUT
    if "internal_error" in values:
        return cli.EXIT_INTERNAL
    return cli.EXIT_SOLVE


def sweep(args) -> int:
    from mpi4py import MPI

    from ..design.spec import DesignError
    from ..io.outdir import OutputError
    from ..jobs.sweep import load_sweep, run_sweep, say

    try:
        spec = load_sweep(args.sweep)
    except DesignError as exc:
        raise cli.InputError(str(exc)) from None
    out = args.out or Path("results") / spec.name
    if not args.verbose:
        logging.getLogger("skelfem").setLevel(logging.WARNING)   # per-case logs would interleave
    try:
        summary = run_sweep(spec, out, MPI.COMM_WORLD, progress=None if args.quiet else say, force=args.force)
    except (DesignError, OutputError) as exc:
        raise cli.InputError(str(exc)) from None
    if MPI.COMM_WORLD.rank == 0 and not args.quiet:
        failed = f"; failed: {', '.join(summary['failed'])}" if summary["failed"] else ""
        print(f"{spec.name}: {summary['converged']}/{summary['cases']} converged, ran {summary['ran']} "
              f"case(s) in {summary['time']:.1f} s{failed}\n  summary in {out}/summary.csv and summary.png")
    code = exit_status(summary["statuses"])
    if code:
        failed = summary["failed"]
        shown = ", ".join(failed[:5]) + (f" and {len(failed) - 5} more" if len(failed) > 5 else "")
        cli.error(f"{spec.source}: {len(failed)} of {summary['cases']} case(s) failed ({shown}); "
                  f"see {out / 'summary.csv'}; running the sweep again retries them")
    return code
