"""``skelfem simulate``: a static equilibrium (or a run in time, or a --tol ladder) to files.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path
from .common import EXIT_OK, EXIT_SOLVE, InputError, error, load, prepare, reserve_output

log = logging.getLogger("skelfem")


def simulate(args) -> int:
    from mpi4py import MPI

    from ..jobs.run import write_results

    t0 = time.perf_counter()
    design = load(args)
    targets = parse_tol(args.tol, design)
    args.tol = targets
    if args.tol is not None and design.dynamics is not None:
        raise InputError(f"{args.design}: --tol chooses the mesh of a static run; a design with [dynamics] "
                         "sets [mesh] by hand")
    if getattr(args, "adaptive", False) and args.tol is None:
        raise InputError("--adaptive: refines for --tol; give --tol ABS_MM too")
    if args.tol is not None and design.stages:
        raise InputError(f"{args.design}: --tol refines the mesh of one static solve; a design with [[stages]] "
                         "sets [mesh] by hand")
    if getattr(args, "estimate", False) and design.dynamics is not None:
        raise InputError(f"{args.design}: --estimate: a run in time ([dynamics]) has no error estimate yet; "
                         "it estimates static equilibria")
    if getattr(args, "estimate", False) and design.stages:
        raise InputError(f"{args.design}: --estimate: a design with [[stages]] has no error estimate from the "
                         "command line yet (Session.estimate() estimates the state after a stage)")
    if args.tol is not None and args.tol.bare and not design.markers:
        raise InputError(f"{args.design}: --tol ABS_MM needs at least one marker (its error is what it bounds); "
                         "name an observable instead (--tol cables.NAME.tension=TOL)")
    args.out = reserve_output(args, design)           # before any work: a bad --out is bad input
    extra = {}
    if args.tol is not None:
        design, session = prepare_tol(args, design)
        with session:
            solved, extra["accuracy"] = refine_to_tol(session, args.tol, getattr(args, "adaptive", False))
            if getattr(args, "estimate", False) and solved.converged:
                extra.update(session.estimate())
            result = write_results(session, solved, args.out, t0, picture=not args.no_picture, extra=extra)
    else:
        design, session = prepare(args)
        if design.dynamics is not None:
            return _simulate_in_time(args, design, session, t0, extra)
        if design.stages:
            return _simulate_stages(args, design, session, t0, extra)
        with session:
            solved = session.solve(estimate=getattr(args, "estimate", False))
            result = write_results(session, solved, args.out, t0, picture=not args.no_picture, extra=extra)
    if not solved.converged:
        error(f"{design.name}: solve failed ({solved.status}) after {solved.load_steps} load step(s); "
              f"{ADVICE.get(solved.status, ADVICE[None])}; details in {args.out / 'result.json'}")
        return EXIT_SOLVE
    if not args.quiet and MPI.COMM_WORLD.rank == 0:
        _summary(result, args.out)
    return EXIT_OK


def parse_tol(values: list[str] | None, design):
    """--tol's values: a bare ABS_MM (every marker) and/or NAME=TOL (observables), checked against the
    design before anything is meshed; Targets (skelfem.accuracy.targets) or None."""
    import math

    from ..accuracy.targets import Targets, check
    if not values:
        return None
    items, seen = [], set()
    for text in values:
        name, eq, number = str(text).rpartition("=")
        name = name.strip() if eq else None
        where = "--tol" if name is None else f"--tol {name}"
        try:
            tol = float(number)
        except ValueError:
            raise InputError(f"{where}: invalid float value {number!r} (give ABS_MM, or NAME=TOL)") from None
        if not (0 < tol < math.inf):
            raise InputError(f"{where}: must be a finite number > 0, got {number}")
        if name is not None and (why := check(design, name)):
            raise InputError(f"--tol {text}: {why}")
        if name in seen:
            raise InputError(f"--tol {text}: {'a bare tolerance' if name is None else name} is given twice")
        seen.add(name)
        items.append((name, tol))
    return Targets(tuple(items), design.dim)


ADVICE = {   # what to try after a failed solve, by its status
    None: "try more [solver].steps or a finer mesh",
    "friction_not_converged": "the friction limits did not settle (the stick/slip pattern of a tendon's via "
                              "points or of a contact kept changing, at every load step tried: more steps "
                              "rarely help); a smaller friction coefficient or gentler bends of the tendon's "
                              "path settle",
}


def prepare_tol(args, design):
    """--tol: design at the first size of skelfem.accuracy's ladder (P2), meshed; (that design, session)."""
    from mpi4py import MPI

    from ..accuracy import ladder
    from ..design.spec import DesignError
    from ..mesh.geometry import MeshingError
    from ..jobs.run import open_session

    try:
        first = ladder.first_level(design)
        log.info("--tol %s: P%d from h = %g mm, refined until the estimate meets it",
                 args.tol.spec(), ladder.DEGREE, first.mesh.size)
        return first, open_session(first, MPI.COMM_WORLD)
    except (DesignError, MeshingError) as exc:
        raise InputError(str(exc)) from None


