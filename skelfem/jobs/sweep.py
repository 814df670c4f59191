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
Each case is published whole into ``<out>/<case>/`` (skelfem.io.outdir: staged,
then swapped in), with a ``sweep`` entry in its result.json naming its
overrides and a hash of the design file's bytes, the overrides and the
picture flag. A case is skipped on the next run only if its result.json
converged and carries the same hash: an edited design or changed overrides
rerun it, and failed cases are tried again. Override values are passed at
full precision. ``summary.csv`` is rewritten after every case, so an
interrupted sweep leaves a summary of what is done; ``summary.png`` at the
end. The sweep's exit status says whether every case converged.
"""
from __future__ import annotations

import hashlib
import itertools
import json
import math
import re
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..design.spec import DesignError
from ..design.parse import MAX_FILE, load_design, read_toml
from ..io.files import read_bounded

MAX_CASES = 100_000
FAILED = ("bad_input", "bad_output", "internal_error")


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
    design_hash: str = ""  # sha256 of the design file's bytes when the sweep was loaded


def _fail(source, key, msg):
    raise DesignError(f"{source}: {key}: {msg}" if key else f"{source}: {msg}")


def _fmt(value) -> str:
    """A TOML value as text, floats at full precision (repr round-trips)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") \
            .replace("\r", "\\r").replace("\t", "\\t") + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_fmt(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{_key(k)} = {_fmt(v)}" for k, v in value.items()) + "}"
    raise TypeError(type(value).__name__)


def _key(k: str) -> str:
    return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else _fmt(k)


def _label(value) -> str:
    """A value as it appears in a generated case name."""
    if isinstance(value, str):
        return value
    return _fmt(value)


def _short(key: str) -> str:
    return ".".join(key.split(".")[-2:])


def _case_name(raw: str) -> str:
    """A generated case name made safe as a folder name (a short hash keeps it unique when changed)."""
    safe = re.sub(r"[^A-Za-z0-9._=+,\-\[\]]", "_", raw).lstrip(".")
    if safe != raw or len(safe.encode()) > 100 or not safe:
        digest = hashlib.sha256(raw.encode("utf-8", "surrogatepass")).hexdigest()[:8]
        safe = (safe[:88] or "case") + "-" + digest
    return safe


def _assignment(source, where, key, value) -> str:
    if not isinstance(key, str) or not key or "=" in key:
        _fail(source, where, f"{key!r} is not a design key (KEY, without '=')")
    try:
        return f"{key}={_fmt(value)}"
    except TypeError as exc:
        _fail(source, f"{where}.{key}", f"unsupported value type {exc} (use numbers, strings, booleans, arrays)")


