"""Command line for control: ``skelfem ik`` (one target) and ``skelfem track`` (a path).

    skelfem ik DESIGN --marker NAME --target X Y [--max-contraction TENDON=MM ...] [--reg RHO]
    skelfem track DESIGN --marker NAME (--line X0 Y0 X1 Y1 --steps N | --csv FILE)

Both start from the design's own contractions (clipped to the bounds), solved
with its [solver] steps, and write into --out (default results/<name>):
ik.json + ik.png, or track.csv + track.json + track.png. An unreachable target
is not an error: the closest admissible pose is written with reached = false
(exit 0). Bad input is one ``error:`` line (exit 1, nothing written); a failed
initial equilibrium exits 2.
"""
from __future__ import annotations

import argparse
import csv
import hashlib
import io
import json
import logging
import math
import os
import time
from pathlib import Path

import numpy as np

from . import common as cli
from ..io import outdir
from ..viz.plots import ACHIEVED_COLOR, TARGET_COLOR, draw_track, include_points
from ..io.files import FORMAT, InputTooLarge, atomic_write, read_bounded, write_json, write_text



def add_parsers(subparsers) -> None:
    """Add the ``ik`` and ``track`` sub-commands."""
    p = subparsers.add_parser("ik", help="Soft IK: tendon contractions that bring a marker to a target")
    _control_arguments(p)
    p.add_argument("--target", type=float, nargs="+", required=True, metavar="X",
                   help="target position of the marker, mm (one value per dimension)")
    p.set_defaults(handler=ik_command)

    t = subparsers.add_parser("track", help="Soft IK along a sequence of targets, warm-started")
    _control_arguments(t)
    src = t.add_mutually_exclusive_group(required=True)
    src.add_argument("--line", type=float, nargs="+", metavar="X",
                     help="start and end of a straight target path, e.g. X0 Y0 X1 Y1")
    src.add_argument("--csv", type=Path, help="targets, one per line: x,y (a header line is allowed)")
    t.add_argument("--steps", type=int, default=None, help="number of targets on --line (both ends included)")
    t.set_defaults(handler=track_command)


def _control_arguments(p: argparse.ArgumentParser) -> None:
    cli.common_arguments(p)
    p.add_argument("--marker", required=True, help="name of the marker to steer")
    p.add_argument("--max-contraction", action="append", default=[], metavar="TENDON=MM",
                   help="upper bound on one tendon's contraction (repeatable); lower bound is 0")
    p.add_argument("--reg", type=float, default=0.0, metavar="RHO",
                   help="regulariser rho in |y - y'|^2 + rho |u|^2 (default 0)")
    p.add_argument("--tol", type=float, default=None, metavar="MM",
                   help="distance that counts as reached (default 1e-3 x finger length)")
    p.add_argument("--max-solves", type=int, default=40, metavar="N",
                   help="forward solves allowed per target (default 40)")


# -- input ---------------------------------------------------------------------------------------
MAX_SOLVES = 10_000        # forward solves per target
MAX_TARGETS = 100_000      # targets of one track
MAX_CSV_BYTES = 16 * 2 ** 20     # a target file is at most MAX_TARGETS short lines


def contraction_bounds(items: list[str]) -> dict:
    """{tendon: u_max} from TENDON=MM strings."""
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        try:
            v = float(value)
        except ValueError:
            sep, v = "", 0.0
        if not sep or not name.strip() or not 0 < v < math.inf:
            raise cli.InputError(f"--max-contraction {item}: expected TENDON=MM with MM a finite number > 0")
        out[name.strip()] = v
    return out


TOL_RANGE = (1e-9, 0.5)     # --tol relative to the body's largest extent


def _check_numbers(args) -> None:
    if not 0 <= args.reg < math.inf:
        raise cli.InputError(f"--reg {args.reg:g}: must be a finite number >= 0")
    if args.tol is not None and not 0 < args.tol < math.inf:
        raise cli.InputError(f"--tol {args.tol:g}: must be a finite number > 0")
    if not 1 <= args.max_solves <= MAX_SOLVES:
        raise cli.InputError(f"--max-solves {args.max_solves}: must be >= 1 and <= {MAX_SOLVES}")


