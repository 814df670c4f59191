"""Tables of measured numbers, read from the studies' output files when the docs are built.

A page asks for a table by name::

    ```{study-table} bench
    ```

and gets a table built from the files under ``studies/output/`` that the
study scripts (``studies/*.py``) and ``skelfem bench`` write. Nothing here
holds a number: every cell comes from a file, so the pages show what the
last kept run measured, and rerunning a study and rebuilding the docs
refreshes them.

A table whose file is not in the checkout (outputs of studies that are not
kept in the repository, or not yet run) becomes a short note naming the
command that writes it; that is not an error.

Each table is a function in ``TABLES``: it gets the output folder and returns
a ``Table`` (header, rows, an optional caption) or raises ``Missing``.
"""
from __future__ import annotations

import csv
import json
import math
import statistics
from dataclasses import dataclass, field
from pathlib import Path

from docutils import nodes
from docutils.parsers.rst import directives
from sphinx.util.docutils import SphinxDirective

ROOT = Path(__file__).resolve().parents[2]
OUTPUT = ROOT / "studies" / "output"


class Missing(Exception):
    """The table's file is not there: (path, the command that writes it)."""


@dataclass
class Table:
    header: list[str]
    rows: list[list[str]]
    caption: str = ""
    files: list[Path] = field(default_factory=list)


# -- formatting ---------------------------------------------------------------------------------------
def num(x, digits: int = 3) -> str:
    """A number with `digits` significant digits, plain where that reads well."""
    if x is None or x == "":
        return "–"
    x = float(x)
    if math.isnan(x):
        return "–"
    if x == 0:
        return "0"
    a = abs(x)
    if a >= 10 ** digits:
        return f"{x:,.0f}"
    if a < 1e-3:
        return f"{x:.{digits - 1}e}"
    decimals = max(0, digits - 1 - math.floor(math.log10(a)))
    return f"{x:.{decimals}f}"


def short(x) -> str:
    """A size or tolerance as written in a design file: 0.45, 2, 0.05."""
    return "–" if x is None or x == "" else f"{float(x):g}"


def power(x) -> str:
    """1e6 rather than 1e+06."""
    return f"{float(x):.0e}".replace("e+0", "e").replace("e+", "e") if float(x) >= 1e4 else short(x)


def ms(seconds, digits: int = 3) -> str:
    return num(None if seconds is None else 1e3 * float(seconds), digits)


def secs(seconds) -> str:
    return "–" if seconds is None else f"{float(seconds):.2g} s" if float(seconds) < 1 else f"{float(seconds):.1f} s"


def thousands(n) -> str:
    n = int(n)
    return f"{n / 1000:.1f}k" if n >= 10000 else f"{n:,}"


def span(values, fmt=num) -> str:
    """'a' or 'a–b' over the values."""
    lo, hi = min(values), max(values)
    a, b = fmt(lo), fmt(hi)
    return a if a == b else f"{a}–{b}"


def load_json(rel: str, command: str):
    path = OUTPUT / rel
    if not path.exists():
        raise Missing(path, command)
    return json.loads(path.read_text()), path


def load_csv(rel: str, command: str):
    path = OUTPUT / rel
    if not path.exists():
        raise Missing(path, command)
    with path.open(newline="") as f:
        return list(csv.DictReader(f)), path


def truthy(s: str) -> bool:
    return str(s).strip().lower() in ("true", "1", "yes")


# -- the tables ---------------------------------------------------------------------------------------
def bench(_: dict) -> Table:
    d, path = load_json("bench/bench.json", "skelfem bench --sizes 4 2 1 0.45 --out studies/output/bench")
    rows = []
    for r in d["rows"]:
        nm = r.get("newton_matrix", {})
        rows.append([short(r["size"]), f"{r['dofs']:,}", ms(r["assembly_time"], 2), ms(r["refactorization_time"], 2),
                     ms(r["iteration_time_median"]), str(r["newton_iterations"]), num(r["ratio"]),
                     f"{r['nnz']:,}", f"{nm['nnz']:,}" if "nnz" in nm else "–"])
    f = d.get("floor", {})
    caption = (f"{d.get('design_name', d.get('design'))}, P{d.get('degree')}, medians of {d.get('repeats')} repeats "
               f"on {d.get('machine', {}).get('cpus', '?')} CPUs. Newton order at h = {short(f.get('size'))}: "
               f"{num(f.get('newton_order'))}; ratio there {num(f.get('ratio'))} against the floor's limit "
               f"{num(f.get('limit'))}.")
    return Table(["h [mm]", "DOFs", "FE assembly [ms]", "FE refactor + solve [ms]", "Newton iteration [ms]",
                  "iterations", "ratio", "nnz FE", "nnz K"], rows, caption, [path])


def slice_check(_: dict) -> Table:
    d, path = load_json("slice_check/slice_check.json", "python studies/slice_check.py")
    rows = [[r["design"], r["part"], r["down"], num(r["estimated_support_area"], 3), str(r["support_sections"]),
             str(r["layers"]), "yes" if r["manifold"] and r["parts"] == 1 else "no", str(len(r["warnings"]))]
            for r in d["rows"]]
    moulds = ('every mould half prints without support' if d['moulds_without_support']
              else 'some mould halves need support')
    caption = (f"{d['slicer']}: `--export-gcode --support-material` on every STL as written; "
               f"{'every part sliced without a warning' if d['all_sliced'] else 'some parts did not slice cleanly'}"
               f"; {moulds}.")
    return Table(["design", "part", "face down", "skelfem's support estimate [mm²]", "support sections (G-code)",
                  "layers", "manifold, one part", "warnings"], rows, caption, [path])


def slice_check_3mf(_: dict) -> Table:
    d, path = load_json("slice_check/slice_check.json", "python studies/slice_check.py")
    rows = []
    for p in d.get("prints", []):
        if "error" in p:
            rows.append([p["design"], "not printable: " + p["error"].split(": ", 2)[-1], "", "", "", "", ""])
            continue
        a, b = p["plate"], p["everywhere"]
        rows.append([p["design"], p["down"], str(p["parts"]), ", ".join(num(v, 3) for v in a["filament_cm3"]),
                     str(a["support_sections"]), str(b["support_sections"]), str(len(a["warnings"]))])
    caption = (f"{d['slicer']}: `--export-gcode --support-material --nozzle-diameter 0.4,0.4` on the 3MF of "
               "`skelfem fabricate --format 3mf`, support on the build plate only (and, for comparison, "
               "everywhere); the slicer's parts count every closed shell (a bone's cavity in the body is one).")
    return Table(["design", "face down", "parts", "filament per extruder [cm³]", "support sections (plate only)",
                  "support sections (everywhere)", "warnings"], rows, caption, [path])


def fabrication_volumes(_: dict) -> Table:
    d, path = load_json("fabrication_volumes/fabrication_volumes.json", "python studies/fabrication_volumes.py")
    pct = lambda x, digits=2: f"{100 * x:+.{digits}f} %"                                      # noqa: E731
    rows = [[f"`{r['design']}.toml`",
             ", ".join(pct(b["relative_error"], 3) for b in r["bones"].values()) or "(no bones)",
             ", ".join(num(b["removed_volume"], 3) for b in r["bones"].values()),
             f"{num(r['cavity_volume'], 5)} / {num(r['body_volume'], 5)} mm³ ({pct(r['cavity_relative_error'])})",
             pct(r["closed_relative_error"], 3), secs(r["seconds"])] for r in d["rows"]]
    caption = (f"`{d['command']}` on each design; every number from its fabrication.json; "
               f"{'every check passed' if d['all_passed'] else 'some checks failed'}.")
    return Table(["design", "bones: STL volume against the kernel's", "removed by channels, holes, sockets [mm³]",
                  "cavity against the body", "closed cavity against the body", "time"], rows, caption, [path])


