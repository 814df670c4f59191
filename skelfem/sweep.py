"""Batch sweeps: many variants of one design, in parallel, resumable.

A sweep file names a design and the variants to run::

    design = "../geometry/finger.toml"     # relative to the sweep file
    set = ["mesh.size=3"]                  # optional: applied to every case
    ranks_per_case = 1                     # optional: MPI ranks that solve one case together
    picture = false                        # optional: deformed.png per case

    [parameters]                           # every combination (Cartesian product)
    "materials.pla.E" = [1.0, 100.0, 10000.0]
    "cables.flexor.contraction" = [2.0, 8.0]

    [[cases]]                              # and/or explicit cases
    name = "soft"
    set = { "materials.pla.E" = 0.1 }

Under ``mpirun -n N`` the world is split into N / ranks_per_case groups and
the pending cases are dealt out round-robin, one group per case at a time.
Each case writes ``<out>/<case>/result.json`` (with a ``sweep`` entry naming
its overrides). A case whose result.json exists with the same overrides is
skipped, so a sweep killed half-way completes only what is missing when run
again. A case that fails (bad override, failed solve, crash) is recorded in
its result.json and the sweep goes on. Rank 0 finally writes ``summary.csv``
and ``summary.png``.
"""
from __future__ import annotations

import itertools
import json
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .design import DesignError, load_design


@dataclass(frozen=True)
class Case:
    name: str
    overrides: tuple      # ("key=value", ...), sweep-wide ones first
    params: dict          # parameter key -> value (for the summary)


@dataclass(frozen=True)
class Sweep:
    source: str
    name: str
    design: Path
    cases: tuple
    parameters: tuple     # parameter keys in order
    ranks_per_case: int = 1
    picture: bool = False


def _fail(source, key, msg):
    raise DesignError(f"{source}: {key}: {msg}" if key else f"{source}: {msg}")


def _fmt(value) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_fmt(v) for v in value) + "]"
    if isinstance(value, str):
        return f'"{value}"'
    return str(value).lower() if isinstance(value, bool) else str(value)


def _short(key: str) -> str:
    return ".".join(key.split(".")[-2:])


def load_sweep(path) -> Sweep:
    """Read and check a sweep file; raises DesignError with a one-line message."""
    path = Path(path)
    source = str(path)
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        _fail(source, "", "no such file")
    except tomllib.TOMLDecodeError as exc:
        _fail(source, "", f"malformed TOML: {exc}")
    known = {"design", "name", "set", "ranks_per_case", "picture", "parameters", "cases"}
    for key in data:
        if key not in known:
            _fail(source, key, "unknown key")
    if not isinstance(data.get("design"), str):
        _fail(source, "design", "missing: the design file to sweep (path relative to the sweep file)")
    design = (path.parent / data["design"]).resolve()
    if not design.is_file():
        _fail(source, "design", f"no such file: {design}")
    common = data.get("set", [])
    if not isinstance(common, list) or not all(isinstance(s, str) and "=" in s for s in common):
        _fail(source, "set", 'must be a list of "KEY=VALUE" strings')
    params = data.get("parameters", {})
    if not isinstance(params, dict):
        _fail(source, "parameters", "must be a table of KEY = [values]")
    for key, values in params.items():
        if not isinstance(values, list) or not values:
            _fail(source, f"parameters.{key}", "must be a non-empty list of values")
    cases = []
    keys = tuple(params)
    for combo in itertools.product(*(params[k] for k in keys)) if keys else ():
        over = tuple(common) + tuple(f"{k}={_fmt(v)}" for k, v in zip(keys, combo))
        name = "__".join(f"{_short(k)}={_fmt(v)}" for k, v in zip(keys, combo)).replace('"', "")
        cases.append(Case(name, over, dict(zip(keys, combo))))
    explicit = data.get("cases", [])
    if not isinstance(explicit, list) or not all(isinstance(c, dict) for c in explicit):
        _fail(source, "cases", "must be an array of tables ([[cases]])")
    for i, c in enumerate(explicit):
        name, sets = c.get("name"), c.get("set", {})
        if not isinstance(name, str) or not name or "/" in name:
            _fail(source, f"cases[{i}].name", "must be a non-empty name without '/'")
        if not isinstance(sets, dict) or set(c) - {"name", "set"}:
            _fail(source, f"cases[{i}]", 'takes name and set = { "KEY" = value, ... } only')
        cases.append(Case(name, tuple(common) + tuple(f"{k}={_fmt(v)}" for k, v in sets.items()),
                          {k: v for k, v in sets.items()}))
    if not cases:
        _fail(source, "", "no cases: give [parameters] and/or [[cases]]")
    names = [c.name for c in cases]
    if len(set(names)) != len(names):
        _fail(source, "cases", f"duplicate case name {next(n for n in names if names.count(n) > 1)!r}")
    rpc = data.get("ranks_per_case", 1)
    if not isinstance(rpc, int) or isinstance(rpc, bool) or rpc < 1:
        _fail(source, "ranks_per_case", "must be an integer >= 1")
    all_keys = keys + tuple(k for c in cases for k in c.params if k not in keys)
    return Sweep(source, str(data.get("name", path.stem)), design, tuple(cases),
                 tuple(dict.fromkeys(all_keys)), rpc, bool(data.get("picture", False)))