def _peek(args):
    """The design as read (cheap, before meshing), to check names and targets early."""
    design = cli.load(args)
    if args.marker not in design.markers:
        have = ", ".join(design.markers) or "none"
        raise cli.InputError(f"{args.design}: marker '{args.marker}' not in design (have: {have})")
    tendons = [c.name for c in design.cables if c.kind == "tendon"]
    if not tendons:
        raise cli.InputError(f"{args.design}: cables: {args.command} needs at least one tendon to steer the "
                             "marker (the design has none)")
    if args.tol is not None:
        from ..design.sections import body_extent
        big = float(np.max(body_extent(design)))
        if not TOL_RANGE[0] * big <= args.tol <= TOL_RANGE[1] * big:
            # a larger one counted every target as reached; a smaller one lies below what Newton resolves
            raise cli.InputError(f"--tol {args.tol:g}: must lie in "
                                 f"[{TOL_RANGE[0] * big:.3g}, {TOL_RANGE[1] * big:.3g}] "
                                 f"mm for this design ({TOL_RANGE[0]:g} to {TOL_RANGE[1]:g} x its largest extent, "
                                 f"{big:.3g} mm)")
    for name in contraction_bounds(args.max_contraction):
        if name not in tendons:
            raise cli.InputError(f"--max-contraction: '{name}' is not a tendon of the design "
                                 f"(tendons: {', '.join(tendons) or 'none'})")
    return design


def _setup(args):
    """Design, model and SoftIK from the arguments; InputError for bad input."""
    from mpi4py import MPI
    if MPI.COMM_WORLD.size > 1:
        raise cli.InputError(f"{args.design}: {args.command} runs on one MPI process "
                             f"(got {MPI.COMM_WORLD.size}); use `skelfem sweep` to spread runs over ranks")
    from ..analysis.control import SoftIK

    design, session = cli.prepare(args, kind=args.command)
    model, timings = session.model, dict(session.timings)
    ik = SoftIK(session, args.marker, upper=contraction_bounds(args.max_contraction), reg=args.reg, tol=args.tol,
                max_solves=args.max_solves)
    if not args.verbose:                        # one line per target, not per Newton solve
        cli.log.setLevel(logging.WARNING)
    return design, model, ik, timings


def coordinate_rows(values: list[float], dim: int, what: str) -> np.ndarray:
    if len(values) % dim:
        raise cli.InputError(f"{what}: expected a multiple of {dim} coordinates, got {len(values)}")
    a = np.asarray(values, dtype=float).reshape(-1, dim)
    if not np.all(np.isfinite(a)):
        raise cli.InputError(f"{what}: coordinates must be finite numbers, got {' '.join(f'{v:g}' for v in values)}")
    if np.abs(a).max(initial=0.0) > 1e7:
        raise cli.InputError(f"{what}: coordinates must lie within +-1e7 mm")
    return a


def read_targets(path: Path, dim: int) -> np.ndarray:
    """Targets from a CSV file: one point per line, comma or whitespace separated."""
    try:
        text = read_bounded(path, MAX_CSV_BYTES, "target file")
    except InputTooLarge as exc:
        raise cli.InputError(str(exc)) from None
    except OSError as exc:
        raise cli.InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    except (UnicodeDecodeError, ValueError):
        raise cli.InputError(f"{path}: not a text (UTF-8) file") from None
    rows = []
    for n, line in enumerate(text.splitlines(), start=1):
        fields = [f for f in line.replace(",", " ").split() if f]
        if not fields or line.lstrip().startswith("#"):
            continue
        try:
            values = [float(f) for f in fields]
        except ValueError:
            if not rows and n == _first_content_line(text):
                continue                          # a header
            raise cli.InputError(f"{path}: line {n}: expected {dim} numbers, got {line.strip()[:60]!r}") from None
        if len(values) != dim or not np.all(np.isfinite(values)) or max(map(abs, values)) > 1e7:
            raise cli.InputError(f"{path}: line {n}: expected {dim} finite numbers, got {line.strip()[:60]!r}")
        rows.append(values)
        if len(rows) > MAX_TARGETS:
            raise cli.InputError(f"{path}: more than {MAX_TARGETS} targets")
    if not rows:
        raise cli.InputError(f"{path}: no targets")
    return np.array(rows)


def _first_content_line(text: str) -> int:
    for n, line in enumerate(text.splitlines(), start=1):
        if line.strip() and not line.lstrip().startswith("#"):
            return n
    return 0