def fabrication_poses(_: dict) -> Table:
    d, path = load_json("fabrication_volumes/fabrication_volumes.json", "python studies/fabrication_volumes.py")
    rows = [[r["design"], part, p["down"], num(p["bed_area"], 3), num(p["support_area"], 3)]
            for r in d["rows"] for part, p in r["parts"].items()]
    return Table(["design", "part", "face down", "bed area [mm²]", "support estimate [mm²]"], rows,
                 "How each part is written, lying on the bed (fabrication.json's `print`).", [path])


def in_hand_roll(_: dict) -> Table:
    d, path = load_json("in_hand_roll/in_hand_roll.json", "python studies/in_hand_roll.py")
    rows = [[f"{r['target_deg']:g}", num(-r["rotation_deg"], 3), num(r["error"], 2), r["status"],
             ", ".join(num(u, 3) for u in r["contractions"]), str(r["forward_solves"]),
             ", ".join(num(v, 2) for v in r["sticking"].values()), num(r["min_distance"], 2)] for r in d["rows"]]
    caption = (f"{d['design']}, {d['dofs']:,} DOFs; tendons {', '.join(d['tendons'])}; {d['reached']} of "
               f"{len(d['rows'])} targets reached, the disk turned {num(d['largest_rotation_deg'], 3)}° in all, "
               f"{d['approximate_jacobians']} IK steps without friction's coupling; {secs(d['seconds'])} for "
               "the whole run.")
    return Table(["target [°]", "disk turned [°]", "marker error [mm]", "IK", "contractions [mm]", "solves",
                  "sticking (left, right)", "min distance [mm]"], rows, caption, [path])


def mpi_speed(_: dict) -> Table:
    d, path = load_json("mpi_speed/mpi_speed.json", "python studies/mpi_speed.py")
    n = d["ranks"]
    rows = [["1 rank", secs(d["serial"]["wall"]), secs(d["serial"]["setup"]), secs(d["serial"]["solve"])],
            [f"mpirun -n {n}", secs(d["parallel"]["wall"]), secs(d["parallel"]["setup"]),
             secs(d["parallel"]["solve"])],
            ["ratio", num(d["wall_ratio"], 2), num(d["setup_ratio"], 3), num(d["solve_ratio"], 2)]]
    walls = d.get("walls", {})
    caption = (f"{Path(d['design']).name} {' '.join('--set ' + s for s in d.get('set', []))}: {d['dofs']:,} DOFs, "
               f"medians of {d['repeats']} alternated runs; energies agree to {num(d['energy_difference'], 2)}"
               + (f"; single walls: 1 rank {', '.join(secs(w) for w in walls.get('1', []))}, "
                  f"{n} ranks {', '.join(secs(w) for w in walls.get(str(n), []))}" if walls else "") + ".")
    return Table(["", "wall", "set-up (mesh + model)", "solve"], rows, caption, [path])


def editor_latency(_: dict) -> Table:
    d, path = load_json("editor_latency/latency.json", "python studies/editor_latency.py")

    def pp(s: dict) -> str:
        return f"{s['p50']:.0f} / {s['p95']:.0f}"

    c, v, api = d["contraction"], d["vertex"], d["api"]
    rows = [["contraction slider (live `set`)", pp(c["rendered"]["contraction"]), pp(c["every_event"]["contraction"]),
             pp(c["server_ms"]["set"])],
            ["bone-vertex drag (draft: moved nodes)", pp(v["rendered"]["vertex"]), pp(v["every_event"]["vertex"]),
             pp(v["server_ms"]["edit (moved nodes)"])],
            ["release of the drag (re-mesh)", pp(v["rendered"]["release"]), pp(v["every_event"]["release"]),
             pp(v["server_ms"]["edit (re-meshed)"])],
            ["`POST /api/solve`, one bone vertex moved", pp(api["one_vertex_ms"]), "", ""],
            ["`POST /api/solve`, contraction changed", pp(api["contraction_ms"]), "", ""]]
    caption = (f"{d['design']} ({d['dofs']} DOFs, {d['cells']} cells): {d['drags']} drags of {d['moves']} moves, "
               f"a move every {d['step_ms']} ms; p50 / p95 in ms. The page redraws an answer in "
               f"{c['render_ms']['p50']:.1f} ms (p50).")
    return Table(["what", "rendered", "every event", "server's own time"], rows, caption, [path])


def editor_latency_sizes(_: dict) -> Table:
    """The editor's latency on the bundled design and on finer meshes of it (one row each)."""
    d, path = load_json("editor_latency/latency.json", "python studies/editor_latency.py")

    def pp(s: dict | None) -> str:
        return f"{s['p50']:.0f} / {s['p95']:.0f}" if s and s.get("n") else "–"

    rows = []
    for case in [d] + d.get("sizes", []):
        c, v = case["contraction"], case["vertex"]
        render = [x for x in (c["render_ms"], v["render_ms"]) if x.get("n")]
        rows.append([f"h = {short(case['mesh_size'])} mm", f"{case['dofs']:,}", f"{case['cells']:,}",
                     pp(c["rendered"].get("contraction")), pp(v["rendered"].get("vertex")),
                     pp(v["rendered"].get("release")), pp(v.get("settled", {}).get("release")),
                     span([x["p50"] for x in render], lambda t: f"{t:.1f}"),
                     pp(c["server_ms"].get("set")), pp(v["server_ms"].get("edit (moved nodes)")),
                     f"{case['before']['load_average'][0]:.1f}–{case['after']['load_average'][0]:.1f}"])
    caption = (f"{d['design']} and finer meshes of it: {d['drags']} drags of {d['moves']} moves each, a move every "
               f"{d['step_ms']} ms; p50 / p95 in ms from the input event to the picture (release: its first "
               f"frame, then its first converged picture); frame budget {d['frame_budget_ms']:g} ms; the host's "
               "one-minute load average before and after each case (two cores).")
    return Table(["mesh", "DOFs", "cells", "slider", "bone-vertex drag", "release", "release, converged",
                  "drawing (p50)", "server: set", "server: moved nodes", "load"], rows, caption, [path])


def editor_latency3d(_: dict) -> Table:
    """The editor's latency for a 3D bone dragged and turned (finger3d at about 10k and 50k DOFs)."""
    d, path = load_json("editor_latency/latency3d.json", "python studies/editor_latency3d.py")

    def pp(s: dict | None) -> str:
        return f"{s['p50']:.0f} / {s['p95']:.0f}" if s and s.get("n") else "–"

    rows = []
    for case in d["cases"]:
        for kind, part in (("bone-move", "move"), ("bone-turn", "turn")):
            c = case[part]
            rows.append([f"h = {short(case['mesh_size'])} mm", f"{case['dofs']:,}", kind.replace("bone-", ""),
                         pp(c["rendered"].get(kind)), pp(c["every_event"].get(kind)),
                         pp(c["rendered"].get("release")), pp(c.get("settled", {}).get("release")),
                         pp(c["server_ms"].get("edit (moved nodes)")), pp(c["render_ms"]),
                         f"{c['certificates']['converged_above_tolerance']}",
                         f"{case['before']['load_average'][0]:.1f}–{case['after']['load_average'][0]:.1f}"])
    first = d["cases"][0]
    caption = (f"finger3d.toml's distal bone moved in the view's plane (move) and turned about z (turn): "
               f"{first['drags']} drags of {first['moves']} moves each, a move every {first['step_ms']} ms; "
               "p50 / p95 in ms from the input event to the picture (release: its first frame, then its first "
               f"converged picture); frame budget {d['frame_budget_ms']:g} ms; 'converged above tolerance' "
               "counts certificates that said converged with |R| above the batch tolerance; the host's one-minute "
               "load average before and after each case (two cores).")
    return Table(["mesh", "DOFs", "drag", "rendered", "every event", "release", "release, converged",
                  "server: moved nodes", "drawing", "converged above tolerance", "load"], rows, caption, [path])


