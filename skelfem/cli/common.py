"""What every sub-command shares: exit codes, logging, common arguments, one-line errors, loading and output folders.

Command line: ``skelfem simulate DESIGN [--out DIR] [--set KEY=VALUE ...]``, ``skelfem fabricate DESIGN``, ....

Exit status: 0 on success, 1 for bad input (one ``error:`` line on stderr;
command-line mistakes included), 2 when the solve does not converge
(result.json says why), 3 for an internal error, 130 / 143 when interrupted
by SIGINT / SIGTERM. Under MPI every rank ends with the same status and one
line is printed (see skelfem.runtime.mpiguard).
"""
from __future__ import annotations

import argparse
import logging
import re
import sys
from pathlib import Path


log = logging.getLogger("skelfem")


EXIT_OK, EXIT_INPUT, EXIT_SOLVE, EXIT_INTERNAL = 0, 1, 2, 3
MAX_MESSAGE = 2000


class _RankZero(logging.Filter):
    def filter(self, record):
        from mpi4py import MPI
        return MPI.COMM_WORLD.rank == 0


def setup_logging(verbosity: int) -> None:
    level = {0: logging.WARNING, 1: logging.INFO}.get(verbosity, logging.DEBUG)
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(message)s"))
    handler.addFilter(_RankZero())
    log.handlers[:] = [handler]
    log.setLevel(level)
    log.propagate = False
    # FFCx/setuptools chatter on a first compilation goes to the root logger,
    # whose level setuptools raises to INFO: give the root a handler that
    # passes warnings only (this also stops logging.info from adding one).
    root = logging.getLogger()
    quiet = logging.StreamHandler(sys.stderr)
    quiet.setLevel(logging.WARNING)
    root.handlers[:] = [quiet]
    root.setLevel(logging.WARNING)
    for name in ("FFCx", "UFL", "ffcx", "ufl"):
        logging.getLogger(name).setLevel(logging.WARNING)


def common_arguments(parser: argparse.ArgumentParser,
                     out_help: str = "output folder (default: results/<name>)") -> None:
    """Arguments every command that runs a design shares."""
    parser.add_argument("design", type=Path, help="design file (TOML)")
    parser.add_argument("--out", type=Path, default=None, help=out_help)
    parser.add_argument("--force", action="store_true",
                        help="mesh even if the estimated size exceeds what this machine solves")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="override one design value, e.g. cables.flexor.contraction=8")
    parser.add_argument("-q", "--quiet", action="store_true", help="print only errors")
    parser.add_argument("-v", "--verbose", action="store_true", help="print every Newton iteration")


# Modules that add sub-commands: each has add_parsers(subparsers), and every
# parser it adds sets `handler` (a function args -> exit status).
class InputError(Exception):
    """Bad input found by a command; main prints it as one error line and exits 1."""


def one_line(message: str) -> str:
    """A message as one printable line: control characters escaped, very long ones shortened."""
    text = re.sub(r"[\x00-\x1f\x7f]", lambda m: repr(m.group())[1:-1], str(message))
    return text if len(text) <= MAX_MESSAGE else text[:MAX_MESSAGE - 3] + "..."


def print_error(message: str) -> None:
    try:
        print(f"error: {one_line(message)}", file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


def error(message: str) -> None:
    """Print one ``error:`` line (rank 0 only)."""
    from ..runtime.mpiguard import rank_hint
    if rank_hint() == 0:
        print_error(message)


def load(args):
    """The validated design of args (with --set), within the mesh-size limit unless --force; InputError if not."""
    from ..design import resources
    from ..design.spec import DesignError
    from ..design.parse import load_design
    try:
        design = load_design(args.design, args.overrides)
        resources.check(design, force=getattr(args, "force", False))
    except DesignError as exc:
        raise InputError(str(exc)) from None
    command = getattr(args, "command", None)
    if design.stages and command not in RUNS_STAGES and not getattr(args, "stages_noted", False):
        log.warning("%s: skelfem %s works on the design as written, before its [[stages]] (skelfem simulate "
                    "runs them)", design.name, command)
        args.stages_noted = True                # once, however often the command loads its design
    return design


RUNS_STAGES = ("simulate", "sweep", "fabricate")   # the commands a design's [[stages]] concern (fabricate: none)


def reserve_output(args, design, kind: str = "simulate") -> Path:
    """Check and lock the output folder before any work (collective); InputError if unusable."""
    from mpi4py import MPI

    from ..io.outdir import OutputError, reserve
    out = args.out or Path("results") / design.name
    try:
        reserve(out, MPI.COMM_WORLD, kind)
    except OutputError as exc:
        raise InputError(str(exc)) from None
    return out


def meshing_line(design) -> str:
    """The summary's first line: the mesh, and in 2D how deep the slab is, saying so where that depth is the
    1 mm default (a forgotten thickness makes a body twenty times softer against its cables and loads)."""
    text = f"{design.name}: meshing (size {design.mesh.size:g} mm, P{design.mesh.degree}"
    if design.dim == 2:
        text += f", a {design.thickness:g} mm slab"
        if "thickness" not in design.data:
            text += ": thickness not given, the default"
    return text + ")"


def prepare(args, kind: str = "simulate"):
    """Load and validate args.design, reserve the output folder, mesh; returns (design, session)."""
    from mpi4py import MPI

    from ..design.spec import DesignError
    from ..mesh.geometry import MeshingError
    from ..jobs.run import open_session

    design = load(args)
    args.out = reserve_output(args, design, kind)
    log.info("%s", meshing_line(design))
    try:
        session = open_session(design, MPI.COMM_WORLD)
    except (DesignError, MeshingError) as exc:
        raise InputError(str(exc)) from None
    return design, session


def output_folder(args, design, kind: str = "simulate") -> Path:
    """The output folder of args (default results/<name>), checked but not locked; InputError if unusable."""
    from ..io.outdir import OutputError, check_path
    out = args.out or Path("results") / design.name
    try:
        check_path(out, kind)
    except OutputError as exc:
        raise InputError(str(exc)) from None
    return out


