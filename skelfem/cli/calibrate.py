"""``skelfem calibrate``: fit live parameters of a design to measured states (skelfem.analysis.calibrate).

    skelfem calibrate DESIGN --data DATA.csv --fit KEY [--fit KEY ...] [--sigma COLUMN=VALUE ...]
                      [--bounds KEY=LO,HI ...] [--holdout FRACTION] [--max-iterations N] [--starts N]
                      [--model-error inflate|refine|ignore] [--max-dofs N] [--out DIR]

The CSV has one row per measured state (the contract: skelfem.analysis.caldata
and docs/guide/calibration.md). Writes calibration.json (estimates, initial
values, std, 95 % intervals, correlations, unidentifiable groups, iterations,
residual RMS per column, the held-out error, the model's own error per column and
what the fit did with it), calibrated.toml (the design file
with the fitted values, its comments kept), fit.csv (data and model per row),
fit.png, residuals.png and parameters.png. Bad input: one ``error:`` line,
exit 1, nothing written, before any meshing. A row that does not converge at
the start (or whose sensitivity solve fails there): exit 2, nothing written.
A fit that does not converge: exit 2, its best state written as a partial
result (partial.toml instead of calibrated.toml, ``converged: false``).
"""
from __future__ import annotations

import logging
import math
import sys
import time
from pathlib import Path

from . import common as cli
from ..analysis.calerror import DEFAULT as MODEL_ERROR, MAX_DOFS, MODES
from ..io import outdir
from ..io.files import FORMAT, write_csv, write_json, write_text

MAX_ITERATIONS = 1000
MAX_STARTS = 100
MAX_DOFS_LIMIT = 100_000_000


def add_parsers(subparsers) -> None:
    p = subparsers.add_parser("calibrate", help="fit live parameters (E, nu, stiffnesses, ...) to measurements")
    cli.common_arguments(p)
    p.add_argument("--data", type=Path, required=True, metavar="DATA.csv",
                   help="one row per measured state: condition columns (--set keys) and measurement columns "
                        "(markers.M.x, cables.C.tension, grounds.G.force.x, pins.P.reaction.x); optional experiment")
    p.add_argument("--fit", action="append", required=True, metavar="KEY",
                   help="a live parameter to fit (repeatable), e.g. materials.ecoflex.E; a key that is also a "
                        "condition column is fitted as an offset added to it; a pattern such as "
                        "'cables.lig*.stiffness' fits one value shared by the keys it matches")
    p.add_argument("--sigma", action="append", default=[], metavar="COLUMN=VALUE",
                   help="a measurement column's standard deviation (repeatable; COLUMN may be a pattern such "
                        "as 'markers.*'); default 1 in the column's unit, the covariance then scaled by the fit")
    p.add_argument("--bounds", action="append", default=[], metavar="KEY=LO,HI", help="box for a fitted parameter")
    p.add_argument("--holdout", type=float, default=0.0, metavar="FRACTION",
                   help="fraction of rows kept out of the fit to measure the prediction error (default 0)")
    p.add_argument("--max-iterations", type=int, default=20, metavar="N",
                   help="trust-region Gauss-Newton iterations allowed per start (default 20)")
    p.add_argument("--starts", type=int, default=1, metavar="N",
                   help="fit from N starts: the design's values and N - 1 drawn within a decade of them "
                        "(seeded); the lowest misfit wins (default 1)")
    p.add_argument("--model-error", choices=MODES, default=MODEL_ERROR,
                   help="the model's own discretisation error, estimated in every cell: 'inflate' weighs each "
                        "cell by sigma^2 + e^2 and carries the error into the intervals (default), 'refine' "
                        "halves [mesh] size until it is below sigma/3 (up to --max-dofs), 'ignore' only reports it")
    p.add_argument("--max-dofs", type=int, default=MAX_DOFS, metavar="N",
                   help=f"--model-error refine: no mesh above N degrees of freedom (default {MAX_DOFS})")
    p.set_defaults(handler=calibrate_command)


def _progress(enabled: bool):
    """A progress line on stderr: iteration and row."""
    if not enabled:
        return None
    t0 = time.perf_counter()

    def show(iteration: int, row: int, rows: int) -> None:
        width = 24
        done = int(width * row / rows)
        sys.stderr.write(f"\rcalibrate: iteration {iteration:2d} [{'#' * done}{'.' * (width - done)}] "
                         f"row {row}/{rows}  {time.perf_counter() - t0:6.1f} s")
        if row == rows:
            sys.stderr.write("\r" + " " * 72 + "\r")
        sys.stderr.flush()
    return show


def calibrated_text(source, fitted: dict, overrides=()) -> str:
    """The design file's text with the fitted values (comments and layout kept).

    The run's --set overrides are kept too, except mesh and solver settings
    (how the calibration was computed, not what was calibrated).
    """
    from ..design.parse import load_design
    from ..editor.savefile import render
    text = Path(source).read_text(encoding="utf-8")
    kept = [o for o in overrides if not o.strip().startswith(("mesh.", "solver."))]
    new = load_design(source, kept + [f"{k}={_toml(v)}" for k, v in fitted.items()]).raw
    return render(text, new, default_name=Path(source).stem)


def _toml(v) -> str:
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    return repr(float(v))


