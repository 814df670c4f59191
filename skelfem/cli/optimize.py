"""``skelfem optimize``: tendon schedules that put a marker on timed targets (skelfem.analysis.optimize).

    skelfem optimize DESIGN --marker M (--target X Y [--at T] | --csv TIMED_TARGETS) [--knots K]
                     [--max-contraction TENDON=MM ...] [--smooth RHO] [--tol MM] [--max-evaluations N]
                     [--method lbfgsb|gauss-newton] [--out DIR]

The design needs [dynamics] (its dt, duration, integrator and damping set the
runs). Writes optimize.json (schedules, achieved positions, error in mm,
reached, iterations, forward runs and adjoint (or tangent) sweeps, time), schedules.csv
(time and every tendon's contraction at the knots) and optimize.png (the
marker's path over the run with the targets, on the final pose). An
unreachable target is not an error: the best schedules found are written
with reached = false (exit 0). Bad input: one ``error:`` line, exit 1,
nothing written.
"""
from __future__ import annotations

import logging
import math
import time
from pathlib import Path

import numpy as np

from . import common as cli
from ..io import outdir
from ..viz.plots import ACHIEVED_COLOR, TARGET_COLOR, include_points
from ..io.files import FORMAT, atomic_write, write_csv, write_json

MAX_KNOTS = 200
MAX_EVALUATIONS = 10_000


def add_parsers(subparsers) -> None:
    p = subparsers.add_parser("optimize", help="tendon schedules that bring a marker to timed targets (dynamics)")
    cli.common_arguments(p)
    p.add_argument("--marker", required=True, help="name of the marker to steer")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--target", type=float, nargs="+", metavar="X", help="target position of the marker, mm")
    src.add_argument("--csv", type=Path, help="timed targets, one per line: t,x,y (3D: t,x,y,z); a header is allowed")
    p.add_argument("--at", type=float, default=None, metavar="T", help="time of --target, s (default: the duration)")
    p.add_argument("--knots", type=int, default=4, metavar="K", help="knots of each schedule, evenly spaced over "
                   "[0, duration] (default 4)")
    p.add_argument("--max-contraction", action="append", default=[], metavar="TENDON=MM",
                   help="upper bound on one tendon's contraction (repeatable; default 25%% of its length)")
    p.add_argument("--smooth", type=float, default=None, metavar="RHO",
                   help="smoothness regulariser rho sum (u_k+1 - u_k)^2 (default 1e-6)")
    p.add_argument("--tol", type=float, default=None, metavar="MM",
                   help="distance that counts as reached (default 1e-3 x finger length)")
    p.add_argument("--method", choices=["lbfgsb", "gauss-newton"], default="lbfgsb",
                   help="L-BFGS-B on adjoint gradients (default) or bounded Gauss-Newton on forward sensitivities")
    p.add_argument("--max-evaluations", type=int, default=60, metavar="N",
                   help="forward runs (each with its adjoint sweep) allowed (default 60)")
    p.set_defaults(handler=optimize_command)


DEFAULT_STEPS = 50      # time steps of the run when the design has no [dynamics]


def _duration_from_targets(args, design) -> float:
    """The run's duration for a design without [dynamics]: --at, or the CSV's last time."""
    from .control import read_targets
    if args.csv is not None:
        times = [float(r[0]) for r in read_targets(args.csv, design.dim + 1)]
        T = max(times) if times else math.nan
        where = f"--csv {args.csv}: its last time"
    elif args.at is not None:
        T, where = float(args.at), "--at"
    else:
        raise cli.InputError(f"{args.design}: dynamics: missing (optimize plans motions in time: give --at T, "
                             "the target's time, or add a [dynamics] section)")
    if not (math.isfinite(T) and T > 0.0):
        raise cli.InputError(f"{where} {T:g}: must be a finite time > 0 s (the run's duration, the design having "
                             "no [dynamics])")
    return T


