"""Command line: ``skelfem simulate DESIGN [--out DIR] [--set KEY=VALUE ...]``.

Exit status: 0 on success, 1 for bad input (one ``error:`` line on stderr),
2 when the solve does not converge (result.json says why).
"""
from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

log = logging.getLogger("skelfem")

EXIT_OK, EXIT_INPUT, EXIT_SOLVE = 0, 1, 2


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
    # FFCx/distutils chatter on first compilation goes to the root logger
    logging.getLogger().setLevel(logging.WARNING)
    for name in ("FFCx", "UFL", "ffcx", "ufl"):
        logging.getLogger(name).setLevel(logging.WARNING)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="skelfem", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)
    s = sub.add_parser("simulate", help="static equilibrium of a design")
    s.add_argument("design", type=Path, help="design file (TOML)")
    s.add_argument("--out", type=Path, default=None, help="output folder (default: results/<name>)")
    s.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override one design value, e.g. cables.flexor.contraction=8")
    s.add_argument("--no-picture", action="store_true", help="skip deformed.png")
    s.add_argument("-q", "--quiet", action="store_true", help="print only errors")
    s.add_argument("-v", "--verbose", action="store_true", help="print every Newton iteration")
    return p


def error(message: str) -> None:
    from mpi4py import MPI
    if MPI.COMM_WORLD.rank == 0:
        print(f"error: {message}", file=sys.stderr)


def simulate(args) -> int:
    from mpi4py import MPI

    from .design import DesignError, load_design
    from .geometry import MeshingError, mesh_design
    from .output import plot_deformed, result_dict, write_json, write_xdmf
    from .scene import Scene
    from .solver import NewtonSolver

    comm = MPI.COMM_WORLD
    t0 = time.perf_counter()
    try:
        design = load_design(args.design, args.overrides)
    except DesignError as exc:
        error(str(exc))
        return EXIT_INPUT
    out = args.out or Path("results") / design.name
    if out.exists() and not out.is_dir():
        error(f"{out}: output path exists and is not a folder")
        return EXIT_INPUT
    log.info("%s: meshing (size %g mm, P%d)", design.name, design.mesh.size, design.mesh.degree)
    try:
        tm = mesh_design(design, comm)
        t_mesh = time.perf_counter()
        scene = Scene(design, tm)
    except (DesignError, MeshingError) as exc:
        error(str(exc))
        return EXIT_INPUT
    solver = NewtonSolver(scene, design.solver)
    t_compile = time.perf_counter()
    log.info("%s: %d DOFs, %d cells; solving in %d load step(s)", design.name,
             scene.V.dofmap.index_map.size_global * scene.bs,
             tm.mesh.topology.index_map(tm.mesh.topology.dim).size_global, design.solver.steps)
    report = solver.solve(design.solver.steps)
    t_solve = time.perf_counter()
    timings = {"mesh": t_mesh - t0, "compile": t_compile - t_mesh, "solve": t_solve - t_compile}
    timings["total"] = time.perf_counter() - t0
    result = result_dict(design, scene, report, timings)
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
    if report.converged:
        write_xdmf(out / "solution.xdmf", scene) if comm.size == 1 else None
        if not args.no_picture and comm.size == 1:
            pulled = [f"{c.name} u={c.contraction:g} mm" for c in design.cables
                      if c.kind == "tendon" and c.contraction > 0]
            title = f"{design.name}: " + (", ".join(pulled) if pulled else "no contraction")
            plot_deformed(out / "deformed.png", scene, title)
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
        print(f"  marker {name}: ({m['position'][0]:.2f}, {m['position'][1]:.2f}) mm, "
              f"moved ({', '.join(f'{d:+.2f}' for d in m['displacement'])}) mm")
    for name, c in (result["cables"] or {}).items():
        print(f"  {c['kind']} {name}: tension {c['tension']:.3f} N, length {c['length']:.2f} mm")
    print(f"  results in {out}/ (result.json, solution.xdmf, deformed.png), "
          f"{result['timings']['total']:.1f} s")


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    setup_logging(0 if args.quiet else (2 if args.verbose else 1))
    if args.command == "simulate":
        return simulate(args)
    return EXIT_INPUT


if __name__ == "__main__":
    sys.exit(main())
