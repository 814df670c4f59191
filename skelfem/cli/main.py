"""Command line: ``skelfem simulate DESIGN [--out DIR] [--set KEY=VALUE ...]``, ``skelfem fabricate DESIGN``, ....

Exit status: 0 on success, 1 for bad input (one ``error:`` line on stderr;
command-line mistakes included), 2 when the solve does not converge
(result.json says why), 3 for an internal error, 130 / 143 when interrupted
by SIGINT / SIGTERM. Under MPI every rank ends with the same status and one
line is printed (see skelfem.runtime.mpiguard).
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from .common import (EXIT_INPUT, EXIT_INTERNAL, EXIT_SOLVE, InputError, print_error, common_arguments, error,
                     setup_logging)
from .fabricate import fabricate
from .simulate import simulate
from . import bench, calibrate, control, edit, optimize, optimize_design, sweep

# Modules that add sub-commands: each has add_parsers(subparsers), and every
# parser it adds sets `handler` (a function args -> exit status).
COMMAND_MODULES = (sweep, bench, control, edit, optimize, optimize_design, calibrate)



class _Parser(argparse.ArgumentParser):
    """argparse with one ``error:`` line and exit status 1 (bad input) for a bad command line."""

    def error(self, message):
        raise InputError(f"{self.prog}: {message} (see {self.prog} --help)")

    def _print_message(self, message, file=None):
        from ..runtime.mpiguard import rank_hint
        if rank_hint() == 0:                  # --help once under mpirun
            super()._print_message(message, file)


def _parser() -> argparse.ArgumentParser:
    p = _Parser(prog="skelfem", description="Simulate and control cable-driven soft robots "
                "with embedded skeletons.")
    sub = p.add_subparsers(dest="command", required=True)
    s = sub.add_parser("simulate", help="static equilibrium of a design (a run in time if it has [dynamics])")
    common_arguments(s)
    s.add_argument("--no-picture", action="store_true", help="skip deformed.png (motion.gif with [dynamics])")
    s.add_argument("--tol", action="append", default=None, metavar="ABS_MM|NAME=TOL",
                   help="refine the mesh (P2, from twice [mesh] size) until the design's own error estimate "
                        "(Richardson over the meshes) is below ABS_MM mm for every marker, or below TOL for the "
                        "observable NAME (e.g. cables.flexor.tension=0.05, markers.tip=0.1; repeat for several); "
                        "result.json reports it under accuracy")
    s.add_argument("--adaptive", action="store_true",
                   help="with --tol: graded meshes refined where element indicators of the marker error are "
                        "large, instead of uniform ones (serial runs)")
    s.add_argument("--estimate", action="store_true",
                   help="estimate the error of every observable (the same equilibrium one degree richer on the "
                        "same mesh); result.json reports them under errors")
    s.set_defaults(handler=simulate)
    f = sub.add_parser("fabricate", help="printable bones (STL, STEP) and a two-part mould for casting the body, "
                                         "or one multi-material 3MF",
                       description="Bones with cable channels and ligament anchor holes, and a two-part mould "
                                   "whose cavity is the body, from the design's [fabrication] section.")
    f.add_argument("design", type=Path, help="design file (TOML)")
    f.add_argument("--out", type=Path, default=None, help="output folder (default: results/<name>)")
    f.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override one design value, e.g. fabrication.channel_diameter=1.5")
    f.add_argument("--format", choices=("cast", "3mf"), default="cast",
                   help="cast: bones (STL, STEP) and a two-part mould to cast the body in (default); 3mf: the "
                        "whole robot as one multi-material 3MF, body and bones on their own extruders, printed "
                        "in one process")
    f.add_argument("--no-picture", action="store_true", help="skip fabrication.png and casting.png")
    f.add_argument("-q", "--quiet", action="store_true", help="print only errors")
    f.add_argument("-v", "--verbose", action="store_true", help="print the tracebacks of internal errors")
    f.set_defaults(handler=fabricate)
    for module in COMMAND_MODULES:
        module.add_parsers(sub)
    return p


def _stdio() -> None:
    """Never fail on printing a path that is not valid UTF-8."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.reconfigure(errors="backslashreplace")
        except (AttributeError, ValueError, OSError):
            pass


