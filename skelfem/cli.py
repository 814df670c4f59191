"""Command line: ``skelfem simulate DESIGN [--out DIR] [--set KEY=VALUE ...]``, ``skelfem fabricate DESIGN``, ....

Exit status: 0 on success, 1 for bad input (one ``error:`` line on stderr;
command-line mistakes included), 2 when the solve does not converge
(result.json says why), 3 for an internal error, 130 / 143 when interrupted
by SIGINT / SIGTERM. Under MPI every rank ends with the same status and one
line is printed (see skelfem.mpiguard).
"""
from __future__ import annotations

import argparse
import logging
import re
import sys
import time
from pathlib import Path

log = logging.getLogger("skelfem")

if __name__ == "skelfem.cli":                 # as early as possible: a Ctrl-C during start-up is clean too
    import os as _os
    # No PETSc signal handlers: PetscFinalize would put the default actions back while a finished
    # command exits, and a SIGTERM then would kill it (status -15) after its result is complete.
    _os.environ["PETSC_OPTIONS"] = (_os.environ.get("PETSC_OPTIONS", "") + " -no_signal_handler").strip()
    from . import interrupts as _interrupts
    _interrupts.install()

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


def common_arguments(parser: argparse.ArgumentParser, out_help: str = "output folder (default: results/<name>)") -> None:
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
COMMAND_MODULES = ("skelfem.cli_sweep", "skelfem.cli_bench", "skelfem.cli_control", "skelfem.cli_edit",
                   "skelfem.cli_optimize")


class _Parser(argparse.ArgumentParser):
    """argparse with one ``error:`` line and exit status 1 (bad input) for a bad command line."""

    def error(self, message):
        raise InputError(f"{self.prog}: {message} (see {self.prog} --help)")

    def _print_message(self, message, file=None):
        from .mpiguard import rank_hint
        if rank_hint() == 0:                  # --help once under mpirun
            super()._print_message(message, file)


def _parser() -> argparse.ArgumentParser:
    p = _Parser(prog="skelfem", description="Simulate and control cable-driven soft robots "
                "with embedded skeletons.")
    sub = p.add_subparsers(dest="command", required=True)
    s = sub.add_parser("simulate", help="static equilibrium of a design (a run in time if it has [dynamics])")
    common_arguments(s)
    s.add_argument("--no-picture", action="store_true", help="skip deformed.png (motion.gif with [dynamics])")
    s.add_argument("--tol", type=float, default=None, metavar="ABS_MM",
                   help="refine the mesh (P2, from twice [mesh] size) until the design's own marker error "
                        "estimate (Richardson over the meshes) is below ABS_MM mm; result.json reports it "
                        "under accuracy")
    s.add_argument("--adaptive", action="store_true",
                   help="with --tol: graded meshes refined where element indicators of the marker error are "
                        "large, instead of uniform ones (serial runs)")
    s.set_defaults(handler=simulate)
    f = sub.add_parser("fabricate", help="printable bones (STL, STEP) and a two-part mould for casting the body",
                       description="Bones with cable channels and ligament anchor holes, and a two-part mould "
                                   "whose cavity is the body, from the design's [fabrication] section.")
    f.add_argument("design", type=Path, help="design file (TOML)")
    f.add_argument("--out", type=Path, default=None, help="output folder (default: results/<name>)")
    f.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override one design value, e.g. fabrication.channel_diameter=1.5")
    f.add_argument("--no-picture", action="store_true", help="skip fabrication.png")
    f.add_argument("-q", "--quiet", action="store_true", help="print only errors")
    f.add_argument("-v", "--verbose", action="store_true", help="print the tracebacks of internal errors")
    f.set_defaults(handler=fabricate)
    import importlib
    for name in COMMAND_MODULES:
        importlib.import_module(name).add_parsers(sub)
    return p


class InputError(Exception):
    """Bad input found by a command; main prints it as one error line and exits 1."""


def one_line(message: str) -> str:
    """A message as one printable line: control characters escaped, very long ones shortened."""
    text = re.sub(r"[\x00-\x1f\x7f]", lambda m: repr(m.group())[1:-1], str(message))
    return text if len(text) <= MAX_MESSAGE else text[:MAX_MESSAGE - 3] + "..."