# -- running -----------------------------------------------------------------------------------------
def completed(out: Path, case: Case) -> bool:
    """A case is done when its result.json exists and records the same overrides."""
    try:
        res = json.loads((out / case.name / "result.json").read_text())
    except (OSError, ValueError):
        return False
    return res.get("sweep", {}).get("overrides") == list(case.overrides)


def run_case(sweep: Sweep, case: Case, out: Path, comm) -> dict:
    """Run one case on comm; always leaves a result.json (failures included)."""
    from .geometry import MeshingError
    from .output import write_json
    from .run import simulate_design

    extra = {"sweep": {"name": sweep.name, "case": case.name, "overrides": list(case.overrides)}}
    folder = out / case.name
    t0 = time.perf_counter()
    try:
        design = load_design(sweep.design, case.overrides)
        return simulate_design(design, folder, comm, picture=sweep.picture, extra=extra)
    except (DesignError, MeshingError) as exc:
        status, message = "bad_input", str(exc)
    except Exception as exc:  # recorded, and the sweep goes on
        status, message = "internal_error", f"{type(exc).__name__}: {exc}"
    result = {"format": 1, "converged": False, "status": status, "error": message,
              "timings": {"total": round(time.perf_counter() - t0, 4)}, **extra}
    if comm.rank == 0:
        write_json(folder / "result.json", result)
    return result


def say(message: str) -> None:
    print(message, flush=True)


def run_sweep(sweep: Sweep, out: Path, comm=None, progress=say) -> dict:
    """Run the pending cases of a sweep on comm (MPI.COMM_WORLD by default)."""
    from mpi4py import MPI

    comm = comm or MPI.COMM_WORLD
    if comm.size % sweep.ranks_per_case:
        raise DesignError(f"{sweep.source}: ranks_per_case: {sweep.ranks_per_case} does not divide "
                          f"the {comm.size} MPI ranks")
    t0 = time.perf_counter()
    pending = None
    if comm.rank == 0:
        pending = [i for i, c in enumerate(sweep.cases) if not completed(out, c)]
    pending = comm.bcast(pending, root=0)
    n_done = len(sweep.cases) - len(pending)
    if comm.rank == 0 and progress:
        progress(f"{sweep.name}: {len(sweep.cases)} cases, {n_done} already done, {len(pending)} to run "
                 f"on {comm.size // sweep.ranks_per_case} group(s) of {sweep.ranks_per_case} rank(s)")
    groups = comm.size // sweep.ranks_per_case
    color = comm.rank // sweep.ranks_per_case
    sub = comm.Split(color, comm.rank)
    try:
        for k, i in enumerate(pending):
            if k % groups != color:
                continue
            case = sweep.cases[i]
            res = run_case(sweep, case, out, sub)
            if sub.rank == 0 and progress:
                its = f", {res.get('newton_iterations')} Newton iterations" if res.get("converged") else ""
                progress(f"  [{n_done + k + 1}/{len(sweep.cases)}] {case.name}: {res['status']}{its}, "
                         f"{res['timings']['total']:.1f} s")
    finally:
        sub.Free()
    comm.Barrier()
    summary = None
    if comm.rank == 0:
        summary = write_summary(sweep, out)
        summary["time"] = time.perf_counter() - t0
        summary["ran"] = len(pending)
    return comm.bcast(summary, root=0)