def _check(args, design) -> list:
    """The timed targets [(t, point)]; InputError for anything wrong (before meshing)."""
    from .control import contraction_bounds, coordinate_rows, read_targets
    if design.dynamics is None:
        raise cli.InputError(f"{args.design}: dynamics: missing (optimize plans motions in time: add a "
                             "[dynamics] section)")
    if design.dynamics.damping_stiffness > 0.0:
        raise cli.InputError(f"{args.design}: dynamics.damping.stiffness: optimize's adjoint does not "
                             "differentiate stiffness damping (set it to 0, or use mass damping)")
    if args.marker not in design.markers:
        have = ", ".join(design.markers) or "none"
        raise cli.InputError(f"{args.design}: marker '{args.marker}' not in design (have: {have})")
    tendons = [c.name for c in design.tendons]
    if not tendons:
        raise cli.InputError(f"{args.design}: cables: optimize needs at least one tendon (the design has none)")
    for name in contraction_bounds(args.max_contraction):
        if name not in tendons:
            raise cli.InputError(f"--max-contraction: '{name}' is not a tendon of the design "
                                 f"(tendons: {', '.join(tendons)})")
    if not 2 <= args.knots <= MAX_KNOTS:
        raise cli.InputError(f"--knots {args.knots}: must be >= 2 and <= {MAX_KNOTS}")
    if args.smooth is not None and not 0 <= args.smooth < math.inf:
        raise cli.InputError(f"--smooth {args.smooth:g}: must be a finite number >= 0")
    if args.tol is not None and not 0 < args.tol < math.inf:
        raise cli.InputError(f"--tol {args.tol:g}: must be a finite number > 0")
    if not 1 <= args.max_evaluations <= MAX_EVALUATIONS:
        raise cli.InputError(f"--max-evaluations {args.max_evaluations}: must be >= 1 and <= {MAX_EVALUATIONS}")
    T = design.dynamics.duration
    dim = design.dim
    if args.csv is not None:
        if args.at is not None:
            raise cli.InputError("--at goes with --target, not with --csv (the CSV has the times)")
        rows = read_targets(args.csv, dim + 1)
        targets = [(float(r[0]), r[1:]) for r in rows]
    else:
        point = coordinate_rows(args.target, dim, "--target")
        if len(point) != 1:
            raise cli.InputError(f"--target: expected {dim} numbers, got {len(args.target)}")
        at = T if args.at is None else args.at
        targets = [(float(at), point[0])]
    for t, _ in targets:
        if not (math.isfinite(t) and 0.0 < t <= T * (1 + 1e-12)):
            raise cli.InputError(f"target time {t:g} s: must lie in (0, {T:g}] (the run's duration)")
    return targets


def optimize_dict(design, marker, targets, res, timings: dict, method: str = "lbfgsb") -> dict:
    return {
        "format": FORMAT, "design": design.name, "marker": marker,
        "targets": [{"time": t, "target": [float(v) for v in p], "position": [float(v) for v in y],
                     "error": float(e)} for (t, p), y, e in zip(targets, res.positions, res.errors)],
        "error": res.error, "reached": res.reached, "status": res.status,
        "schedules": {n: [[float(t), float(u)] for t, u in zip(res.knot_times, row)]
                      for n, row in zip(res.names, res.schedules)},
        "max_contraction": {n: float(u) for n, u in zip(res.names, res.upper)},
        "objective": res.objective, "iterations": res.iterations, "forward_runs": res.forward_runs,
        "adjoint_sweeps": res.adjoint_sweeps, "failed_runs": res.failed_runs, "method": method,
        "gradient": res.gradient,
        "history": [{"objective": j, "error": e} for j, e in res.history],
        "dynamics": {"dt": design.dynamics.dt, "duration": design.dynamics.duration,
                     "integrator": design.dynamics.integrator},
        "time": round(res.time, 4), "timings": {k: round(float(v), 4) for k, v in timings.items()},
    }