def _rigid(rel: str, command: str) -> Table:
    d, path = load_json(rel, command)

    def row(name: str, runs: list[dict]) -> list[str]:
        its = [r["iterations"] for r in runs]
        warm = sorted({i for r in runs for i in r["warm_iterations"]})
        return [name, f"{runs[0]['unknowns']:,}", f"{runs[0]['nnz'] / 1000:.0f}k",
                span([r["time"] for r in runs], lambda t: f"{t:.2f} s") + f" ({span(its, str)} its)",
                span([r["per_iteration"] for r in runs], lambda t: f"{1e3 * t:.0f} ms"),
                span([r["warm_time"] for r in runs], lambda t: f"{t:.2f} s") + f" ({span(warm, str)} its)"]

    elastic = d["elastic"]
    e_bones = [r["E_bone"][0] for r in elastic]
    rows = [row("rigid bones", [d["rigid"]]),
            row(f"elastic, E_bone = {power(min(e_bones))} … {power(max(e_bones))} MPa", elastic)]
    diffs = [r["marker_difference"] for r in elastic]
    caption = (f"{Path(d['design']).name}, h = {short(d['size'])}, P1, medians; the elastic bones' markers are "
               f"{span(diffs, lambda x: num(x, 2))} mm from the rigid ones' (1/E_bone).")
    return Table(["", "unknowns", "nonzeros", "cold solve", "per iteration", "warm re-solve"], rows, caption, [path])


def rigid_bones_2d(_: dict) -> Table:
    return _rigid("rigid_bones/finger_h0.45.json", "python studies/rigid_bones.py --size 0.45 --repeats 3")


def rigid_bones_3d(_: dict) -> Table:
    return _rigid("rigid_bones/finger3d_h2.json",
                  "python studies/rigid_bones.py --design geometry/finger3d.toml --size 2 --exponents 0 1 2")


def speed_accuracy(opts: dict) -> Table:
    rows_in, path = load_csv("speed_accuracy/cases.csv", "python studies/speed_accuracy.py")
    problem = opts.get("problem", "finger")
    table: dict = {}
    for r in rows_in:
        if r["problem"] != problem:
            continue
        key = (int(r["degree"]), float(r["size"]))
        table.setdefault(key, {"dofs": r["dofs"]})[r["bones"]] = r
    bones = sorted({b for v in table.values() for b in v if b != "dofs"})

    def cell(r):
        if r is None:
            return "", ""
        if not truthy(r["converged"]):
            return "failed", secs(r["time"])
        err = float(r["error"]) if r["error"] not in ("", "nan") else math.nan
        return ("reference" if math.isnan(err) else num(err, 2)), secs(r["time"])

    rows = []
    for (deg, size), v in sorted(table.items(), key=lambda kv: (kv[0][0], -kv[0][1])):
        line = [f"P{deg}", short(size), f"{int(v['dofs']):,}"]
        for b in bones:
            line += list(cell(v.get(b)))
        rows.append(line)
    header = ["degree", "h [mm]", "DOFs"] + [f"{b} bones: {what}" for b in bones for what in ("error [mm]", "time")]
    summary, spath = load_json("speed_accuracy/summary.json", "python studies/speed_accuracy.py")
    ref = summary["summary"].get(problem, {}).get("reference_error", {})
    caption = (f"{problem}: marker error against the finest P2 mesh, whose own error is estimated at "
               f"{num(ref.get('error'), 2)} mm ({ref.get('method', '?')}).")
    return Table(header, rows, caption, [path, spath])


def _tol_rows(rows_in: list[dict]) -> list[list[str]]:
    """Rows of one tol_check csv, tolerances with the same answer merged."""
    groups: dict = {}
    order = []
    for r in rows_in:
        failed = r.get("failed") or ""
        key = (r["design"], r["dofs"], r["estimated_error"], failed)
        if key not in groups:
            groups[key] = []
            order.append(key)
        groups[key].append(r)
    out = []
    for key in order:
        rs = groups[key]
        r = rs[0]
        tols = ", ".join(short(x["tol"]) for x in rs) + " mm"
        times = span([float(x["time"]) for x in rs], lambda t: f"{t:.1f}")
        if key[3]:
            out.append([r["design"], tols, f"**failed**: {key[3]}", "", "–", "–", "–", f"{times} s"])
            continue
        bones = r.get("bones") or "none"
        if bones not in ("none", "") and r.get("bones_difference"):
            bones += f" ({num(r['bones_difference'], 2)} mm)"
        met = "met" if truthy(r["reported_met"]) else "**not met**"
        eff = num(r["effectivity"]) if truthy(r["measurable"]) else f"{num(r['effectivity'])}, not measurable"
        share = float(r["time"]) / float(r["reference_time"]) if r.get("reference_time") else math.nan
        out.append([r["design"], tols,
                    f"P{r['degree']}, h = {float(r['size']):.3g}, {r['meshes']} meshes, {thousands(r['dofs'])} DOFs",
                    bones, f"{num(r['estimated_error'])} mm, {met}",
                    f"{num(r['error_vs_reference'])} mm (± {num(r['reference_uncertainty'], 2)})", eff,
                    f"{times} s ({num(share, 1)})"])
    return out


TOL_HEADER = ["design", "tol", "final mesh", "bones (b)", "estimated", "actual (reference's own scatter)",
              "effectivity", "time (share of the reference's)"]


def tol_check(_: dict) -> Table:
    rows_in, path = load_csv("tol_check/tol_check.csv", "python studies/tol_check.py")
    return Table(TOL_HEADER, _tol_rows(rows_in), "Uniform ladder (`--tol`); rows with the same answer merged.",
                 [path])


def tol_check_adaptive(_: dict) -> Table:
    rows_in, path = load_csv("tol_check/tol_check_adaptive.csv", "python studies/tol_check.py --adaptive")
    return Table(TOL_HEADER, _tol_rows(rows_in), "Adaptive rounds (`--tol --adaptive`); rows with the same answer "
                 "merged.", [path])


def scatter(_: dict) -> Table:
    files = [("finger_bones", "scatter/scatter.json"), ("finger_soft", "scatter/finger_soft/scatter.json"),
             ("finger_tapered_fillet", "scatter/finger_tapered_fillet/scatter.json")]
    rows, paths = [], []
    for name, rel in files:
        try:
            d, path = load_json(rel, f"python studies/scatter.py --design geometry/{name}.toml")
        except Missing:
            continue
        paths.append(path)
        xs = [r["markers"]["tip"][0] for r in d["rows"]]
        sizes = [r["size"] for r in d["rows"]]
        # the mesh farthest from the others' median, and the spread without it
        med = statistics.median(xs)
        far = max(range(len(xs)), key=lambda i: abs(xs[i] - med))
        rest = [x for i, x in enumerate(xs) if i != far]
        rows.append([d.get("design", name), f"{len(xs)} (h = {short(min(sizes))} … {short(max(sizes))})",
                     f"{num(d['std'][0], 2)} mm", f"{num(d['range'][0], 2)} mm",
                     f"h = {short(sizes[far])}: {num(statistics.pstdev(rest), 2)} / "
                     f"{num(max(rest) - min(rest), 2)} mm"])
    if not rows:
        raise Missing(OUTPUT / "scatter", "python studies/scatter.py")
    return Table(["design", "meshes", "tip x: standard deviation", "range",
                  "without the farthest mesh: std / range"], rows,
                 "Graded P2 meshes of nearly the same size, warm-started.", paths)