def refine_to_tol(session, tol, adaptive: bool = False):
    """skelfem.accuracy.tol.refine, with mesh failures of a finer level as one-line input errors."""
    from ..accuracy import tol as accuracy
    from ..design.spec import DesignError
    from ..mesh.geometry import MeshingError
    try:
        return accuracy.refine(session, tol, adaptive)
    except (DesignError, MeshingError) as exc:
        raise InputError(str(exc)) from None


def _simulate_in_time(args, design, session, t0, extra) -> int:
    """simulate for a design with [dynamics]: the run in time and its files (see run.write_dynamic_results)."""
    from mpi4py import MPI

    from ..jobs.run import ProgressBar, write_dynamic_results

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


def _simulate_stages(args, design, session, t0, extra) -> int:
    """simulate for a design with [[stages]]: each stage in order, and the files (run.write_staged_results)."""
    from mpi4py import MPI

    from ..jobs.run import write_staged_results

    with session:
        result = write_staged_results(session, args.out, t0, picture=not args.no_picture, extra=extra)
    if not result["converged"]:
        failed = result["stages"][-1]
        done = [s["name"] for s in result["stages"][:-1]]
        error(f"{design.name}: stage {failed['name']} failed ({failed['status']}) after "
              f"{failed['load_steps']} load step(s); "
              + (f"stage(s) {', '.join(done)} completed (stages.xdmf); " if done else "")
              + ("" if failed["status"].startswith("no equilibrium") else
                 f"try more steps in stage {failed['name']} (steps = N) or a finer mesh; ")
              + f"details in {args.out / 'result.json'}")
        return EXIT_SOLVE
    if not args.quiet and MPI.COMM_WORLD.rank == 0:
        _summary(result, args.out)
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
        asked = (f"{a['tol']:g} mm" if not isinstance(a["tol"], dict)
                 else ", ".join(f"{k} {v:g}" for k, v in a["tol"].items()))
        if isinstance(a["tol"], dict) and a.get("estimated_error") is not None:
            est = f"{a['estimated_error']:.3g} of each tolerance"
        print(f"  --tol {asked}: P{a.get('degree', 2)}, {where} "
              f"after {len(a['levels'])} meshes, estimated {'marker ' if not isinstance(a['tol'], dict) else ''}"
              f"error {est}"
              + ("" if a["met"] else f" (NOT met: {a['stop']})"))
        for name, t in (a.get("targets") or {}).items():
            print(f"    {name}: estimated error {t['estimated_error']:.3g} (tolerance {t['tol']:g})")
        if a.get("warning"):
            print(f"  warning: {a['warning']}")
    for stage in result.get("stages", []):
        print(f"  stage {stage['name']}: {stage['status']} in {stage['newton_iterations']} Newton iterations over "
              f"{stage['load_steps']} step(s)")
    if result.get("events"):
        from ..fem.jumps import describe
        print(f"  jump: {describe(result['events'])}; a static answer is one of several here, try more load "
              "steps or a run in time ([dynamics])")
    if hist:
        print("  last step |R|: " + " ".join(f"{r:.1e}" for r in hist[-5:]))
    if "estimate" in result:
        e = result["estimate"]
        print(f"  --estimate: P{e['degree']} on the same mesh ({e['dofs']} DOFs), {e.get('status', '-')}; "
              "errors of every observable under errors in result.json")
    errors = result.get("errors") or {}

    def pm(name: str, fmt: str) -> str:           # " +- e" where the observable has an estimate
        e = (errors.get(name) or {}).get("error")
        return "" if e is None else f" +- {e:{fmt}}"
    for name, m in (result["markers"] or {}).items():
        bars = [pm(f"markers.{name}.{a}", ".2g") for a in "xyz"[:len(m["position"])]]
        print(f"  marker {name}: ({', '.join(f'{p:.2f}{e}' for p, e in zip(m['position'], bars))}) mm, "
              f"moved ({', '.join(f'{d:+.2f}' for d in m['displacement'])}) mm")
    for name, c in (result["cables"] or {}).items():
        print(f"  {c['kind']} {name}: tension {c['tension']:.3f}{pm(f'cables.{name}.tension', '.2g')} N, "
              f"length {c['length']:.2f} mm")
    files = "result.json, solution.xdmf, deformed.png" + (", stages.xdmf" if result.get("stages") else "")
    print(f"  results in {out}/ ({files}), "
          f"{result['timings']['total']:.1f} s")