def calibrate_command(args) -> int:
    from mpi4py import MPI

    from ..analysis.caldata import DataError, prepare_data

    t0 = time.perf_counter()
    if MPI.COMM_WORLD.size > 1:
        raise cli.InputError(f"{args.design}: calibrate runs on one MPI process (got {MPI.COMM_WORLD.size})")
    if not 1 <= args.max_iterations <= MAX_ITERATIONS:
        raise cli.InputError(f"--max-iterations {args.max_iterations}: must be >= 1 and <= {MAX_ITERATIONS}")
    if not 1 <= args.starts <= MAX_STARTS:
        raise cli.InputError(f"--starts {args.starts}: must be >= 1 and <= {MAX_STARTS}")
    if not 1 <= args.max_dofs <= MAX_DOFS_LIMIT:
        raise cli.InputError(f"--max-dofs {args.max_dofs}: must be >= 1 and <= {MAX_DOFS_LIMIT}")
    if not (math.isfinite(args.holdout) and 0.0 <= args.holdout < 1.0):
        raise cli.InputError(f"--holdout {args.holdout:g}: must be a fraction in [0, 1)")
    design = cli.load(args)
    try:
        data = prepare_data(design, args.data, args.fit, args.sigma, args.bounds, args.holdout)
    except DataError as exc:
        raise cli.InputError(str(exc)) from None
    design, session = cli.prepare(args, kind="calibrate")
    timings = dict(session.timings)
    if not args.verbose:
        cli.log.setLevel(logging.WARNING)
    from ..analysis.calibrate import calibrate
    from ..fem.newton import SolveError
    from ..viz.calplots import calibration_figures
    with session:
        try:
            cal = calibrate(session, data, max_iterations=args.max_iterations, starts=args.starts,
                            progress=_progress(not args.quiet and sys.stderr.isatty()),
                            model_error=args.model_error, max_dofs=args.max_dofs)
        except SolveError as exc:
            cli.error(f"{design.name}: {exc}; nothing written to {args.out}")
            return cli.EXIT_SOLVE
        timings.update(calibrate=cal.time, total=time.perf_counter() - t0)
        fitted = cal.overrides(design)
        result = {"format": FORMAT, "design": design.name, "data": str(args.data), **cal.to_dict(),
                  "calibrated": fitted, "timings": {k: round(float(v), 4) for k, v in timings.items()}}
        text = calibrated_text(args.design, fitted, args.overrides)
        header = ["row", "experiment", "fitted"] + [f"{c}{s}" for c in cal.columns
                                                    for s in ("", ":model", ":model_error")]
        rows = [dict(zip(header, [i + 1, data.experiments[i], int(data.train[i])]
                         + [v for j in range(len(cal.columns))
                            for v in (_cell(data.values[i, j]), float(cal.model_values[i, j]),
                                      _cell(cal.model_errors[i, j]))]))
                for i in range(data.rows)]
        design_file = "calibrated.toml" if cal.converged else "partial.toml"     # a partial result: its best state
        with outdir.publish(args.out, kind="calibrate") as stage:    # every file or none
            stage.run(write_json, stage.path / "calibration.json", result)
            stage.run(write_text, stage.path / design_file, text)
            stage.run(write_csv, stage.path / "fit.csv", header, rows)
            stage.run(calibration_figures, stage.path, cal, f"{design.name}: calibration")
    if not args.quiet:
        state = "converged" if cal.converged else f"not converged ({cal.status})"
        print(f"{design.name}: {len(cal.keys)} parameters from {data.rows} rows, {state} in "
              f"{cal.iterations} iterations, {cal.solves} solves, {cal.time:.1f} s")
        for i, k in enumerate(cal.keys):
            print(f"  {k} = {cal.values[i]:.6g} (start {cal.initial[i]:.6g}), {_interval(cal, i)}")
        for group, ways in zip(cal.unidentifiable, cal.identify_with):
            print(f"  the data cannot separate: {', '.join(group)}; measure as well: {'; or '.join(ways)}")
        _print_model_error(cal)
        if cal.holdout:
            print(f"  held-out rows: {cal.holdout['rows']}, weighted RMS {cal.holdout['weighted_rms']:.3g}")
        print(f"  results in {args.out}/ (calibration.json, {design_file}, fit.csv, fit.png, residuals.png, "
              "parameters.png)")
    if not cal.converged:
        cli.error(f"{design.name}: the fit did not converge ({cal.status}) in {cal.iterations} iterations; "
                  f"its best state is in {args.out}/partial.toml, not calibrated")
        return cli.EXIT_SOLVE
    return cli.EXIT_OK


def _print_model_error(cal) -> None:
    """The model error's line: what was done, and each column's largest e / sigma at the estimate."""
    me = cal.model_error
    if not me:
        return
    worst = ", ".join(f"{c} {v.get('max_over_sigma_at_estimate', math.nan):.3g}" for c, v in me["columns"].items())
    print(f"  model error (max e/sigma): {worst}; {me['mode']}: {me['how']}")
    if me["too_coarse"] and me["mode"] == "ignore":
        print("  the model's error is above a third of sigma: its intervals do not hold it (--model-error inflate "
              "or refine)")


def _interval(cal, i: int) -> str:
    """'95 % [lo, hi] (x/÷ f)', or why the parameter is not identified."""
    if not math.isfinite(cal.std[i]):
        return f"not identified: {cal.reasons[i]}"
    lo, hi = cal.ci95[i]
    text = f"95 % [{lo:.6g}, {hi:.6g}]"
    if cal.data.parameters[i].log:
        text += f" (x/÷ {cal.factor[i]:.4g})"
    return text if cal.identified[i] else f"{text}, not identified: {cal.reasons[i]}"


def _cell(v: float):
    return float(v) if math.isfinite(v) else ""