def _track_targets(args, dim: int) -> np.ndarray:
    if args.csv is not None:
        if args.steps is not None:
            raise cli.InputError("--steps goes with --line, not with --csv")
        return read_targets(args.csv, dim)
    ends = coordinate_rows(args.line, dim, "--line")
    if len(ends) != 2:
        raise cli.InputError(f"--line: expected {2 * dim} numbers (start and end), got {len(args.line)}")
    if args.steps is None or not 2 <= args.steps <= MAX_TARGETS:
        raise cli.InputError(f"--line needs --steps N with 2 <= N <= {MAX_TARGETS}")
    from ..analysis.control import line_targets
    return line_targets(ends, args.steps)


def _settle(design, ik, out: Path) -> float | None:
    """Initial equilibrium at the design's contractions; returns its time, None on failure."""
    from ..fem.newton import SolveError
    t0 = time.perf_counter()
    try:
        ik.settle(design.solver.steps)
    except SolveError as exc:
        cli.error(f"{design.name}: initial {exc}; nothing written to {out}")
        return None
    return time.perf_counter() - t0


# -- results as numbers ------------------------------------------------------------------------------
def _named(names, values) -> dict:
    return {n: float(v) for n, v in zip(names, values)}


def tensions(model) -> dict:
    """Cable tensions k max(0, l - L) at the model's state, N."""
    u = model.u.x.array
    return {t.name: float(t.cable.tension(u, t.rest_length)) for t in model.terms_in("cables")}


def ik_dict(design, ik, res, timings: dict) -> dict:
    """ik.json: the pose Soft IK found for one target."""
    return {
        "format": FORMAT, "design": design.name, "marker": ik.marker,
        "target": [float(v) for v in res.target], "position": [float(v) for v in res.position],
        "error": float(res.error), "tol": float(ik.tol), "reached": bool(res.reached), "status": res.status,
        "contractions": _named(ik.names, res.contractions),
        "max_contraction": {n: (None if np.isinf(v) else float(v)) for n, v in zip(ik.names, ik.upper)},
        "reg": float(ik.reg), "body_extent": float(ik.length),
        "forward_solves": int(res.forward_solves), "failed_solves": int(res.failed_solves),
        "iterations": int(res.iterations), "errors": [float(e) for e in res.errors],
        "tensions": tensions(ik.model), "time": round(float(res.time), 4),
        "timings": {k: round(float(v), 4) for k, v in timings.items()},
    }


def track_rows(names, results, dim: int) -> tuple[list[str], list[list]]:
    """Header and rows of track.csv: one row per target."""
    axes = "xyz"[:dim]
    header = (["step"] + [f"target_{a}" for a in axes] + list(axes) + ["error", "reached"]
              + list(names) + ["forward_solves", "seconds"])
    rows = [[i, *r.target, *r.position, r.error, int(r.reached), *r.contractions, r.forward_solves,
             round(r.time, 4)] for i, r in enumerate(results)]
    return header, rows


def write_csv(path: Path, header, rows) -> None:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    w.writerows([[f"{v:.10g}" if isinstance(v, float) else v for v in row] for row in rows])
    write_text(path, buf.getvalue())


def track_summary(design, ik, results, timings: dict) -> dict:
    """track.json: how well the marker followed the path."""
    err = np.array([r.error for r in results])
    solves = np.array([r.forward_solves for r in results])
    secs = np.array([r.time for r in results])
    return {
        "format": FORMAT, "design": design.name, "marker": ik.marker, "targets": len(results),
        "reached": int(sum(r.reached for r in results)), "tol": float(ik.tol),
        "body_extent": float(ik.length),
        "error": {"max": float(err.max()), "mean": float(err.mean()), "median": float(np.median(err)),
                  "max_relative": float(err.max() / ik.length)},
        "forward_solves": {"total": int(solves.sum()), "min": int(solves.min()),
                           "median": float(np.median(solves)), "max": int(solves.max())},
        "seconds_per_target": {"median": float(np.median(secs)), "max": float(secs.max())},
        "contractions": {n: [float(v) for v in col] for n, col in
                         zip(ik.names, np.array([r.contractions for r in results]).T)},
        "reg": float(ik.reg),
        "timings": {k: round(float(v), 4) for k, v in timings.items()},
    }


# -- pictures -------------------------------------------------------------------------------------------
def plot_ik(path: Path, model, res, title: str = "") -> None:
    """The deformed pose with the target (cross) and the achieved marker (circle)."""
    if model.dim == 3:
        from ..viz.plots import plot_deformed_3d
        plot_deformed_3d(path, model, title, points=[(res.target, "red")])
        return
    from matplotlib.figure import Figure

    from ..viz.plots import plot_deformed
    fig = Figure(figsize=(6, 7), dpi=120)
    ax = fig.subplots()
    plot_deformed(None, model, title, ax=ax)
    _mark(ax, res.target, res.position)
    include_points(ax, np.array([res.target]))
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))