def _print_error(message: str) -> None:
    try:
        print(f"error: {one_line(message)}", file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


def error(message: str) -> None:
    """Print one ``error:`` line (rank 0 only)."""
    from .mpiguard import rank_hint
    if rank_hint() == 0:
        _print_error(message)


def load(args):
    """The validated design of args (with --set), within the mesh-size limit unless --force; InputError if not."""
    from . import resources
    from .design import DesignError, load_design
    try:
        design = load_design(args.design, args.overrides)
        resources.check(design, force=getattr(args, "force", False))
    except DesignError as exc:
        raise InputError(str(exc)) from None
    return design


def reserve_output(args, design, kind: str = "simulate") -> Path:
    """Check and lock the output folder before any work (collective); InputError if unusable."""
    from mpi4py import MPI

    from .outdir import OutputError, reserve
    out = args.out or Path("results") / design.name
    try:
        reserve(out, MPI.COMM_WORLD, kind)
    except OutputError as exc:
        raise InputError(str(exc)) from None
    return out


def prepare(args, kind: str = "simulate"):
    """Load and validate args.design, reserve the output folder, mesh; returns (design, session)."""
    from mpi4py import MPI

    from .design import DesignError
    from .geometry import MeshingError
    from .run import open_session

    design = load(args)
    args.out = reserve_output(args, design, kind)
    log.info("%s: meshing (size %g mm, P%d)", design.name, design.mesh.size, design.mesh.degree)
    try:
        session = open_session(design, MPI.COMM_WORLD)
    except (DesignError, MeshingError) as exc:
        raise InputError(str(exc)) from None
    return design, session


def output_folder(args, design, kind: str = "simulate") -> Path:
    """The output folder of args (default results/<name>), checked but not locked; InputError if unusable."""
    from .outdir import OutputError, check_path
    out = args.out or Path("results") / design.name
    try:
        check_path(out, kind)
    except OutputError as exc:
        raise InputError(str(exc)) from None
    return out


def simulate(args) -> int:
    from mpi4py import MPI

    from .run import write_results

    t0 = time.perf_counter()
    if args.tol is not None and not (0 < args.tol < float("inf")):
        raise InputError(f"--tol: must be a finite number > 0, got {args.tol:g}")
    design = load(args)
    if args.tol is not None and design.dynamics is not None:
        raise InputError(f"{args.design}: --tol chooses the mesh of a static run; a design with [dynamics] "
                         "sets [mesh] by hand")
    if getattr(args, "adaptive", False) and args.tol is None:
        raise InputError("--adaptive: refines for --tol; give --tol ABS_MM too")
    if args.tol is not None and not design.markers:
        raise InputError(f"{args.design}: --tol needs at least one marker (its error is what --tol bounds)")
    args.out = reserve_output(args, design)           # before any work: a bad --out is bad input
    extra = {}
    if args.tol is not None:
        design, session = prepare_tol(args, design)
        with session:
            solved, extra["accuracy"] = refine_to_tol(session, args.tol, getattr(args, "adaptive", False))
            result = write_results(session, solved, args.out, t0, picture=not args.no_picture, extra=extra)
    else:
        design, session = prepare(args)
        if design.dynamics is not None:
            return _simulate_in_time(args, design, session, t0, extra)
        with session:
            solved = session.solve()
            result = write_results(session, solved, args.out, t0, picture=not args.no_picture, extra=extra)
    if not solved.converged:
        error(f"{design.name}: solve failed ({solved.status}) after {solved.load_steps} load step(s); "
              f"try more [solver].steps or a finer mesh; details in {args.out / 'result.json'}")
        return EXIT_SOLVE
    if not args.quiet and MPI.COMM_WORLD.rank == 0:
        _summary(result, args.out)
    return EXIT_OK


def prepare_tol(args, design):
    """--tol: design at the first size of skelfem.accuracy's ladder (P2), meshed; (that design, session)."""
    from mpi4py import MPI

    from . import accuracy
    from .design import DesignError
    from .geometry import MeshingError
    from .run import open_session

    try:
        first = accuracy.first_level(design)
        log.info("--tol %g mm: P%d from h = %g mm, refined until the estimate meets it",
                 args.tol, accuracy.DEGREE, first.mesh.size)
        return first, open_session(first, MPI.COMM_WORLD)
    except (DesignError, MeshingError) as exc:
        raise InputError(str(exc)) from None


def refine_to_tol(session, tol: float, adaptive: bool = False):
    """skelfem.accuracy.refine, with mesh failures of a finer level as one-line input errors."""
    from . import accuracy
    from .design import DesignError
    from .geometry import MeshingError
    try:
        return accuracy.refine(session, tol, adaptive)
    except (DesignError, MeshingError) as exc:
        raise InputError(str(exc)) from None


def _simulate_in_time(args, design, session, t0, extra) -> int:
    """simulate for a design with [dynamics]: the run in time and its files (see run.write_dynamic_results)."""
    from mpi4py import MPI

    from .run import ProgressBar, write_dynamic_results

    bar = None if args.quiet else ProgressBar(f"{design.name}: t = 0 .. {design.dynamics.duration:g} s")
    try:
        with session:
            result = write_dynamic_results(session, args.out, t0, picture=not args.no_picture, progress=bar,
                                           extra=extra)
    finally:
        if bar is not None:
            bar.close()
    dyn = result["dynamics"]
    if not result["converged"]:
        error(f"{design.name}: time step failed ({result['status']}) at t = {dyn['time_reached']:.6g} s after "
              f"{dyn['steps']} step(s) and {dyn['cuts']} cut(s); try a smaller [dynamics].dt or a finer mesh; "
              f"the trajectory up to there is in {args.out}")
        return EXIT_SOLVE
    if not args.quiet and MPI.COMM_WORLD.rank == 0:
        print(f"{result['design']}: {dyn['steps']} time steps ({design.dynamics.integrator}, dt = "
              f"{design.dynamics.dt:g} s) to t = {dyn['time_reached']:.4g} s, {result['newton_iterations']} "
              f"Newton iterations, {dyn['cuts']} cut(s); min det F = {result['min_jacobian']:.3f}")
        for name, m in (result["markers"] or {}).items():
            print(f"  marker {name} at t = {dyn['time_reached']:.4g} s: "
                  f"({', '.join(f'{p:.2f}' for p in m['position'])}) mm")
        files = "result.json, trajectory.csv, trajectory.xdmf" + (", motion.gif" if design.dim == 2
                                                                   and not args.no_picture else "")
        print(f"  results in {args.out}/ ({files}), {result['timings']['total']:.1f} s")
    return EXIT_OK


def fabricate(args) -> int:
    """Plan (every check before the folder is touched), then build and publish the parts whole."""
    from mpi4py import MPI

    from . import fabricate as fab
    from .design import DesignError, load_design
    from .outdir import publish

    t0 = time.perf_counter()
    if MPI.COMM_WORLD.size > 1:
        raise InputError("fabricate runs on one process; start it without mpirun")
    try:
        design = load_design(args.design, args.overrides)
        plan = fab.plan(design)
    except DesignError as exc:
        raise InputError(str(exc)) from None
    except fab.FabricationError as exc:
        raise InputError(f"{design.source}: {exc.key}: {exc.message}") from None
    args.out = reserve_output(args, design, "fabricate")
    log.info("%s: building %d bone(s) and the mould", design.name, len(design.bones))
    with publish(args.out, MPI.COMM_WORLD, "fabricate") as stage:
        try:
            report = fab.write(plan, stage.path, picture_file=not args.no_picture)
        except OSError as exc:
            stage.errors.append(f"cannot write {Path(exc.filename).name if exc.filename else 'the parts'}: "
                                f"{exc.strerror or exc}")
            report = None
    if report is None:
        return EXIT_INPUT
    for note in report["notes"]:
        log.warning("%s: warning: %s", design.name, note)
    checks = report["checks"]
    if not checks["passed"]:
        failed = [k for k in ("stl_closed_and_oriented", "bone_volumes", "cavity_is_body") if not checks[k]]
        error(f"internal error: {design.name}: fabrication check(s) failed: {', '.join(failed)}; "
              f"see {args.out / 'fabrication.json'}")
        return EXIT_INTERNAL
    if not args.quiet:
        print(f"{design.name}: {len(design.bones)} bone(s) and a two-part mould in {args.out}/, "
              f"{time.perf_counter() - t0:.1f} s")
        for name, part in report["parts"].items():
            print(f"  {part['stl']:24s} {part['volume']:10.1f} mm^3  {part['triangles']:6d} triangles")
        m = report["mould"]
        print(f"  mould cavity {m['cavity_volume']:.1f} mm^3 against the body's {m['body_volume']:.1f} mm^3 "
              f"({100 * m['relative_error']:+.2f} %; {100 * m['closed_relative_error']:+.3f} % without the pour "
              "hole, vents, exits, pins and pegs); every STL closed and oriented")
    return EXIT_OK


def _summary(result: dict, out: Path) -> None:
    hist = result["residual_history"][-1] if result["residual_history"] else []
    print(f"{result['design']}: converged in {result['newton_iterations']} Newton iterations "
          f"over {result['load_steps']} load step(s); min det F = {result['min_jacobian']:.3f}")
    if "accuracy" in result:
        a = result["accuracy"]
        est = "-" if a.get("estimated_error") is None else f"{a['estimated_error']:.3g} mm"
        where = (f"h = {a['min_size']:.3g} .. {a['max_size']:.3g} mm (adaptive, {a['dofs']} DOFs)"
                 if a.get("adaptive") and "min_size" in a else f"h = {a.get('size', float('nan')):g} mm")
        bones = a.get("bones")
        if bones:
            where += (f", {'rigid' if bones['rigid'] else 'elastic'} bones (rigid ones move the markers by "
                      f"{bones['difference']:.2g} mm)")
        print(f"  --tol {a['tol']:g} mm: P{a.get('degree', 2)}, {where} "
              f"after {len(a['levels'])} meshes, estimated marker error {est}"
              + ("" if a["met"] else f" (NOT met: {a['stop']})"))
    if hist:
        print("  last step |R|: " + " ".join(f"{r:.1e}" for r in hist[-5:]))
    for name, m in (result["markers"] or {}).items():
        print(f"  marker {name}: ({', '.join(f'{p:.2f}' for p in m['position'])}) mm, "
              f"moved ({', '.join(f'{d:+.2f}' for d in m['displacement'])}) mm")
    for name, c in (result["cables"] or {}).items():
        print(f"  {c['kind']} {name}: tension {c['tension']:.3f} N, length {c['length']:.2f} mm")
    print(f"  results in {out}/ (result.json, solution.xdmf, deformed.png), "
          f"{result['timings']['total']:.1f} s")


def _stdio() -> None:
    """Never fail on printing a path that is not valid UTF-8."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.reconfigure(errors="backslashreplace")
        except (AttributeError, ValueError, OSError):
            pass


def _import_gmsh() -> None:
    """Import gmsh now (it resets SIGINT to the default action on import) and put our handlers back.

    Imported later, deep inside meshing or DOLFINx, it would leave Ctrl-C
    killing the process without clean-up until the next re-install.
    """
    from . import interrupts
    with interrupts.held():
        try:
            import gmsh  # noqa: F401
        except ImportError:
            pass


def _run(argv) -> tuple[int, str | None, bool]:
    """(exit status, message to print or None, whether the command ended normally)."""
    from . import outdir, resources
    from .design import DesignError
    from .interrupts import Interrupted

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
            from . import interrupts
            outdir.ON_COMMIT = interrupts.finish
        return args.handler(args), None, True
    except (InputError, DesignError, outdir.OutputError) as exc:
        return EXIT_INPUT, str(exc), False
    except Interrupted as exc:
        return exc.code, "interrupted", False
    except KeyboardInterrupt:
        return 130, "interrupted", False
    except Exception as exc:  # a bug, not bad input: one line, and the traceback with -v
        from .interrupts import received
        if received() is not None:            # an interrupt that surfaced as another error
            return 128 + received(), "interrupted", False
        if verbosity >= 2:
            import traceback
            traceback.print_exc()
        hint = "" if verbosity >= 2 else " (run with -v for the traceback)"
        return EXIT_INTERNAL, f"internal error: {type(exc).__name__}: {exc}{hint}", False
    finally:
        outdir.ON_COMMIT = None
        outdir.release()                      # every output lock this process still holds
        resources.FORCED = False


def main(argv=None) -> int:
    """The skelfem command; returns the exit status (see the module doc)."""
    from . import interrupts, mpiguard

    interrupts.install()
    _stdio()
    ctl = None
    try:
        if mpiguard.world_size_hint() > 1:
            from mpi4py import MPI
            ctl = mpiguard.control(MPI.COMM_WORLD)
        code, message, in_step = _run(argv)
        code, message = mpiguard.agree(ctl, code, message, in_step, say=_print_error)
        if message:
            error(message)
        return code
    except interrupts.Interrupted as exc:     # between the pieces above
        error("interrupted")
        return exc.code
    finally:
        if ctl is not None:
            ctl.Free()
        if argv is None:
            interrupts.ignore()               # the command is over: its status stands through the exit
        else:
            interrupts.uninstall()            # called in process (tests): Python's defaults again


if __name__ == "__main__":    # prefer `python -m skelfem`: one copy of this module
    from skelfem.cli import main as _main
    sys.exit(_main())