# -- summary --------------------------------------------------------------------------------------------
def _rows(sweep: Sweep, out: Path) -> list[dict]:
    rows = []
    for case in sweep.cases:
        try:
            res = json.loads((out / case.name / "result.json").read_text())
        except (OSError, ValueError):
            res = {"converged": False, "status": "missing"}
        row = {"case": case.name, **{k: case.params.get(k, "") for k in sweep.parameters},
               "status": res.get("status"), "converged": bool(res.get("converged")),
               "newton_iterations": res.get("newton_iterations"),
               "min_jacobian": res.get("min_jacobian"),
               "time_total": res.get("timings", {}).get("total")}
        for name, m in (res.get("markers") or {}).items():
            d = np.asarray(m["displacement"])
            for axis, v in zip("xyz", m["position"]):
                row[f"{name}.{axis}"] = v
            row[f"{name}.|u|"] = float(np.linalg.norm(d))
        for name, c in (res.get("cables") or {}).items():
            row[f"{name}.tension"] = c["tension"]
        for name, g in (res.get("grounds") or {}).items():
            row[f"{name}.|force|"] = float(np.linalg.norm(g["force"]))
        rows.append(row)
    return rows


def write_summary(sweep: Sweep, out: Path) -> dict:
    """summary.csv (one row per case) and summary.png; returns counts."""
    from .output import write_csv

    rows = _rows(sweep, out)
    write_csv(out / "summary.csv", list(dict.fromkeys(k for r in rows for k in r)), rows)
    _plot_summary(sweep, rows, out / "summary.png")
    failed = [r["case"] for r in rows if not r["converged"]]
    return {"cases": len(rows), "converged": len(rows) - len(failed), "failed": failed}


def _plot_summary(sweep: Sweep, rows: list[dict], path: Path) -> None:
    """|marker displacement| against the first parameter, one line per other combination."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .output import atomic_write

    metric = next((k for r in rows for k in r if k.endswith(".|u|")), None)
    fig, ax = plt.subplots(figsize=(6.4, 4.0), dpi=110)
    first = sweep.parameters[0] if sweep.parameters else None
    swept = [r for r in rows if isinstance(r.get(first), (int, float)) and not isinstance(r.get(first), bool)]
    if metric and len(swept) >= 2:
        rest = [k for k in sweep.parameters[1:] if all(r.get(k, "") != "" for r in swept)]
        series = {}
        for r in swept:
            series.setdefault(tuple(r.get(k, "") for k in rest), []).append(r)
        for label, rs in series.items():
            rs = sorted(rs, key=lambda r: r[first])
            ok = [r for r in rs if r["converged"]]
            name = ", ".join(f"{_short(k)}={_fmt(v)}" for k, v in zip(rest, label)) or metric
            ax.plot([r[first] for r in ok], [r[metric] for r in ok], "o-", ms=4, label=name)
            bad = [r for r in rs if not r["converged"]]
            if bad:
                ax.plot([r[first] for r in bad], [0.0] * len(bad), "x", color="red", ms=8)
        values = [r[first] for r in swept]
        if min(values) > 0 and max(values) / min(values) > 100:
            ax.set_xscale("log")
        ax.set_xlabel(first)
        ax.legend(fontsize=7)
    elif metric:
        ok = [r for r in rows if r["converged"]]
        ax.bar(range(len(ok)), [r[metric] for r in ok])
        ax.set_xticks(range(len(ok)), [r["case"] for r in ok], rotation=45, ha="right", fontsize=7)
    ax.set_ylabel(f"{metric} [mm]" if metric else "")
    n_bad = sum(not r["converged"] for r in rows)
    ax.set_title(f"sweep {sweep.name}: {len(rows)} cases" + (f", {n_bad} failed (red x)" if n_bad else ""),
                 fontsize=10)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))
    plt.close(fig)