def _mark(ax, target, achieved):
    ax.plot(*target[:2], "x", color=TARGET_COLOR, ms=10, mew=2.5, zorder=6, label="target")
    ax.plot(*achieved[:2], "o", mfc="none", mec=ACHIEVED_COLOR, ms=11, mew=2, zorder=6, label="achieved")


def plot_track(path: Path, model, results, poses: list, title: str = "") -> None:
    """track.png: draw_track on its own figure (3D: the last pose with target and achieved paths)."""
    if model.dim == 3:
        from ..viz.plots import plot_deformed_3d
        targets = np.array([r.target for r in results])
        achieved = np.array([r.position for r in results])
        plot_deformed_3d(path, model, title, paths=[(targets, "red"), (achieved, "#1a7f37")])
        return
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 7), dpi=120)
    ax = fig.subplots()
    draw_track(ax, model, results, poses, title)
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))


# -- commands ------------------------------------------------------------------------------------------
def ik_command(args) -> int:
    t0 = time.perf_counter()
    _check_numbers(args)
    dim = _peek(args).dim
    target = coordinate_rows(args.target, dim, "--target")
    if len(target) != 1:
        raise cli.InputError(f"--target: expected {dim} numbers, got {len(args.target)}")
    design, model, ik, timings = _setup(args)
    settle = _settle(design, ik, args.out)
    if settle is None:
        return cli.EXIT_SOLVE
    res = ik.solve(target[0])
    timings.update(initial_solve=settle, ik=res.time, total=time.perf_counter() - t0)
    result = ik_dict(design, ik, res, timings)
    u_text = ", ".join(f"{u:.2f}" for u in res.contractions)
    with outdir.publish(args.out, kind="ik") as stage:         # both files or neither
        stage.run(write_json, stage.path / "ik.json", result)
        stage.run(plot_ik, stage.path / "ik.png", model, res,
                  f"{design.name}: Soft IK, error {res.error:.3g} mm\nu = ({u_text}) mm")
    if not args.quiet:
        _print_ik(result, args.out)
    return cli.EXIT_OK


def _print_ik(result: dict, out: Path) -> None:
    state = "reached" if result["reached"] else f"not reached ({result['status']})"
    print(f"{result['design']}: marker {result['marker']} at ({', '.join(f'{v:.2f}' for v in result['position'])})"
          f" mm, target ({', '.join(f'{v:.2f}' for v in result['target'])}): error {result['error']:.3g} mm,"
          f" {state}; {result['forward_solves']} forward solves, {result['time']:.2f} s")
    print("  contractions: " + ", ".join(f"{n} {u:.3f} mm" for n, u in result["contractions"].items()))
    print(f"  results in {out}/ (ik.json, ik.png)")


