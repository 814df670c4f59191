"""``skelfem edit DESIGN [--port N] [--no-browser]``: the interactive designer (see skelfem.editor).

Validates the design (a bad one is one ``error:`` line, exit 1, before
anything starts), solves it once, then serves the editor on
http://127.0.0.1:PORT/ (loopback only) and opens it in the browser unless
``--no-browser``. Ctrl-C (or SIGTERM) stops the server; the exit status is 0.
"""
from __future__ import annotations

import logging
import os
import sys
from pathlib import Path

from ..editor.worker import Budget
from . import common as cli

DEFAULT_PORT = 8765
MAX_BUDGET = 1e9         # --max-seconds and --max-memory: finite, and far beyond any use


def add_parsers(subparsers) -> None:
    p = subparsers.add_parser("edit", help="the interactive designer: drag outlines, bones and cables in the "
                                           "browser and see the equilibrium live",
                              description="Serve a page (on 127.0.0.1 only) that draws the design over its "
                                          "equilibrium and re-solves it as you drag vertices, move sliders and "
                                          "targets; Save writes the TOML back.")
    p.add_argument("design", type=Path, help="design file (TOML)")
    p.add_argument("--port", type=int, default=DEFAULT_PORT,
                   help=f"port on 127.0.0.1 (default {DEFAULT_PORT}; 0: any free port)")
    p.add_argument("--no-browser", action="store_true", help="do not open the page in a browser")
    p.add_argument("--max-dofs", type=int, default=None, metavar="N",
                   help="refuse designs estimated beyond N unknowns (default: 60,000 in 2D, 30,000 in 3D: "
                        "about a second a solve)")
    p.add_argument("--max-seconds", type=float, default=None, metavar="S",
                   help=f"cancel a request the solver has spent more than S seconds on (default {Budget.seconds:g}); "
                        "the solver starts again from the last design that solved")
    p.add_argument("--max-memory", type=float, default=None, metavar="MB",
                   help=f"cancel a request that adds more than MB megabytes to the editor's memory (default "
                        f"{Budget.memory / 1e6:,.0f})")
    p.add_argument("-q", "--quiet", action="store_true", help="print only errors")
    p.add_argument("-v", "--verbose", action="store_true", help="print every solve")
    p.set_defaults(handler=edit)


def edit(args) -> int:
    from mpi4py import MPI

    from ..design import resources
    from ..design.spec import DesignError
    from ..design.parse import load_design
    from ..editor.engine import EditError, budget, check_budget
    from ..editor.server import Editor, EditorError
    from ..mesh.geometry import MeshingError

    if MPI.COMM_WORLD.size > 1:
        raise cli.InputError("edit runs on one process; start it without mpirun")
    if not 0 <= args.port <= 65535:
        raise cli.InputError(f"--port {args.port}: must be between 0 and 65535")
    if args.max_dofs is not None and not 1 <= args.max_dofs <= resources.MAX_DOFS[2]:
        raise cli.InputError(f"--max-dofs {args.max_dofs}: must be between 1 and {resources.MAX_DOFS[2]:,}")
    for flag, value in (("--max-seconds", args.max_seconds), ("--max-memory", args.max_memory)):
        if value is not None and not 0 < value <= MAX_BUDGET:
            raise cli.InputError(f"{flag} {value:g}: must be a number above 0 and at most {MAX_BUDGET:g}")
    per_request = Budget(args.max_seconds or Budget.seconds,
                         1e6 * args.max_memory if args.max_memory else Budget.memory)
    try:
        design = load_design(args.design)
        resources.check(design)
    except DesignError as exc:
        raise cli.InputError(str(exc)) from None
    try:
        check_budget(design, budget(args.max_dofs))
    except EditError as exc:
        raise cli.InputError(exc.message) from None
    if not args.verbose:
        cli.log.setLevel(logging.WARNING)       # one line per solve would flood the terminal
    try:
        editor = Editor(args.design, args.port, max_dofs=args.max_dofs, budget=per_request)
    except (DesignError, MeshingError, EditorError) as exc:
        raise cli.InputError(str(exc)) from None
    if not args.quiet:
        print(f"skelfem editor: {editor.url}  ({design.name}{', 3D: read-only' if design.dim != 2 else ''}; "
              "Ctrl-C to stop)", flush=True)
    editor.run(open_browser=not args.no_browser)
    if not args.quiet:
        print("skelfem editor: stopped", flush=True)
    if editor.busy:
        # a solve is still running on the solver thread; nobody waits for it, and finalising
        # MPI/PETSc under it is unsafe: leave now (everything the editor writes is written atomically)
        sys.stdout.flush(), sys.stderr.flush()
        os._exit(cli.EXIT_OK)
    return cli.EXIT_OK