def adaptive_reach(_: dict) -> Table:
    d, path = load_json("adaptive/adaptive.json", "python studies/adaptive.py")
    tols = ["0.1", "0.05", "0.02"]
    rows = []
    for key in sorted(d["summary"]):
        s = d["summary"][key]
        cells = []
        for t in tols:
            v = s["reach"].get(t)
            if v is None:
                cells.append("–")
            elif isinstance(v, str):
                cells.append(v)
            else:
                cells.append(f"{thousands(v['dofs'])} ({v['time']:.1f} s)")
        rows.append([key] + cells + [f"{num(s['best_error'], 2)} mm"])
    refs = d.get("references", {})
    caption = ("DOFs (time) of the first answer within each error, against P2 references at h = "
               f"{short(d.get('ref_size'))} mm (their own scatter: "
               + ", ".join(f"{k} {num(v.get('scatter'), 2)} mm" for k, v in refs.items()) + ").")
    return Table(["design, method, degree"] + [f"within {t} mm" for t in tols] + ["smallest error"], rows,
                 caption, [path])


def adaptive_tol_runs(_: dict) -> Table:
    d, path = load_json("adaptive/adaptive.json", "python studies/adaptive.py")
    rows = []
    for r in d["tol_runs"]:
        if r.get("failed"):
            rows.append([r["design"], short(r["tol"]), r["method"], f"failed: {r['failed']}", "", "", "", ""])
            continue
        rows.append([r["design"], short(r["tol"]), r["method"], thousands(r["dofs"]), f"{r['time']:.1f} s",
                     f"{num(r['estimate'], 2)} mm", f"{num(r['error'], 2)} mm", "yes" if r["met"] else "no"])
    return Table(["design", "--tol [mm]", "method", "DOFs", "time", "estimated", "error", "met"], rows,
                 "P2 `--tol` runs of the adaptive study, uniform against adaptive.", [path])


STRATEGY_NOTES = {"none": "full Newton steps", "residual": "backtracking on |∇Π|",
                  "energy": "Armijo on Π, inversion guard, exact bone rotations; `auto` with bones",
                  "curved": "energy search along the geodesic curve, watchdog, ≤ 1 rad per step; `auto` without bones",
                  "trust_region": "PETSc newtontr"}


def stability(_: dict) -> Table:
    d, path = load_json("stability/summary.json", "python studies/stability.py")
    rows = []
    for name, s in d["strategies"].items():
        sl = d.get("slender", {}).get(name, {})
        rows.append([f"`{name}` ({STRATEGY_NOTES.get(name, '')})", f"{s['successes']}/{s['cases']}",
                     short(s["median_iterations"]),
                     f"{sl.get('successes', '–')}/{sl.get('cases', '–')}", secs(sl.get("total_time"))])
    caption = (f"finger.toml at h = {short(d['size'])} mm over bone/silicone stiffness ratios "
               f"{power(min(d['ratios']))} … {power(max(d['ratios']))} × contractions "
               f"{', '.join(short(c) for c in d['contractions'])} mm, with one load step and with four; "
               "and the slender bodies.")
    return Table(["strategy (`[solver].line_search`)", "stiffness-ratio map", "median iterations",
                  "slender cases", "slender time"], rows, caption, [path])


def friction_stability(_: dict) -> Table:
    d, path = load_json("friction_stability/summary.json", "python studies/friction_stability.py")
    rows = []
    for name, s in d["strategies"].items():
        fails = s["failures"]
        shown = "; ".join(fails[:4]) + (f"; and {len(fails) - 4} more" if len(fails) > 4 else "")
        refused = f" ({s['refused_cases']} refused: rigid objects)" if s.get("refused_cases") else ""
        rows.append([f"`{name}`", f"{s['successes']}/{s['cases']}{refused}", short(s["iterations_median"]),
                     short(s["iterations_max"]), secs(s["time"]), shown or "none"])
    caption = ("One load step from rest, default settings (step cutting on), per case x mu x contact stiffness; "
               f"a converged state farther than {short(d['agree_mm'])} mm from the energy line search's counts "
               "as failed.")
    return Table(["strategy", "converged", "median iterations", "most iterations", "time", "failed cases"], rows,
                 caption, [path])


def stability_slender(_: dict) -> Table:
    d, path = load_json("stability/summary.json", "python studies/stability.py")
    slender = d["slender"]
    names = list(slender)
    cases = list(next(iter(slender.values()))["iterations"])
    rows = [[case] + [("failed" if slender[n]["iterations"][case] is None else str(slender[n]["iterations"][case]))
                      for n in names] for case in cases]
    return Table(["case"] + [f"`{n}`" for n in names], rows,
                 "Newton iterations, every iteration of every attempt counted.", [path])


def peer(_: dict) -> Table:
    d, path = load_json("peer_comparison/summary.json", "python studies/peer_comparison.py")
    rows = []
    for c in d["cases"]:
        rows.append([short(c["size"]), f"{c['dofs']:,}", num(c["tip_difference"], 2), secs(c["time_skelfem"]),
                     secs(c["time_scikit_fem"]),
                     f"{secs(c['scikit_fem_jacobian_time'])} / {secs(c['scikit_fem_linear_solve_time'])}",
                     f"{c['speedup']:.0f}×"])
    return Table(["h [mm]", "DOFs", "tip difference [mm]", "skelfem", "scikit-fem",
                  "scikit-fem: Jacobians / sparse LU", "skelfem faster by"], rows,
                 f"The tendon strip, P{d['degree']}: same mesh, energy, quadrature and via points in both codes.",
                 [path])


def adversarial(_: dict) -> Table:
    d, path = load_json("adversarial.json", "python studies/adversarial.py")
    classes = ("ok", "bad_input", "failed", "interrupted")
    rows = []
    for group, g in d["groups"].items():
        other = sum(n for a, n in g["answers"].items() if a not in classes)
        rows.append([group, str(g["probes"]), str(g["clean"])] + [str(g["answers"].get(a, 0)) for a in classes]
                    + [str(other)])
    total = {a: sum(g["answers"].get(a, 0) for g in d["groups"].values()) for a in classes}
    rows.append(["**all**", f"**{d['probes']}**", f"**{d['clean']}**"] + [str(total[a]) for a in classes]
                + [str(d["probes"] - sum(total.values()))])
    found = ", ".join(f"{k} {v}" for k, v in sorted(d["findings_by_class"].items())) or "none"
    slowest = d.get("slowest_signal_s")
    caption = (f"Findings by class: {found}. The slowest end after a SIGINT: "
               f"{'–' if slowest is None else secs(slowest)}; its probes ran for {secs(d['seconds'])} in all."
               + (f" Stages were skipped: {d['stages_skipped']}" if d.get("stages_skipped") else ""))
    return Table(["group", "probes", "clean", "exit 0 / 200", "exit 1 / 4xx (bad input)",
                  "exit 2 / 503 / not converged (failed)", "interrupted", "other (exit 3, 500, hang, slow)"],
                 rows, caption, [path])


def adversarial_findings(_: dict) -> Table:
    d, path = load_json("adversarial.json", "python studies/adversarial.py")
    rows = [[r["group"], r["name"], r["answer"], "; ".join(f"{f['class']}: {f['what']}" for f in r["findings"])]
            for r in d["results"] if r["findings"]]
    return Table(["group", "probe", "answer", "finding"], rows or [["–", "none", "–", "–"]],
                 "Probes whose answer broke the contract in the kept run.", [path])