class TrackProgress:
    """Targets done so far, kept beside the output folder so an interrupted track resumes.

    ``.<out name>.track-partial/`` holds progress.json (a key over the design
    as overridden, the marker, bounds, regulariser, tolerances and targets;
    one entry per finished target) and the few poses the picture shows. A
    run with the same key continues after the last finished target, from its
    contractions; any other run starts afresh. The folder is removed once the
    track's results are published.
    """

    def __init__(self, out: Path, design, args, targets: np.ndarray):
        target = Path(os.path.realpath(out))
        self.folder = target.parent / f".{target.name}.track-partial"
        key = {"design": design.raw, "marker": args.marker,
               "bounds": sorted(contraction_bounds(args.max_contraction).items()),
               "reg": args.reg, "tol": args.tol, "max_solves": args.max_solves,
               "targets": np.asarray(targets, float).tolist()}
        self.key = hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()
        self.entries, self.poses = [], {}
        try:
            data = json.loads(read_bounded(self.folder / "progress.json", MAX_CSV_BYTES * 4, "progress file"))
            if isinstance(data, dict) and data.get("key") == self.key:
                self.entries = list(data["results"])
                for j in data.get("poses", []):
                    self.poses[int(j)] = np.load(self.folder / f"pose-{int(j)}.npy", allow_pickle=False)
                self.results()                    # every entry readable, or none is used
        except (OSError, ValueError, KeyError, TypeError, IndexError, AttributeError, EOFError):
            self.entries, self.poses = [], {}     # a broken progress file: start over
        if not self.entries and self.folder.exists():
            self.remove()                         # another run's (or a broken) progress

    def results(self):
        from ..analysis.control import IKResult
        out = []
        for e in self.entries:
            out.append(IKResult(np.array(e["target"]), np.array(e["position"]), np.array(e["contractions"]),
                                float(e["error"]), bool(e["reached"]), str(e["status"]), int(e["forward_solves"]),
                                int(e["failed_solves"]), int(e["iterations"]), float(e["time"]),
                                [float(x) for x in e["errors"]]))
        return out

    def add(self, res, pose=None) -> None:
        j = len(self.entries)
        self.folder.mkdir(exist_ok=True)
        if pose is not None:
            atomic_write(self.folder / f"pose-{j}.npy", lambda tmp: np.save(tmp, pose))
            self.poses[j] = pose
        self.entries.append({
            "target": [float(v) for v in res.target], "position": [float(v) for v in res.position],
            "contractions": [float(v) for v in res.contractions], "error": float(res.error),
            "reached": bool(res.reached), "status": res.status, "forward_solves": int(res.forward_solves),
            "failed_solves": int(res.failed_solves), "iterations": int(res.iterations), "time": float(res.time),
            "errors": [float(e) for e in res.errors]})
        write_json(self.folder / "progress.json", {"key": self.key, "results": self.entries,
                                                   "poses": sorted(self.poses)})

    def remove(self) -> None:
        import shutil
        shutil.rmtree(self.folder, ignore_errors=True)


def _resume(design, ik, done) -> bool:
    """Bring the IK to the contractions of the last finished target; False if that pose will not solve."""
    from ..fem.newton import SolveError
    if not done:
        return True
    ik.u = np.clip(np.asarray(done[-1].contractions, float), ik.lower, ik.upper)
    try:
        ik.settle(design.solver.steps)
    except SolveError:
        return False
    return True


def track_command(args) -> int:
    from ..analysis.control import track
    t0 = time.perf_counter()
    _check_numbers(args)
    targets = _track_targets(args, _peek(args).dim)
    design, model, ik, timings = _setup(args)
    progress = TrackProgress(args.out, design, args, targets)
    u0 = ik.u.copy()
    settle = _settle(design, ik, args.out)
    if settle is None:
        return cli.EXIT_SOLVE
    done = progress.results()
    if done and not _resume(design, ik, done):
        progress.remove()
        progress = TrackProgress(args.out, design, args, targets)
        done = []
        ik.u = u0
        settle = _settle(design, ik, args.out)
        if settle is None:
            return cli.EXIT_SOLVE
    from ..analysis.control import pose_indices
    show = pose_indices(len(targets))
    talk = not args.quiet
    if talk and done:
        print(f"  resuming after {len(done)} of {len(targets)} targets done before", flush=True)

    def on_target(i, res):
        j = len(done) + i
        progress.add(res, model.u.x.array.copy() if j in show else None)
        if talk:
            print(f"  {j + 1:3d}/{len(targets)} target ({', '.join(f'{v:.2f}' for v in res.target)}): "
                  f"error {res.error:.3g} mm {'' if res.reached else '(not reached) '}"
                  f"{res.forward_solves} solves {res.time:.2f} s", flush=True)

    results = done + track(ik, targets[len(done):], on_target)
    poses = [progress.poses[j] for j in show if j in progress.poses]
    timings.update(initial_solve=settle, track=sum(r.time for r in results), total=time.perf_counter() - t0)
    header, rows = track_rows(ik.names, results, model.dim)
    summary = track_summary(design, ik, results, timings)
    summary["resumed_after"] = len(done)
    with outdir.publish(args.out, kind="track") as stage:     # the three files together or none
        stage.run(write_csv, stage.path / "track.csv", header, rows)
        stage.run(write_json, stage.path / "track.json", summary)
        stage.run(plot_track, stage.path / "track.png", model, results, poses,
                  f"{design.name}: tracking with Soft IK, max error {summary['error']['max']:.3g} mm")
    progress.remove()
    if talk:
        print(f"{design.name}: {summary['reached']}/{len(results)} targets reached, max error "
              f"{summary['error']['max']:.3g} mm, {summary['forward_solves']['total']} forward solves, "
              f"{timings['track']:.1f} s; results in {args.out}/ (track.csv, track.json, track.png)")
    return cli.EXIT_OK
