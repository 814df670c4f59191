"""``skelfem sweep SWEEP.toml [--out DIR]``: run many variants of a design (see skelfem.sweep)."""
from __future__ import annotations

import logging
from pathlib import Path

from . import cli


def add_parsers(subparsers) -> None:
    p = subparsers.add_parser("sweep", help="run a batch of design variants (parallel under mpirun, resumable)")
    p.add_argument("sweep", type=Path, help="sweep file (TOML)")
    p.add_argument("--out", type=Path, default=None, help="output folder (default: results/<sweep name>)")
    p.add_argument("-q", "--quiet", action="store_true", help="print only errors")
    p.add_argument("-v", "--verbose", action="store_true", help="print each case's solver log")
    p.set_defaults(handler=sweep)


def sweep(args) -> int:
    from mpi4py import MPI

    from .design import DesignError
    from .sweep import load_sweep, run_sweep, say

    try:
        spec = load_sweep(args.sweep)
    except DesignError as exc:
        raise cli.InputError(str(exc)) from None
    out = args.out or Path("results") / spec.name
    if out.exists() and not out.is_dir():
        raise cli.InputError(f"{out}: output path exists and is not a folder")
    if not args.verbose:
        logging.getLogger("skelfem").setLevel(logging.WARNING)   # per-case logs would interleave
    try:
        summary = run_sweep(spec, out, MPI.COMM_WORLD, progress=None if args.quiet else say)
    except DesignError as exc:
        raise cli.InputError(str(exc)) from None
    if MPI.COMM_WORLD.rank == 0 and not args.quiet:
        failed = f"; failed: {', '.join(summary['failed'])}" if summary["failed"] else ""
        print(f"{spec.name}: {summary['converged']}/{summary['cases']} converged, ran {summary['ran']} "
              f"case(s) in {summary['time']:.1f} s{failed}\n  summary in {out}/summary.csv and summary.png")
    return cli.EXIT_OK          # the sweep ran to the end; failed cases are listed in summary.csv