# -- tables of studies whose outputs are not kept in the repository ----------------------------------------
def pull_test(_: dict) -> Table:
    rows_in, path = load_csv("pull_test/pull_test.csv", "python studies/pull_test.py")
    loads = sorted({float(r["load_N"]) for r in rows_in})
    by: dict = {}
    for r in rows_in:
        by.setdefault(r["condition"], {})[float(r["load_N"])] = r["tip_axial_displacement_mm"]
    rows = [[cond] + [num(v.get(F)) for F in loads] for cond, v in by.items()]
    return Table(["load"] + [f"{short(F)} N" for F in loads], rows, "Axial tip displacement in mm.", [path])


def dynamics_checks(_: dict) -> Table:
    d, path = load_json("dynamics/dynamics_checks.json", "python studies/dynamics_checks.py")
    f, o, s = d["frequency"], d["orders"], d["slow_schedule"]
    rows = [["first bending frequency of a cantilever (BDF2)",
             f"{num(f['f_measured'], 4)} Hz against Euler–Bernoulli {num(f['f_euler_bernoulli'], 4)} Hz: "
             f"{100 * f['relative_error']:+.2f} %"]]
    for integ in ("euler", "bdf2"):
        rows.append([f"order in dt, {integ}", f"slope {o[integ]['slope']:.2f} (errors "
                     + ", ".join(num(e, 2) for e in o[integ]["errors_mm"]) + " mm)"])
    for e in d["energy"]:
        rows.append([f"energy from a sudden load, {e['integrator']}, damping {e['damping'] or 'none'}",
                     f"largest step change {e['max_increase_relative']:+.1e}; lost "
                     f"{100 * e['lost_relative']:.1f} % of max |Π|"])
    rows.append(["slow schedule against the static equilibrium",
                 f"{num(s['gap_mm'], 2)} mm: {num(s['relative'], 2)} of the {num(s['motion_mm'])} mm motion"])
    return Table(["check", "result"], rows, "", [path])


def grasp(_: dict) -> Table:
    d, path = load_json("grasp/grasp.json", "python studies/grasp.py")
    mus = [r["mu"] for r in d["results"]]
    by_density: dict = {}
    for r in d["results"]:
        for w in r["weighings"]:
            by_density.setdefault(w["density"], {})[r["mu"]] = w
    rows = []
    for density, cells in sorted(by_density.items()):
        known = next((w for w in cells.values() if "weight" in w), None)
        if known is None:
            continue
        row = [num(known["weight"]), num(known["mu_min"])]
        for mu in mus:
            w = cells.get(mu)
            if w is None or w.get("status") == "skipped":
                row.append("(not tried)")
            else:
                row.append(f"{'held' if w['held'] else 'lost'} ({w['newton_iterations']} its)")
        rows.append(row)
    return Table(["W (N)", "mu_min = W / sum N"] + [f"mu = {short(m)}" for m in mus], rows, "", [path])


def landing(_: dict) -> Table:
    d, path = load_json("landing/landing.json", "python studies/landing.py")
    families = {"slope": "box above a ground", "block": "box above the soft block",
                "stack": "two boxes above the block", "slope3d": "3D cube above a ground",
                "block3d": "3D cube above a block"}
    rows = []
    for r in d["rows"]:
        where = f"held, {num(r['along_slope'])} mm along the slope" if r["held"] else r["status"]
        rows.append([families.get(r["family"], r["family"]), short(r["theta"]), short(r["gap"]), short(r["mu"]),
                     str(r["steps"]), where, num(r["fall_along_slope"]), str(r["newton_iterations"]),
                     secs(r["time"]), thousands(r["dofs"])])
    return Table(["object", "theta (deg)", "gap (mm)", "mu", "steps", "from rest", "gap tan theta (mm)",
                  "Newton its", "solve", "DOFs"], rows, "", [path])


def grasp3d(_: dict) -> Table:
    d, path = load_json("grasp3d/grasp3d.json", "python studies/grasp3d.py")
    c = d["close"]
    rows = [["close (gravity off)", "–", "–", f"sum N = {num(c['normal_magnitude'])} N",
             f"{c['newton_iterations']} its, {secs(c['time'])}"]]
    for w in d["weighings"]:
        if w.get("status") == "skipped":
            rows.append([f"{short(w['ratio'])} mu sum N", "–", "–", "(not tried: a lighter one was lost)", "–"])
            continue
        verdict = ("held" if w["held"] else "lost") if "held" in w else w["status"]
        rows.append([f"{short(w['ratio'])} mu sum N", num(w["weight"]), num(w["mu_min"]) if "mu_min" in w else "–",
                     verdict, f"{w['newton_iterations']} its, {secs(w['time'])}"])
    return Table(["weighing", "W (N)", "mu_min = W / sum N", "result", "cost"], rows,
                 f"mu = {short(d['mu'])}, flexors {short(d['contraction'])} mm, {thousands(d['dofs'])} DOFs.", [path])


def grasp_bench(_: dict) -> Table:
    d, path = load_json("grasp_bench/grasp_bench.json", "python studies/grasp_bench.py")
    cells: dict = {}
    order: list = []
    before: dict = {}                         # the stage a weighing follows (per case and mu)
    for r in d["rows"]:
        stage = r["stage"]
        if stage == "weigh":
            stage = f"weigh after {before.get((r['case'], r['mu']), 'closing')}"
        else:
            before[(r["case"], r["mu"])] = stage
        key = (r["case"], stage)
        if key not in cells:
            cells[key] = {}
            order.append(key)
        text = f"{r['newton_iterations']} its, {secs(r['time'])}"
        if r["status"] != "converged":
            text = f"{r['status']} ({text})"
        cells[key]["with" if r["mu"] > 0 else "without"] = text
    rows = [[f"{case}: {stage}", c.get("with", "–"), c.get("without", "–")] for (case, stage), c in
            ((k, cells[k]) for k in order)]
    return Table(["solve", "with friction", "without friction"], rows, "", [path])


def cable_friction(_: dict) -> Table:
    d, path = load_json("cable_friction/cable_friction.json", "python studies/cable_friction.py")
    rows = []
    for w in d["widths"]:
        f = w.get("full") or {}
        status = "" if w["status"] == "converged" else f" ({w['status']})"
        rows.append([short(w["mu"]), f"{num(w['loop_width'])} mm at {short(w['at'])} mm" if w["loop_width"] > 1e-6
                     else "0", num(f.get("tip_x")), num(f.get("tension_actuated")), num(f.get("tension_far")),
                     f"{w['newton_iterations']}{status}"])
    p = d["params"]
    push = "; ".join(f"mu = {short(x['mu'])}: {num(x['force_gap'], 2)} N" for x in d.get("push", []))
    caption = (f"{d['design']}, its flexor with friction mu, h = {short(p['size'])} mm: contraction 0 → "
               f"{short(p['top'])} → 0 mm in steps of {short(p['top'] / p['steps'])} mm; tip x and tensions at "
               f"{short(p['top'])} mm on the way up. Loop width: the largest |tip x up − tip x down| at one "
               f"contraction. Push test (flexor held at {short(p['pre'])} mm), largest gap between the sensor "
               f"force down and back: {push}.")
    return Table(["mu", "loop width", "tip x [mm]", "tension, actuated end [N]", "tension, far end [N]",
                  "Newton iterations (cycle)"], rows, caption, [path])