def _printable_argv() -> None:
    """sys.argv as valid UTF-8 for the libraries that read it (DOLFINx's logging takes it on import).

    Python decodes bytes that are not UTF-8 (a path in another encoding) with the file system's error
    handler (surrogate escapes); the command itself keeps those, so such paths still work, but a C++
    library cannot take them. Its copy gets them backslash-escaped.
    """
    sys.argv = [a.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace") for a in sys.argv]


def _import_gmsh() -> None:
    """Import gmsh now (it resets SIGINT to the default action on import) and put our handlers back.

    Imported later, deep inside meshing or DOLFINx, it would leave Ctrl-C
    killing the process without clean-up until the next re-install.
    """
    from ..runtime import interrupts
    try:
        interrupts.import_gmsh()          # with the signals held
    except ImportError:
        pass


def _internal(exc: BaseException, verbosity: int) -> tuple[int, str, bool]:
    """A bug, not bad input: one line, and the traceback with -v (an interrupt that surfaced as it: 128+N;
    a linear solve that failed outside Newton's, e.g. a sensitivity's: the solver's failure, exit 2)."""
    import numpy as np

    from ..runtime.interrupts import received
    if received() is not None:            # an interrupt that surfaced as another error
        return 128 + received(), "interrupted", False
    if isinstance(exc, np.linalg.LinAlgError):
        return EXIT_SOLVE, f"linear solve failed: {exc}", False
    if verbosity >= 2:
        import traceback
        traceback.print_exc()
    hint = "" if verbosity >= 2 else " (run with -v for the traceback)"
    return EXIT_INTERNAL, f"internal error: {type(exc).__name__}: {exc}{hint}", False


def _run(argv) -> tuple[int, str | None, bool]:
    """(exit status, message to print or None, whether the command ended normally)."""
    from ..io import outdir
    from ..design import resources
    from ..design.spec import DesignError
    from ..runtime.interrupts import Interrupted

    verbosity = 1
    try:
        try:
            args = _parser().parse_args(argv)
        except SystemExit as exc:             # --help
            return (exc.code if isinstance(exc.code, int) else EXIT_INPUT), None, True
        verbosity = 0 if getattr(args, "quiet", False) else (2 if getattr(args, "verbose", False) else 1)
        setup_logging(verbosity)
        resources.FORCED = bool(getattr(args, "force", False))
        _import_gmsh()
        if args.command != "sweep":           # one result: once it is published, the run is done
            from ..runtime import interrupts
            outdir.ON_COMMIT = interrupts.finish
        return args.handler(args), None, True
    except (InputError, DesignError, outdir.OutputError) as exc:
        return EXIT_INPUT, str(exc), False
    except Interrupted as exc:
        return exc.code, "interrupted", False
    except OSError as exc:
        from ..io.files import disk_error
        message = disk_error(exc)
        if message is None:
            return _internal(exc, verbosity)
        return EXIT_INPUT, message, False
    except KeyboardInterrupt:
        return 130, "interrupted", False
    except Exception as exc:  # a bug, not bad input: one line, and the traceback with -v
        return _internal(exc, verbosity)
    finally:
        outdir.ON_COMMIT = None
        outdir.release()                      # every output lock this process still holds
        resources.FORCED = False


def main(argv=None) -> int:
    """The skelfem command; returns the exit status (see the module doc)."""
    from ..runtime import interrupts, mpiguard

    interrupts.install()
    _stdio()
    in_process = argv is not None             # called by a test: Python's handlers again at the end
    argv = sys.argv[1:] if argv is None else list(argv)
    _printable_argv()
    ctl, status = None, 130
    try:
        if mpiguard.world_size_hint() > 1:
            from mpi4py import MPI
            ctl = mpiguard.control(MPI.COMM_WORLD)
        code, message, in_step = _run(argv)
        code, message = mpiguard.agree(ctl, code, message, in_step, say=print_error)
        if message:
            error(message)
        status = code
        return code
    except interrupts.Interrupted as exc:     # between the pieces above
        error("interrupted")
        status = exc.code
        return exc.code
    finally:
        if ctl is not None:
            ctl.Free()
        if not in_process:
            interrupts.ignore()               # the command is over: its status stands through the exit
            if interrupts.abandoned():        # a Gmsh call still runs in its thread: leave without finalisers
                sys.stdout.flush()
                sys.stderr.flush()
                mpiguard.finalise_alone()     # but MPI's (Gmsh uses none): no session folder left in TMPDIR
                os._exit(status)
        else:
            interrupts.uninstall()            # called in process (tests): Python's defaults again


if __name__ == "__main__":    # prefer `python -m skelfem`: one copy of this module
    from skelfem.cli.main import main as _main
    sys.exit(_main())