def load_sweep(path) -> Sweep:
    """Read and check a sweep file; raises DesignError with a one-line message."""
    from ..io.outdir import check_name

    path = Path(path)
    source = str(path)
    data = read_toml(path, "sweep file")
    known = {"design", "name", "set", "ranks_per_case", "picture", "parameters", "cases"}
    for key in data:
        if key not in known:
            _fail(source, key, "unknown key")
    if not isinstance(data.get("design"), str) or not data["design"]:
        _fail(source, "design", "missing: the design file to sweep (path relative to the sweep file)")
    try:
        design = (path.parent / data["design"]).resolve()
        design_bytes = None
        if design.is_file():
            with open(design, "rb") as fh:      # at most what a design may be (an endless file is not one)
                design_bytes = fh.read(MAX_FILE + 1)
            if len(design_bytes) > MAX_FILE:
                _fail(source, "design",
                      f"{data['design']!r} is larger than {MAX_FILE // 2 ** 20} MB; not a design file")
    except (OSError, ValueError, RuntimeError) as exc:
        _fail(source, "design", f"cannot read {data['design']!r} ({exc})")
    if design_bytes is None:
        _fail(source, "design", f"no such file: {design}")
    name = data.get("name", path.stem)
    problem = check_name(name, "the sweep name (it names the output folder)") if isinstance(name, str) \
        else "must be a string"
    if problem:
        _fail(source, "name", problem)
    common = data.get("set", [])
    if not isinstance(common, list) or not all(isinstance(s, str) and "=" in s for s in common):
        _fail(source, "set", 'must be a list of "KEY=VALUE" strings')
    params = data.get("parameters", {})
    if not isinstance(params, dict):
        _fail(source, "parameters", "must be a table of KEY = [values]")
    count = 1
    for key, values in params.items():
        if not isinstance(values, list) or not values:
            _fail(source, f"parameters.{key}", "must be a non-empty list of values")
        count *= len(values)
        if count > MAX_CASES:
            _fail(source, "parameters", f"more than {MAX_CASES} combinations")
    cases = []
    keys = tuple(params)
    for combo in itertools.product(*(params[k] for k in keys)) if keys else ():
        over = tuple(common) + tuple(_assignment(source, "parameters", k, v) for k, v in zip(keys, combo))
        raw = "__".join(f"{_short(k)}={_label(v)}" for k, v in zip(keys, combo))
        cases.append(Case(_case_name(raw), over, dict(zip(keys, combo))))
    explicit = data.get("cases", [])
    if not isinstance(explicit, list) or not all(isinstance(c, dict) for c in explicit):
        _fail(source, "cases", "must be an array of tables ([[cases]])")
    if len(cases) + len(explicit) > MAX_CASES:
        _fail(source, "cases", f"more than {MAX_CASES} cases")
    for i, c in enumerate(explicit):
        cname, sets = c.get("name"), c.get("set", {})
        problem = check_name(cname, "a case name") if isinstance(cname, str) else "must be a string"
        if problem:
            _fail(source, f"cases[{i}].name", problem)
        if not isinstance(sets, dict) or set(c) - {"name", "set"}:
            _fail(source, f"cases[{i}]", 'takes name and set = { "KEY" = value, ... } only')
        over = tuple(common) + tuple(_assignment(source, f"cases[{i}].set", k, v) for k, v in sets.items())
        cases.append(Case(cname, over, dict(sets)))
    if not cases:
        _fail(source, "", "no cases: give [parameters] and/or [[cases]]")
    names = [c.name for c in cases]
    if len(set(names)) != len(names):
        seen = set()
        dup = next(n for n in names if n in seen or seen.add(n))
        _fail(source, "cases", f"duplicate case name {dup!r}")
    if "summary.csv" in names or "summary.png" in names:
        _fail(source, "cases", "a case may not be named like the summary files")
    rpc = data.get("ranks_per_case", 1)
    if not isinstance(rpc, int) or isinstance(rpc, bool) or not 1 <= rpc <= 4096:
        _fail(source, "ranks_per_case", "must be an integer >= 1")
    picture = data.get("picture", False)
    if not isinstance(picture, bool):
        _fail(source, "picture", "must be true or false")
    _check_design(source, data["design"], design, cases, common)
    all_keys = keys + tuple(k for c in cases for k in c.params if k not in keys)
    return Sweep(source, name, design, tuple(cases), tuple(dict.fromkeys(all_keys)), rpc, picture,
                 hashlib.sha256(design_bytes).hexdigest())


def _check_design(source: str, given: str, design: Path, cases, common) -> None:
    """The sweep's design must be a design: checked once, before any case (with the common ``set``,
    then with the first case's overrides, which may be what makes it valid). A file that is not a
    design used to run every case and record each as bad input."""
    first = None
    for overrides in dict.fromkeys((tuple(o for o in cases[0].overrides if o in common), cases[0].overrides)):
        try:
            load_design(design, list(overrides))
            return
        except DesignError as exc:
            first = first or exc
    _fail(source, "design", f"{given!r} is not a usable design file: {first}")


# -- running -----------------------------------------------------------------------------------------
def case_hash(sweep: Sweep, case: Case) -> str:
    """What a stored result must match to be reused: design file bytes, overrides, picture flag."""
    h = hashlib.sha256()
    for part in (sweep.design_hash, *case.overrides, f"picture={sweep.picture}"):
        h.update(part.encode("utf-8", "surrogatepass") + b"\0")
    return h.hexdigest()


def _read_result(out: Path, case: Case):
    try:
        res = json.loads(read_bounded(out / case.name / "result.json", MAX_FILE, "result file"))
    except (OSError, ValueError, RecursionError):
        return None
    return res if isinstance(res, dict) else None


def completed(out: Path, case: Case, sweep: Sweep | None = None) -> bool:
    """A case is done when its result.json converged with the same overrides (and hash, given the sweep)."""
    res = _read_result(out, case)
    if res is None or res.get("converged") is not True:
        return False
    entry = res.get("sweep")
    if not isinstance(entry, dict) or entry.get("overrides") != list(case.overrides):
        return False
    return sweep is None or entry.get("hash") == case_hash(sweep, case)