def capstan(_: dict) -> Table:
    cmd = "python studies/cable_friction_bench.py"
    rows_c, path = load_csv("cable_friction_bench/capstan.csv", cmd)
    rows_o, path_o = load_csv("cable_friction_bench/order.csv", cmd)
    rows = [[f"{float(r['theta']) / math.pi:g} π", short(r["mu"]), num(r["ratio"], 5), num(r["capstan"], 5),
             f"{float(r['error']):+.3%}", r["newton_iterations"]] for r in rows_c]
    order = ", ".join(f"{num(r['observed_order'])}" for r in rows_o if r["observed_order"])
    spacing = ", ".join(f"{short(r['degrees_per_via_point'])}°: {float(r['error']):+.2%}" for r in rows_o)
    caption = ("A tendon through a channel in a rigid pulley, pulled 3 mm, its far end in the silicone beside it; "
               "a via point every 5° of the arc. Ratio: tension entering the arc over tension leaving it; "
               "Θ measured on the deformed via points. Refining the spacing at Θ = 2π, mu = 0.3 "
               f"({spacing}): observed order {order}.")
    return Table(["Θ", "mu", "ratio", "e^(mu Θ)", "error", "Newton iterations"], rows, caption, [path, path_o])


def cable_friction_cost(_: dict) -> Table:
    rows_i, path = load_csv("cable_friction_bench/iterations.csv", "python studies/cable_friction_bench.py")
    rows = [[f"`{r['design']}`", short(r["mu"]), r["newton_iterations"], f"{float(r['ratio_to_frictionless']):.2f}×",
             num(r["time"], 2), num(r["tension_actuated_end"]), num(r["tension_far_end"])] for r in rows_i]
    caption = ("Each bundled finger solved from rest as bundled, every cable with friction mu; time in seconds "
               "on this machine (one run each).")
    return Table(["design", "mu", "Newton iterations", "against mu = 0", "time [s]", "tendon, actuated end [N]",
                  "far end [N]"], rows, caption, [path])


def cable_friction_speed(_: dict) -> Table:
    d, path = load_json("cable_friction_cost/cable_friction_cost.json", "python studies/cable_friction_cost.py")

    def pair(on, off, key: str, fmt=str) -> list[str]:
        a, b = on[key], off[key]
        return [f"{fmt(a)} / {fmt(b)}", f"{a / b:.2f}×"]
    rows = [[f"statics: `{r['design']}`, friction {r['friction']}"]
            + pair(r["with"], r["without"], "newton_iterations") + pair(r["with"], r["without"], "time", secs)
            for r in d["statics"]]
    rev = {r["mu"]: r for r in d["reversal"]}
    mu = max(rev)
    for m in (mu, 0.0):
        r = rev[m]
        rows.append([f"`finger` cycle, mu {short(m)}: a step up (mean) / the first step down",
                     f"{num(r['up_mean'], 2)} / {r['reversal']}", f"{r['reversal'] / r['up_mean']:.2f}×", "", ""])
    rows.append([f"`finger` whole cycle, mu {short(mu)} / 0"] + pair(rev[mu], rev[0.0], "cycle_iterations")
                + pair(rev[mu], rev[0.0], "time", secs))
    dyn = {r["mu"]: r for r in d["in_time"]}
    on, off = dyn[max(dyn)], dyn[0.0]
    rows.append([f"in time: `flick`, flexor friction {short(max(dyn))} / 0"] + pair(on, off, "newton_iterations")
                + pair(on, off, "time", secs))
    return Table(["case", "Newton iterations, with / without friction", "ratio", "time, with / without",
                  "ratio"], rows,
                 "Statics: a solve from rest, best wall time of three fresh sessions (Session built outside the "
                 "timer) on a machine shared with other work, so time ratios are good to about ±0.3. The cycle: "
                 "flexor 0 → 8 mm → 0 in 8 steps each way at mesh size 2. No bundled 3D design has cable "
                 "friction.", [path])


def hand_grasp(_: dict) -> Table:
    d, path = load_json("hand_grasp/hand_grasp.json", "python studies/hand_grasp.py")

    def cell(w) -> str:
        return f"{num(w['weight'])} N ({num(w['margin'])} / {num(w['margin_pads'])})"
    rows = []
    for r in d["results"]:
        c = r["close"]
        if not c.get("converged"):
            rows.append([r["shape"], short(r["mu"]), f"not closed: {c['status']}", "–", "–", "–"])
            continue
        f = c["fingers"]
        tried = [w for w in r["weighings"] if "held" in w]
        held = [w for w in tried if w["held"]]
        lost = next((w for w in tried if not w["held"]), None)
        last = cell(lost) if lost else "none (heaviest tried held)"
        if lost and not lost["status"].startswith("no equilibrium"):
            last += f" ({lost['status'].split(' (')[0]})"
        moved = held[-1]["moved"] if held else None
        rows.append([r["shape"], short(r["mu"]), f"{num(f['left'])} / {num(f['centre'])} / {num(f['right'])}",
                     cell(held[-1]) if held else "none held", last,
                     (f"({num(moved['displacement'][0], 2)}, {num(moved['displacement'][1], 2)}) mm, "
                      f"{num(math.degrees(moved['rotation']), 2)}°") if moved else "–"])
    p = d["params"]
    caption = (f"Outer flexors {short(p['contraction'])} mm, centre flexor {short(p['centre'])} mm, mesh "
               f"{short(p['size'])} mm; densities {short(p['densities'][0])} to {short(p['densities'][-1])} kg/m^3 "
               f"in steps of {short(p['densities'][1] - p['densities'][0]) if len(p['densities']) > 1 else '–'}. "
               "Margin: mu / mu_min, with mu_min = W / sum N of the three contacts (as the gripper) and "
               "W / (N_left + N_right) of the outer fingers (pads). Moved: the heaviest held object's "
               f"displacement and turn since the closed grip. {d['agree_with_mu_min']} of {d['weighings']} "
               f"weighings agree with the three contacts' mu_min, {d['agree_with_mu_min_pads']} with the pads'.")
    return Table(["shape", "mu", "closed: N left / centre / right (N)", "heaviest held: W (margin three / pads)",
                  "first lost: W (margin three / pads)", "held object moved"], rows, caption, [path])


def linear_scaling(opts: dict) -> Table:
    folder = opts.get("folder", "linear_scaling")
    d, path = load_json(f"{folder}/linear_scaling.json", "python studies/linear_scaling.py"
                        + ("" if folder == "linear_scaling" else f" --out studies/output/{folder} ..."))
    rows = []
    for r in d["rows"]:
        its = r["krylov_per_newton"]
        rows.append([thousands(r["dofs"]) if r["dofs"] else "–", r["solver"], secs(r["wall_s"]),
                     f"{num(r['peak_mb'])} MB", num(r.get("kb_per_dof")),
                     str(r["newton_iterations"]), span(its, str) if its else "–", str(r["fallbacks"]),
                     f"{num(r['time_ratio'])} / {num(r['memory_ratio'])}" if "time_ratio" in r else "",
                     num(r["marker_difference_mm"]) if "marker_difference_mm" in r else "", r["status"]])
    return Table(["DOFs", "solver", "wall time", "peak memory", "KB / DOF", "Newton its", "Krylov its per step",
                  "fallbacks", "iterative / direct: time / memory", "tip difference (mm)", "status"], rows,
                 f"{d['design']}, P{d['degree']}: one `skelfem simulate` per row, in its own process "
                 f"({d['cpu']} cores); peak memory is the process's maximum resident set, the interpreter "
                 "and DOLFINx included.", [path])


def arm3d_fine(_: dict) -> Table:
    d, path = load_json("arm3d_fine/arm3d_fine.json", "python studies/arm3d_fine.py")
    t = d["timings"]
    rows = [["DOFs (P1 tetrahedra)", f"{thousands(d['dofs'])} ({thousands(d['cells'])})"],
            ["wall time (meshing, compile, solve)", f"{secs(d['wall_s'])} ({secs(t['mesh'])}, {secs(t['compile'])}, "
                                                    f"{secs(t['solve'])})"],
            ["Newton iterations; Krylov per step (mean)",
             f"{d['newton_iterations']}; {span(d['krylov_per_newton'], str)} "
                                                          f"({num(d['krylov_mean'])})"],
            ["fallbacks to MUMPS", str(d["linear_fallbacks"])],
            ["peak memory", f"{num(d['peak_gb'])} GB, {num(d['kb_per_dof'])} KB per DOF"],
            ["tendon tensions (N)", ", ".join(f"{k} {num(v)}" for k, v in d["tensions"].items())]]
    note = d.get("note") or f"one run on {d.get('ranks', 1)} rank(s), peak memory summed over them"
    return Table([f"arm3d at h = {d.get('size', 0.62)} mm, iterative", ""], rows, note + "; `" + d["command"] + "`",
                 [path])