def plot_optimize(path: Path, model, trajectory: list, marker: str, targets, res, title: str) -> None:
    """The marker's path over the run, the targets and where it was at their times, on the final pose."""
    from matplotlib.figure import Figure

    from ..viz.plots import plot_deformed
    fig = Figure(figsize=(6, 7), dpi=120)
    ax = fig.subplots()
    plot_deformed(None, model, title, ax=ax)
    if ax.get_legend() is not None:
        ax.get_legend().remove()
    path_xy = np.array([[r[f"{marker}_x"], r[f"{marker}_y"]] for r in trajectory])
    ax.plot(path_xy[:, 0], path_xy[:, 1], "-", color="#555555", lw=1.2, zorder=5, label=f"{marker} path")
    pts = np.array([p[:2] for _, p in targets])
    got = np.array([y[:2] for y in res.positions])
    ax.plot(pts[:, 0], pts[:, 1], "x", color=TARGET_COLOR, ms=10, mew=2.5, zorder=6, label="target")
    ax.plot(got[:, 0], got[:, 1], "o", mfc="none", mec=ACHIEVED_COLOR, ms=11, mew=2, zorder=6,
            label="at the target's time")
    include_points(ax, np.vstack([pts, got, path_xy]))
    ax.legend(handles=ax.get_lines()[-3:], loc="lower left", fontsize=8)
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))


def optimize_command(args) -> int:
    from mpi4py import MPI

    from .control import contraction_bounds
    from ..analysis.optimize import DEFAULT_SMOOTH, optimize_schedules

    t0 = time.perf_counter()
    if MPI.COMM_WORLD.size > 1:
        raise cli.InputError(f"{args.design}: optimize runs on one MPI process (got {MPI.COMM_WORLD.size})")
    design = cli.load(args)
    if design.dynamics is None:          # a run as long as the last target, in DEFAULT_STEPS steps
        T = _duration_from_targets(args, design)
        args.overrides = list(args.overrides) + [f"dynamics.duration={T!r}", f"dynamics.dt={T / DEFAULT_STEPS!r}"]
        design = cli.load(args)
        cli.log.info("%s: no [dynamics]: a run of %g s in %d steps (%s, no damping)", design.name, T,
                     DEFAULT_STEPS, design.dynamics.integrator)
    targets = _check(args, design)
    design, session = cli.prepare(args, kind="optimize")
    timings = dict(session.timings)
    if not args.verbose:
        cli.log.setLevel(logging.WARNING)
    with session:
        try:
            res = optimize_schedules(session, args.marker, targets, knots=args.knots,
                                     upper=contraction_bounds(args.max_contraction),
                                     smooth=DEFAULT_SMOOTH if args.smooth is None else args.smooth,
                                     tol=args.tol, max_evaluations=args.max_evaluations, method=args.method)
        except RuntimeError as exc:
            cli.error(f"{design.name}: {exc}; nothing written to {args.out}")
            return cli.EXIT_SOLVE
        final = session.run_in_time()                        # the best schedules, for the picture
        timings.update(optimize=res.time, total=time.perf_counter() - t0)
        result = optimize_dict(session.design, args.marker, targets, res, timings, args.method)
        header = ["time"] + list(res.names)
        rows = [dict(zip(header, [float(t), *map(float, res.schedules[:, k])]))
                for k, t in enumerate(res.knot_times)]
        with outdir.publish(args.out, kind="optimize") as stage:
            stage.run(write_json, stage.path / "optimize.json", result)
            stage.run(write_csv, stage.path / "schedules.csv", header, rows)
            if design.dim == 2:
                stage.run(plot_optimize, stage.path / "optimize.png", session.model, final.report.trajectory,
                          args.marker, targets, res,
                          f"{design.name}: {args.marker}, error {res.error:.3g} mm "
                          f"({'reached' if res.reached else 'not reached'})")
    if not args.quiet:
        state = "reached" if res.reached else f"not reached ({res.status})"
        print(f"{design.name}: marker {args.marker}, largest error {res.error:.3g} mm, {state}; "
              f"{res.forward_runs} forward runs + {res.adjoint_sweeps} adjoint sweeps, {res.time:.1f} s")
        for n, row in zip(res.names, res.schedules):
            print(f"  {n}: " + ", ".join(f"{u:.3f}" for u in row) + " mm at t = "
                  + ", ".join(f"{t:.3g}" for t in res.knot_times) + " s")
        print(f"  results in {args.out}/ (optimize.json, schedules.csv"
              + (", optimize.png)" if design.dim == 2 else ")"))
    return cli.EXIT_OK