def run_case(sweep: Sweep, case: Case, out: Path, comm, force: bool = False) -> tuple[dict, bool]:
    """Run one case on comm; returns (result, whether this rank ended in step with the others).

    A failure that every rank meets alike (bad input, unusable folder) is
    recorded at once; an internal error is only returned (in_step False):
    record_failure() writes it once the ranks have agreed (run_sweep).
    """
    from ..design import resources
    from ..mesh.geometry import MeshingError
    from ..runtime.interrupts import Interrupted, received
    from ..io.outdir import OutputError
    from .run import simulate_design

    extra = {"sweep": {"name": sweep.name, "case": case.name, "overrides": list(case.overrides),
                       "hash": case_hash(sweep, case)}}
    folder = out / case.name
    t0 = time.perf_counter()
    in_step = True
    try:
        if received() is not None:            # a signal swallowed by a callback during the last case
            raise Interrupted(received())
        design = load_design(sweep.design, case.overrides)
        resources.check(design, force)
        return simulate_design(design, folder, comm, picture=sweep.picture, extra=extra), True
    except Interrupted:
        raise
    except (DesignError, MeshingError) as exc:
        status, message = "bad_input", str(exc)
    except OutputError as exc:
        status, message = "bad_output", str(exc)
    except Exception as exc:  # recorded, and the sweep goes on
        from ..io.files import disk_error
        if received() is not None:            # an interrupt that surfaced as another error (a C callback)
            raise Interrupted(received()) from None
        full = disk_error(exc)                # a full or read-only disk: the user's to fix, not a bug
        status, message = ("bad_output", f"{folder}: {full}") if full else \
            ("internal_error", f"{type(exc).__name__}: {exc}")
        in_step = False
    if received() is not None:
        raise Interrupted(received())
    result = {"format": 1, "converged": False, "status": status, "error": message,
              "timings": {"total": round(time.perf_counter() - t0, 4)}, **extra}
    if in_step:
        record_failure(case, out, comm, result)
    return result, in_step


def record_failure(case: Case, out: Path, comm, result: dict) -> None:
    """Publish a failed case's result.json (collective on comm), unless its folder is unusable."""
    from ..io.outdir import OutputError, publish
    from ..io.files import write_json

    if result.get("status") == "bad_output":
        return
    try:
        with publish(out / case.name, comm) as stage:
            if comm.rank == 0:
                stage.run(write_json, stage.path / "result.json", result)
    except OutputError as exc:
        result.update(status="bad_output", error=str(exc))


def say(message: str) -> None:
    print(message, flush=True)


def run_sweep(sweep: Sweep, out: Path, comm=None, progress=say, force: bool = False) -> dict:
    """Run the pending cases of a sweep on comm (MPI.COMM_WORLD by default).

    Returns {"cases", "converged", "failed": [names], "statuses": {name: status}, "ran", "time"}.
    """
    from mpi4py import MPI

    from ..io.outdir import open_folder, release

    comm = comm or MPI.COMM_WORLD
    if comm.size % sweep.ranks_per_case:
        raise DesignError(f"{sweep.source}: ranks_per_case: {sweep.ranks_per_case} does not divide "
                          f"the {comm.size} MPI ranks")
    locked = open_folder(out, comm)
    try:
        return _run_pending(sweep, out, comm, progress, force)
    finally:
        if locked:
            release(out)


def _run_pending(sweep, out, comm, progress, force) -> dict:
    from ..runtime import mpiguard

    t0 = time.perf_counter()
    pending = None
    if comm.rank == 0:
        pending = [i for i, c in enumerate(sweep.cases) if not completed(out, c, sweep)]
    pending = comm.bcast(pending, root=0)
    n_done = len(sweep.cases) - len(pending)
    if comm.rank == 0 and progress:
        progress(f"{sweep.name}: {len(sweep.cases)} cases, {n_done} already done, {len(pending)} to run "
                 f"on {comm.size // sweep.ranks_per_case} group(s) of {sweep.ranks_per_case} rank(s)")
    groups = comm.size // sweep.ranks_per_case
    color = comm.rank // sweep.ranks_per_case
    sub = comm.Split(color, comm.rank)
    ctl = mpiguard.control(sub)
    outcomes = {}
    last_csv = time.monotonic()
    try:
        for k, i in enumerate(pending):
            if k % groups != color:
                continue
            case = sweep.cases[i]
            res, in_step = run_case(sweep, case, out, sub, force)
            # every rank of the group ends the case together (an error on one rank alone aborts)
            mpiguard.agree(ctl, 0 if in_step else 3, f"sweep case {case.name}: {res.get('error')}", in_step,
                           say=lambda m: print(f"error: {m}", flush=True))
            if not in_step:
                record_failure(case, out, sub, res)
            outcomes[case.name] = {"status": res.get("status"), "error": res.get("error")}
            if sub.rank == 0 and progress:
                its = f", {res.get('newton_iterations')} Newton iterations" if res.get("converged") else ""
                progress(f"  [{n_done + k + 1}/{len(sweep.cases)}] {case.name}: {res.get('status')}{its}, "
                         f"{(res.get('timings') or {}).get('total', 0.0):.1f} s")
            if comm.rank == 0 and time.monotonic() - last_csv > 5.0:
                _write_csv(sweep, out, outcomes)          # progress: the summary so far
                last_csv = time.monotonic()
    finally:
        if ctl is not None:
            ctl.Free()
        sub.Free()
    gathered = comm.gather(outcomes, root=0)
    summary = None
    if comm.rank == 0:
        merged = {k: v for part in gathered for k, v in part.items()}
        summary = write_summary(sweep, out, merged)
        summary["time"] = time.perf_counter() - t0
        summary["ran"] = len(pending)
    return comm.bcast(summary, root=0)