def reference_3d(_: dict) -> Table:
    d, path = load_json("reference_3d/reference_3d.json", "python studies/reference_3d.py")
    rows = [[r["solver"], thousands(r["dofs"]) if r["dofs"] else "–", secs(r["wall_s"]), f"{num(r['peak_gb'])} GB",
             str(r["newton_iterations"]), str(r["fallbacks"]), r["status"]] for r in d["rows"]]
    return Table(["solver", "DOFs (finest)", "wall time", "peak memory", "Newton its (finest)", "fallbacks", "status"],
                 rows, f"{d['design']}'s P2 reference at h = {d['h_ref']} (three graded meshes, warm-started), "
                       "each solver in its own process.", [path])


def krylov_bounds(_: dict) -> Table:
    d, path = load_json("krylov_bounds/krylov_bounds.json", "python studies/krylov_bounds.py")
    what = {"refinement": "refinement, elastic bones", "refinement_rigid": "refinement, rigid bones",
            "contrast": "E_bone / E_body", "nu": "nu of the body"}
    rows = []
    for sweep, rs in d["sweeps"].items():
        for r in rs:
            value = r.get("size", r.get("contrast", r.get("nu")))
            fresh = r.get("krylov_fresh")
            rows.append([what[sweep], f"h = {r['size']:g}" if "size" in r else str(value),
                         thousands(r["dofs"]), str(r["newton_iterations"]), num(r["krylov_mean"]),
                         str(r["krylov_max"]), "–" if fresh is None else str(fresh),
                         f"{r['fallbacks']} / {r.get('loose_steps', 0)}", secs(r["solve_s"]), r["status"]])
        fresh_ratio = d.get("fresh_ratios", {}).get(sweep)
        rows.append([f"**{what[sweep]}**", "largest / smallest", "", "", f"**{num(d['ratios'][sweep])}**",
                     "", "–" if fresh_ratio is None else f"**{num(fresh_ratio)}**", "", "", ""])
    return Table(["sweep", "case", "DOFs", "Newton its", "Krylov its per Newton step (mean)", "max",
                  f"converged tangent to {d.get('fresh_rtol', 1e-8):g}, fresh multigrid",
                  "fallbacks / loose steps", "solve",
                  "status"], rows,
                 f"{d['design']}: one solve from rest per row, [solver] linear = \"iterative\"; refinement at "
                 "P1, contrast and Poisson's ratio at P2.", [path])


def estimate_effectivity(_: dict) -> Table:
    d, path = load_json("estimate_effectivity/estimate_effectivity.json",
                        "python studies/estimate_effectivity.py")
    rows = []
    for r in d["rows"]:
        if not r["measurable"] and r["observable"].startswith("pins"):
            continue                                   # reactions of a body nothing else holds: round-off
        eff = "–" if r["effectivity"] is None else num(r["effectivity"], 2)
        rows.append([r["case"], f"P{r['degree']}, {thousands(r['dofs'])}", f"`{r['observable']}`", num(r["value"], 4),
                     num(r["true_error"], 2), num(r["reference_uncertainty"], 1), num(r["estimate"], 2),
                     f"**{eff}**" if r["effectivity"] is not None and not 0.5 <= r["effectivity"] <= 2 else eff])
    s = d["summary"]
    cap = (f"{s['measurable']} measurable rows of {s['rows']}: {s['within_0.5_2']} with an effectivity in [0.5, 2], "
           f"{s['within_0.33_3']} in [1/3, 3], {s['below_0.1']} below 0.1 "
           f"(range {num(s['min'], 2)}–{num(s['max'], 2)}); "
           f"tip and tension within [0.5, 2]: {s['tip_and_tension_within_0.5_2']}. "
           "A row is measurable when its true error is at least three times the references' own difference; "
           "bold: outside [0.5, 2].")
    return Table(["case", "mesh", "observable", "value", "true error", "reference ±", "estimate", "effectivity"],
                 rows, cap, [path])


def estimate_cost(_: dict) -> Table:
    d, path = load_json("estimate_effectivity/estimate_effectivity.json",
                        "python studies/estimate_effectivity.py")
    rows = [[case, thousands(c["dofs"]), secs(c["solve_s"]), secs(c["estimate_s"]), f"**{num(c['ratio'], 2)}**",
             secs(c["compile_s"])] for case, c in d["summary"]["cost"].items()]
    return Table(["case", "DOFs", "solve", "estimate", "estimate / solve", "its forms compiled (once)"], rows,
                 "Wall times in one process, one after the other (on a shared machine); the richer degree's forms are "
                 "compiled once per machine (FFCx's cache), counted apart. CPU times: the next table.", [path])


def estimate_cost_cpu(_: dict) -> Table:
    d, path = load_json("estimate_cost/estimate_cost.json", "python studies/estimate_cost.py")
    rows = [[r["case"].replace(":", ", h = ") + " mm", f"{r['dim']}D", thousands(r["dofs"]),
             str(r["newton_iterations"]), secs(r["solve_cpu_s"]), secs(r["estimate_cpu_s"]),
             f"**{num(r['ratio_cpu'], 2)}**",
             thousands(r["richer_dofs"]), str(r["richer_newton_iterations"]),
             "–" if r["krylov_iterations"] is None else str(r["krylov_iterations"]), secs(r["algebraic_s"])]
            for r in d]
    return Table(["design", "", "DOFs (P1)", "Newton its", "solve (CPU)", "estimate (CPU)", "estimate / solve",
                  "richer DOFs (P2)", "its Newton its", "Krylov its", "algebraic part"], rows,
                 "CPU seconds of one process (time.process_time), the solve from rest and then the estimate; the "
                 "richer solve is MUMPS in 2D and below 30k DOFs, CG with two-level p-multigrid in 3D above.", [path])


def estimate_effectivity_h(_: dict) -> Table:
    d, path = load_json("estimate_effectivity/estimate_effectivity_h.json",
                        "python studies/estimate_effectivity.py --sweep block3d block3d_in_bone block3d_anchor3")
    rows = []
    for r in d:
        eff = "–" if r["effectivity"] is None else num(r["effectivity"], 2)
        rows.append([r["case"], f"{num(r['h'])} mm, {thousands(r['dofs'])}", f"`{r['observable']}`",
                     num(r["true_error"], 2), num(r["reference_uncertainty"], 1), num(r["estimate"], 2),
                     f"**{eff}**" if r["effectivity"] is not None and not 0.5 <= r["effectivity"] <= 2 else eff])
    ref = d[0]
    return Table(["design", "P1 mesh, DOFs", "observable", "true error", "reference ±", "estimate", "effectivity"],
                 rows, f"The reference is P2 at h = {num(ref['reference_h'])} mm ({thousands(ref['reference_dofs'])} "
                 "DOFs on the block), its uncertainty its change from P2 at 1.5 mm; bold: outside [0.5, 2].", [path])


