"""Command line: ``skelfem simulate DESIGN [--out DIR] [--set KEY=VALUE ...]``.

Exit status: 0 on success, 1 for bad input (one ``error:`` line on stderr),
2 when the solve does not converge (result.json says why), 3 for an
internal error.
"""
from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

log = logging.getLogger("skelfem")

EXIT_OK, EXIT_INPUT, EXIT_SOLVE, EXIT_INTERNAL = 0, 1, 2, 3


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
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="override one design value, e.g. cables.flexor.contraction=8")
    parser.add_argument("-q", "--quiet", action="store_true", help="print only errors")
    parser.add_argument("-v", "--verbose", action="store_true", help="print every Newton iteration")


# Modules that add sub-commands: each has add_parsers(subparsers), and every
# parser it adds sets `handler` (a function args -> exit status).
COMMAND_MODULES = ()


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="skelfem", description="Simulate and control cable-driven soft robots "
                                "with embedded skeletons.")
    sub = p.add_subparsers(dest="command", required=True)
    s = sub.add_parser("simulate", help="static equilibrium of a design")
    common_arguments(s)
    s.add_argument("--no-picture", action="store_true", help="skip deformed.png")
    s.set_defaults(handler=simulate)
    import importlib
    for name in COMMAND_MODULES:
        importlib.import_module(name).add_parsers(sub)
    return p


class InputError(Exception):
    """Bad input found by a command; main prints it as one error line and exits 1."""


def error(message: str) -> None:
    from mpi4py import MPI
    if MPI.COMM_WORLD.rank == 0:
        print(f"error: {message}", file=sys.stderr)


def prepare(args):
    """Load, validate and mesh args.design; returns (design, scene, timings) or raises InputError."""
    from mpi4py import MPI

    from .design import DesignError, load_design
    from .geometry import MeshingError, mesh_design
    from .scene import Scene

    t0 = time.perf_counter()
    try:
        design = load_design(args.design, args.overrides)
        out = output_folder(args, design)
        log.info("%s: meshing (size %g mm, P%d)", design.name, design.mesh.size, design.mesh.degree)
        tm = mesh_design(design, MPI.COMM_WORLD)
        t_mesh = time.perf_counter()
        scene = Scene(design, tm)
    except (DesignError, MeshingError) as exc:
        raise InputError(str(exc)) from None
    args.out = out
    return design, scene, {"mesh": t_mesh - t0, "compile": time.perf_counter() - t_mesh}


def output_folder(args, design) -> Path:
    out = args.out or Path("results") / design.name
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: output path exists and is not a folder")
    return out


def simulate(args) -> int:
    from mpi4py import MPI

    from .output import plot_deformed, plot_deformed_3d, result_dict, write_json, write_xdmf
    from .solver import NewtonSolver

    comm = MPI.COMM_WORLD
    t0 = time.perf_counter()
    design, scene, timings = prepare(args)
    out = args.out
    t1 = time.perf_counter()
    solver = NewtonSolver(scene, design.solver)
    timings["compile"] += time.perf_counter() - t1
    log.info("%s: %d DOFs, %d cells; solving in %d load step(s)", design.name,
             scene.V.dofmap.index_map.size_global * scene.bs,
             scene.mesh.topology.index_map(scene.mesh.topology.dim).size_global, design.solver.steps)
    t2 = time.perf_counter()
    report = solver.solve(design.solver.steps)
    timings["solve"] = time.perf_counter() - t2
    timings["total"] = time.perf_counter() - t0
    result = result_dict(design, scene, report, timings)
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
        for stale in ("solution.xdmf", "solution.h5", "deformed.png"):
            (out / stale).unlink(missing_ok=True)    # never leave an old equilibrium beside a new result
    if report.converged and comm.size == 1:
        write_xdmf(out / "solution.xdmf", scene)
        if not args.no_picture:
            pulled = [f"{c.name} u={c.contraction:g} mm" for c in design.cables
                      if c.kind == "tendon" and c.contraction > 0]
            title = f"{design.name}: " + (", ".join(pulled) if pulled else "no contraction")
            (plot_deformed if design.dim == 2 else plot_deformed_3d)(out / "deformed.png", scene, title)
    result["timings"]["total"] = round(time.perf_counter() - t0, 4)
    if comm.rank == 0:
        write_json(out / "result.json", result)
    if not report.converged:
        error(f"{design.name}: solve failed ({report.status}) after {report.load_steps} load step(s); "
              f"try more [solver].steps or a finer mesh; details in {out / 'result.json'}")
        return EXIT_SOLVE
    if not args.quiet and comm.rank == 0:
        _summary(result, out)
    return EXIT_OK


def _summary(result: dict, out: Path) -> None:
    hist = result["residual_history"][-1] if result["residual_history"] else []
    print(f"{result['design']}: converged in {result['newton_iterations']} Newton iterations "
          f"over {result['load_steps']} load step(s); min det F = {result['min_jacobian']:.3f}")
    if hist:
        print("  last step |R|: " + " ".join(f"{r:.1e}" for r in hist[-5:]))
    for name, m in (result["markers"] or {}).items():
        print(f"  marker {name}: ({', '.join(f'{p:.2f}' for p in m['position'])}) mm, "
              f"moved ({', '.join(f'{d:+.2f}' for d in m['displacement'])}) mm")
    for name, c in (result["cables"] or {}).items():
        print(f"  {c['kind']} {name}: tension {c['tension']:.3f} N, length {c['length']:.2f} mm")
    print(f"  results in {out}/ (result.json, solution.xdmf, deformed.png), "
          f"{result['timings']['total']:.1f} s")


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    verbosity = 0 if getattr(args, "quiet", False) else (2 if getattr(args, "verbose", False) else 1)
    setup_logging(verbosity)
    try:
        return args.handler(args)
    except InputError as exc:
        error(str(exc))
        return EXIT_INPUT
    except KeyboardInterrupt:
        error("interrupted")
        return 130
    except Exception as exc:  # a bug, not bad input: say so in one line unless -v asks for the traceback
        if verbosity >= 2:
            raise
        error(f"internal error: {type(exc).__name__}: {exc} (run with -v for the traceback)")
        return EXIT_INTERNAL


if __name__ == "__main__":
    sys.exit(main())