# -- summary --------------------------------------------------------------------------------------------
def _row(sweep: Sweep, case: Case, out: Path, outcomes: dict) -> dict:
    res = _read_result(out, case)
    known = outcomes.get(case.name)
    if known is not None and known.get("status") == "bad_output":
        res = {"converged": False, "status": "bad_output", "error": known.get("error")}
    if res is None or (res.get("sweep", {}) or {}).get("overrides") != list(case.overrides):
        res = {"converged": False, "status": (known or {}).get("status") or "missing"}
    row = {"case": case.name, **{k: case.params.get(k, "") for k in sweep.parameters},
           "status": res.get("status"), "converged": res.get("converged") is True,
           "newton_iterations": res.get("newton_iterations"),
           "min_jacobian": res.get("min_jacobian"),
           "time_total": (res.get("timings") or {}).get("total")}
    try:
        for name, m in (res.get("markers") or {}).items():
            d = np.asarray(m["displacement"], float)
            for axis, v in zip("xyz", m["position"]):
                row[f"{name}.{axis}"] = v
            row[f"{name}.|u|"] = float(np.linalg.norm(d))
        for name, c in (res.get("cables") or {}).items():
            row[f"{name}.tension"] = c["tension"]
        for name, g in (res.get("grounds") or {}).items():
            row[f"{name}.|force|"] = float(np.linalg.norm(np.asarray(g["force"], float)))
    except (AttributeError, KeyError, TypeError, ValueError):
        row["status"] = "unreadable"
        row["converged"] = False
    return row


def _rows(sweep: Sweep, out: Path, outcomes: dict | None = None) -> list[dict]:
    return [_row(sweep, case, out, outcomes or {}) for case in sweep.cases]


def _write_csv(sweep: Sweep, out: Path, outcomes: dict | None = None) -> list[dict]:
    from ..io.files import write_csv

    rows = _rows(sweep, out, outcomes)
    write_csv(out / "summary.csv", list(dict.fromkeys(k for r in rows for k in r)), rows)
    return rows


def write_summary(sweep: Sweep, out: Path, outcomes: dict | None = None) -> dict:
    """summary.csv (one row per case) and summary.png; returns counts and each case's status."""
    rows = _write_csv(sweep, out, outcomes)
    _plot_summary(sweep, rows, out / "summary.png")
    failed = [r["case"] for r in rows if not r["converged"]]
    return {"cases": len(rows), "converged": len(rows) - len(failed), "failed": failed,
            "statuses": {r["case"]: r["status"] for r in rows}}


def _plot_summary(sweep: Sweep, rows: list[dict], path: Path) -> None:
    """|marker displacement| against the first parameter, one line per other combination."""
    from matplotlib.figure import Figure

    from ..io.files import atomic_write

    metric = next((k for r in rows for k in r if k.endswith(".|u|")), None)
    fig = Figure(figsize=(6.4, 4.0), dpi=110)
    ax = fig.subplots()
    first = sweep.parameters[0] if sweep.parameters else None

    def number(v):
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
    swept = [r for r in rows if number(r.get(first))]
    if metric and len(swept) >= 2:
        rest = [k for k in sweep.parameters[1:] if all(r.get(k, "") != "" for r in swept)]
        series = {}
        for r in swept:
            series.setdefault(tuple(_label(r.get(k, "")) for k in rest), []).append(r)
        for label, rs in series.items():
            rs = sorted(rs, key=lambda r: r[first])
            ok = [r for r in rs if r["converged"] and metric in r]
            name = ", ".join(f"{_short(k)}={v}" for k, v in zip(rest, label)) or metric
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
        ok = [r for r in rows if r["converged"] and metric in r]
        ax.bar(range(len(ok)), [r[metric] for r in ok])
        ax.set_xticks(range(len(ok)), [r["case"] for r in ok], rotation=45, ha="right", fontsize=7)
    ax.set_ylabel(f"{metric} [mm]" if metric else "")
    n_bad = sum(not r["converged"] for r in rows)
    ax.set_title(f"sweep {sweep.name}: {len(rows)} cases" + (f", {n_bad} failed (red x)" if n_bad else ""),
                 fontsize=10)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))