def goal_oriented(_: dict) -> Table:
    d, path = load_json("goal_oriented/goal_oriented.json", "python studies/goal_oriented.py")
    rows = []
    for c in d:
        for method in ("uniform", "goal"):
            pts = ", ".join(f"{thousands(r['dofs'])}: {num(r['error'], 2)}" for r in c[method])
            rows.append([c["case"], method, pts, thousands(round(c[f"dofs_{method}"])) if c[f"dofs_{method}"] else "–"])
        rows.append([c["case"], "**uniform / goal**", "", f"**{num(c['ratio'], 2)}**" if c["ratio"] else "–"])
    return Table(["design", "refinement", "DOFs: tension error [N], mesh by mesh", "DOFs to 1 % error"], rows,
                 "P2; the reference is P2 on a finer uniform mesh (" + "; ".join(
                     f"{c['case']}: {num(c['reference']['tension'], 4)} N ± {num(c['reference']['uncertainty'], 1)}"
                     for c in d) + ").", [path])


def hand_scenario(_: dict) -> Table:
    d, path = load_json("hand_scenario/hand_scenario.json", "python studies/hand_scenario.py")
    rows = []
    for name in ("hand", "gripper3d"):
        if name not in d:
            continue
        r = d[name]
        by = r.get("worst_follow", {}).get("by_stage", {})
        for st in r["stages"]:
            ok = st["converged"]
            rows.append([r["design"], st["name"], st["status"], f"{st['newton_iterations']} / {st['load_steps']}",
                         ", ".join(num(v, 4) for v in st["object"]) if ok else "–",
                         num(st["object_angle"], 3) if ok else "–",
                         f"{100 * by[st['name']]:.2f} %" if st["name"] in by else "–",
                         num(st["normal"], 3) if ok else "–",
                         num(math.hypot(*st["ground_force"]), 3) if ok else "–"])
    caption = "; ".join(f"{d[n]['design']}: {d[n]['dofs']:,} DOFs, {secs(d[n]['time'])}, object "
                        f"{num(d[n]['size'], 3)} mm across (its box's diagonal)"
                        for n in ("hand", "gripper3d") if n in d)
    return Table(["design", "stage", "status", "Newton its / load steps", "object centroid [mm]", "object turned [°]",
                  "held: off the base's motion (worst, % of size)", "fingers' normal force [N]",
                  "ground's normal force [N]"], rows, caption + ".", [path])


def knuckle_contact3d(_: dict) -> Table:
    d, path = load_json("knuckle_contact3d/knuckle_contact3d.json", "python studies/knuckle_contact3d.py")
    names = {"on": "self-contact on", "projected": "on, Hessian projected throughout", "off": "self-contact off",
             "grown": "on (pattern grows)", "full": "on, whole boundary block"}
    rows = []
    for key in ("on", "projected", "off", "grown", "full"):
        if key not in d:
            continue
        r = d[key]
        rows.append([names[key], f"{short(r['size'])} mm, {thousands(r['dofs'])}", r["status"],
                     f"{r['newton_iterations']} ({', '.join(str(s['iterations']) for s in r['steps'])})",
                     str(r["meet_step"]) if key != "off" and r["meet_step"] else "–",
                     num(r["min_distance"]), num(r["final_distance"]), "yes" if r["intersects"] else "no",
                     thousands(r["pattern_pairs"]) if r["pattern_pairs"] else "–",
                     f"{secs(r['solve_time'])} ({secs(r.get('solve_cpu'))} CPU)"])
    on = d["on"]
    return Table(["run", "mesh, DOFs", "status", "Newton its (per load step)", "knuckles meet in step",
                  "min distance over iterates [mm]", "final [mm]", "triangles intersect", "pattern node pairs",
                  "solve (wall, CPU)"], rows,
                 f"finger_knuckles3d.toml, flexor {short(on['contraction'])} mm in {len(on['steps'])} load steps, "
                 f"dhat = {short(on['dhat'])} mm, {on['boundary_nodes']:,} boundary nodes on the "
                 f"{short(on['size'])} mm mesh; distances are ipctk's between non-adjacent boundary parts.", [path])


TABLES = {f.__name__: f for f in (estimate_effectivity, estimate_cost, estimate_cost_cpu, estimate_effectivity_h,
                                  goal_oriented,
                                  linear_scaling, krylov_bounds, arm3d_fine, reference_3d, bench, in_hand_roll,
                                  slice_check, slice_check_3mf, fabrication_volumes, fabrication_poses, mpi_speed,
                                  editor_latency, editor_latency_sizes, editor_latency3d,
                                  rigid_bones_2d, rigid_bones_3d, speed_accuracy,
                                  tol_check, tol_check_adaptive, scatter, adaptive_reach, adaptive_tol_runs,
                                  stability, stability_slender, friction_stability, peer, pull_test, dynamics_checks,
                                  grasp, grasp3d, hand_grasp, hand_scenario, grasp_bench, landing,
                                  cable_friction, capstan, cable_friction_cost, cable_friction_speed, adversarial,
                                  adversarial_findings, knuckle_contact3d)}


# -- docutils -----------------------------------------------------------------------------------------------
def _inline(text: str) -> list[nodes.Node]:
    """Cell text with `code` and **bold** spans."""
    out: list[nodes.Node] = []
    i = 0
    while i < len(text):
        if text.startswith("**", i) and "**" in text[i + 2:]:
            j = text.index("**", i + 2)
            out.append(nodes.strong(text=text[i + 2:j]))
            i = j + 2
        elif text[i] == "`" and "`" in text[i + 1:]:
            j = text.index("`", i + 1)
            out.append(nodes.literal(text=text[i + 1:j]))
            i = j + 1
        else:
            j = min([k for k in (text.find("`", i), text.find("**", i)) if k >= 0] or [len(text)])
            if j == i:
                j = i + 1
            out.append(nodes.Text(text[i:j]))
            i = j
    return out


def build_table(t: Table) -> list[nodes.Node]:
    table = nodes.table(classes=["study-table"])
    group = nodes.tgroup(cols=len(t.header))
    table += group
    for _ in t.header:
        group += nodes.colspec(colwidth=1)
    head = nodes.thead()
    group += head
    row = nodes.row()
    for h in t.header:
        row += nodes.entry("", nodes.paragraph("", "", *_inline(h)))
    head += row
    body = nodes.tbody()
    group += body
    for cells in t.rows:
        row = nodes.row()
        for c in cells + [""] * (len(t.header) - len(cells)):
            row += nodes.entry("", nodes.paragraph("", "", *_inline(str(c))))
        body += row
    source = ", ".join(f"studies/output/{p.relative_to(OUTPUT)}" for p in t.files)
    note = nodes.paragraph(classes=["study-table-source"])
    if t.caption:
        note += _inline(t.caption + " ")
    note += nodes.emphasis(text="From ")
    note += nodes.literal(text=source)
    note += nodes.emphasis(text=", read when these pages were built.")
    return [table, note]


class StudyTable(SphinxDirective):
    """```{study-table} NAME``` with options given as ``:problem: strip``."""

    required_arguments = 1
    option_spec = {"problem": directives.unchanged, "folder": directives.unchanged}

    def run(self):
        name = self.arguments[0]
        if name not in TABLES:
            raise self.error(f"study-table: no table {name!r}; known: {', '.join(sorted(TABLES))}")
        try:
            t = TABLES[name](dict(self.options))
        except Missing as e:
            path, command = e.args
            self.env.note_dependency(str(path))
            para = nodes.paragraph()
            para += nodes.Text("This table is made from ")
            para += nodes.literal(text=str(Path(path).relative_to(ROOT)))
            para += nodes.Text(", which is not in this checkout: ")
            para += nodes.literal(text=command)
            para += nodes.Text(" writes it; rebuild the docs afterwards to see it here.")
            return [nodes.note("", para)]
        for p in t.files:
            self.env.note_dependency(str(p))
        return build_table(t)


def setup(app):
    app.add_directive("study-table", StudyTable)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
