"""``skelfem bench [DESIGN] [--sizes H ...]``: Newton iteration cost against its floor.

Prints one table row per mesh size (DOFs, Jacobian assembly, numeric
refactorisation + solve, Newton iteration, iterations per solve, their
ratio) and writes bench.json (atomically) into the output folder. See
skelfem.jobs.bench for what is measured and how.
"""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

log = logging.getLogger("skelfem")

DEFAULT_DESIGN = Path("geometry") / "finger.toml"
DEFAULT_SIZES = (4.0, 2.0, 1.0, 0.45)


def add_parsers(subparsers) -> None:
    p = subparsers.add_parser("bench", help="time assembly, refactorisation and Newton iterations over mesh sizes",
                              description=__doc__.splitlines()[0].strip("`"),
                              formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("design", type=Path, nargs="?", default=DEFAULT_DESIGN, help="design file (TOML)")
    p.add_argument("--sizes", type=float, nargs="+", default=list(DEFAULT_SIZES), metavar="H",
                   help="mesh sizes (mm), one table row each")
    p.add_argument("--degree", type=int, choices=(1, 2), default=None,
                   help="Lagrange degree (default: the design's)")
    p.add_argument("--steps", type=int, default=None, help="load steps (default: the design's)")
    p.add_argument("--repeats", type=int, default=3, help="solves per size; timings are medians")
    p.add_argument("--pc", choices=("lu", "cholesky"), default=None,
                   help="MUMPS factorisation (default: the solver's)")
    p.add_argument("--out", type=Path, default=None, help="output folder (default: results/<name>)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override one design value, e.g. cables.flexor.contraction=4")
    p.add_argument("-q", "--quiet", action="store_true", help="print only errors")
    p.add_argument("-v", "--verbose", action="store_true", help="print every Newton iteration")
    p.set_defaults(handler=bench)


MAX_SIZES, MAX_REPEATS = 20, 100


def _check(args) -> None:
    import math

    from ..design.spec import MAX_STEPS
    from .common import InputError
    if not all(0 < h < math.inf for h in args.sizes):     # nan and inf too (nan passed "h <= 0")
        raise InputError(f"--sizes: must be finite and > 0, got {' '.join(f'{h:g}' for h in args.sizes[:8])}")
    if len(args.sizes) > MAX_SIZES:
        raise InputError(f"--sizes: at most {MAX_SIZES} sizes, got {len(args.sizes)}")
    if not 1 <= args.repeats <= MAX_REPEATS:
        raise InputError(f"--repeats: must be >= 1 and <= {MAX_REPEATS}, got {args.repeats}")
    if args.steps is not None and not 1 <= args.steps <= MAX_STEPS:
        raise InputError(f"--steps: must be >= 1 and <= {MAX_STEPS}, got {args.steps}")


def bench(args) -> int:
    from mpi4py import MPI

    from ..jobs import bench as B
    from .common import EXIT_OK, EXIT_SOLVE, InputError, error, output_folder
    from ..design.spec import DesignError
    from ..design.parse import load_design
    from ..mesh.geometry import MeshingError

    _check(args)
    # one progress line per size; the solver's per-load-step lines only with -v
    logging.getLogger("skelfem.jobs.bench").setLevel(log.getEffectiveLevel())
    if not args.verbose:
        log.setLevel(max(log.getEffectiveLevel(), logging.WARNING))
    try:
        design = load_design(args.design, args.overrides)
    except DesignError as exc:
        raise InputError(str(exc)) from None
    out = output_folder(args, design)
    options = {"pc_type": args.pc} if args.pc else None
    log.info("%s: benchmarking sizes %s (P%d, %d repeat(s))", design.name,
             " ".join(f"{h:g}" for h in args.sizes), args.degree or design.mesh.degree, args.repeats)
    try:
        result = B.run(args.design, args.sizes, args.degree, args.overrides, args.repeats, options, args.steps)
    except (DesignError, MeshingError) as exc:
        raise InputError(str(exc)) from None
    result["design_name"] = design.name
    if MPI.COMM_WORLD.rank == 0:
        B.write(out / "bench.json", result)
        if not args.quiet:
            print(B.format_table(result))
            print(f"bench.json in {out}/")
    failed = [r for r in result["rows"] if not r["converged"]]
    if failed:
        sizes = ", ".join(f"{r['size']:g}" for r in failed)
        error(f"{design.name}: solve failed at size(s) {sizes} ({failed[0]['status']}); "
              "their timings are not of an equilibrium")
        return EXIT_SOLVE
    return EXIT_OK
