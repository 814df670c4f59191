"""How fast the editor answers a drag: from the pointer event to the updated picture, in the browser.

Serves a design (default: the demo, geometry/finger.toml) with `skelfem edit`'s
server, opens it in headless Chromium (Debian's, through Selenium) and drags
with real pointer input (one move every `step_ms` ms, as a mouse sends them;
each drag starts PAUSE s after the last picture of the one before):

* contraction: the flexor's slider, back and forth (a live parameter: warm
  re-solve on the same mesh);
* vertex: a vertex of the distal bone, back and forth (drafts move the
  mesh's nodes with the bone while dragging; a new mesh on release).

The page marks every input event (``performance.mark("input-N")``) and the
frame after the picture that shows it (``paint-N``); ``performance.measure``
gives, for every request it sends, the time from the input event that request
carries to the picture of its answer ("rendered"). Moves that arrive while a
solve runs are merged into the next request (latest wins, never queued): the
time from *every* input event to the first picture that includes it is
reported too ("every event"). Finally `POST /api/solve` is timed from a
script for a one-vertex change (a bone vertex moved 0.5 mm, alternately) and
a contraction change. Prints p50 / p95 and writes latency.json to `out`, with
the host's load average (os.getloadavg) when the run ended.

While dragging, the page sends drafts; the server stops each draft's Newton
steps at the frame budget (skelfem.editor.engine.FRAME_SECONDS) and the page
asks again for the same design until it is converged ("go on" in the server
times). Every answer's certificate is counted: previews, converged ones, and
converged ones whose residual is above the batch tolerance (never, if the
page is right).

The same is measured on finer meshes of the design (``--sizes``, mesh sizes in
mm: 0.9 and 0.5 give finger.toml about 6k and 20k DOFs; the study writes those
variants of the design), each in its own editor and browser, with fewer
``POST`` requests (``--api-fine``). For a release it also times the first
converged picture after it ("settled": the page asks again after every frame
out of time). The host's load average and ``uptime`` are recorded before and
after each case.

    python studies/editor_latency.py [DESIGN] [--moves 30] [--drags 4] [--api 20] [--sizes 0.9 0.5] [--out DIR]
"""
from __future__ import annotations

import argparse
import copy
import http.client
import json
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SIZES = (0.9, 0.5)      # finer meshes of the design (mm): finger.toml at about 6k and 20k DOFs
PAUSE = 0.5             # s from the last picture of a drag to the next drag (a hand lets go and grabs again)


def percentiles(values) -> dict:
    v = np.asarray(values, dtype=float)
    if not len(v):
        return {"n": 0, "p50": None, "p95": None, "max": None}
    return {"n": int(len(v)), "p50": float(np.percentile(v, 50)), "p95": float(np.percentile(v, 95)),
            "max": float(v.max())}


def reset_marks(page) -> None:
    page.js("(() => { S.latency = {rendered: [], events: [], settled: []}; S.server = []; S.renderMs = [];"
            " S.certificates = [];"
            " performance.clearMarks(); performance.clearMeasures(); return 1; })()")


def _collect(page) -> dict:
    measures = page.js("performance.getEntriesByType('measure').map(m => [m.name, m.duration])")
    events = page.js("S.latency.events.map(e => [e.kind, e.ms])")
    settled = page.js("S.latency.settled.map(e => [e.kind, e.ms])")
    server = page.js("S.server.map(e => [e.how, 1000 * e.s, e.rtt])")
    certs = page.js("S.certificates")
    out: dict = {"rendered": {}, "every_event": {}, "server_ms": {}, "round_trip_ms": {},
                 "settled": {k: percentiles([ms for kind, ms in settled if kind == k])
                             for k in sorted({k for k, _ in settled})},
                 "render_ms": percentiles(page.js("S.renderMs")),
                 "certificates": {"converged": sum(c["state"] == "converged" for c in certs),
                                  "preview": sum(c["state"] == "preview" for c in certs),
                                  # the page never says converged above the batch tolerance: this stays 0
                                  "converged_above_tolerance": sum(c["state"] == "converged" and
                                                                   not (c["ratio"] is not None and c["ratio"] <= 1)
                                                                   for c in certs),
                                  "last": certs[-1]["state"] if certs else None}}
    kinds = sorted({name.split("-")[1] for name, _ in measures} | {k for k, _ in events})
    for kind in kinds:
        out["rendered"][kind] = percentiles([ms for name, ms in measures if name.split("-")[1] == kind])
        out["every_event"][kind] = percentiles([ms for k, ms in events if k == kind])
    for how in sorted({h for h, _, _ in server}):
        out["server_ms"][how] = percentiles([ms for h, ms, _ in server if h == how])
        out["round_trip_ms"][how] = percentiles([rtt for h, _, rtt in server if h == how])
    return out


def _slider_drags(page, moves: int, drags: int, step_ms: int) -> None:
    css = "#sliders input[data-cable]"
    _, y = page.center(css)
    rect = page.js("document.querySelector(arguments[0]).getBoundingClientRect().toJSON()", css)
    for k in range(drags):
        x0 = page.js("(() => { const r = document.querySelector(arguments[0]); const b = r.getBoundingClientRect();"
                     " return b.left + 8 + (r.value / r.max) * (b.width - 16); })()", css)
        span = 0.15 * rect["width"] * (-1 if k % 2 == 0 else 1)
        page.drag((x0, y), [(x0 + span * i / moves, y) for i in range(1, moves + 1)], step_ms)
        page.idle()
        time.sleep(PAUSE)


def _vertex_drags(page, moves: int, drags: int, step_ms: int, path) -> None:
    css = page.handle_css(path)
    for k in range(drags):
        x0, y0 = page.center(css)
        dx = 12.0 * (-1 if k % 2 == 0 else 1)
        page.drag((x0, y0), [(x0 + dx * i / moves, y0 + 0.5 * dx * i / moves) for i in range(1, moves + 1)],
                  step_ms)
        page.idle()
        time.sleep(PAUSE)


def _post(port: int, path: str, body) -> tuple[int, float, dict]:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=120)
    data = json.dumps(body).encode()
    t0 = time.perf_counter()
    conn.request("POST", path, body=data, headers={"Content-Type": "application/json"})
    r = conn.getresponse()
    answer = json.loads(r.read())
    dt = time.perf_counter() - t0
    conn.close()
    return r.status, 1000 * dt, answer


def _api(port: int, design: dict, repeats: int) -> dict:
    _post(port, "/api/solve", design)
    vertex, contraction, hows = [], [], set()
    for k in range(repeats):
        d = copy.deepcopy(design)
        d["bones"][-1]["outline"][0][0] += 0.5 * ((k + 1) % 2)      # moved, back, moved, ...: never unchanged
        status, ms, a = _post(port, "/api/solve", d)
        assert status == 200 and a["converged"], a.get("error") or a.get("status")
        vertex.append(ms)
        hows.add(a["editor"]["how"])
    for k in range(repeats):
        d = copy.deepcopy(design)
        d["cables"][0]["contraction"] = float(d["cables"][0].get("contraction", 0.0)) + 0.5 * ((k + 1) % 2)
        status, ms, a = _post(port, "/api/solve", d)
        assert status == 200 and a["converged"]
        contraction.append(ms)
    return {"one_vertex_ms": percentiles(vertex), "contraction_ms": percentiles(contraction), "hows": sorted(hows)}


class GcClock:
    """The cyclic garbage collector's pauses in this process (the editor's server and solver run here):
    collections per generation, their total and longest time (ms); the worker's own collections between
    requests (Worker.tidying) apart, as ``idle`` (count, total ms)."""

    def __init__(self, worker=None):
        self.worker, self.start, self.runs, self.total, self.longest = worker, 0.0, [0, 0, 0], 0.0, 0.0
        self.idle = [0, 0.0]

    def __call__(self, phase: str, info: dict) -> None:
        if phase == "start":
            self.start = time.perf_counter()
            return
        dt = 1000 * (time.perf_counter() - self.start)
        if self.worker is not None and self.worker.tidying:
            self.idle = [self.idle[0] + 1, self.idle[1] + dt]
            return
        self.runs[info["generation"]] += 1
        self.total, self.longest = self.total + dt, max(self.longest, dt)

    def __enter__(self):
        import gc
        gc.callbacks.append(self)
        return self

    def __exit__(self, *exc):
        import gc
        gc.callbacks.remove(self)

    def to_dict(self) -> dict:
        return {"collections": list(self.runs), "total_ms": round(self.total, 2), "longest_ms": round(self.longest, 2),
                "idle": {"collections": self.idle[0], "total_ms": round(self.idle[1], 2)}}


def host_load() -> dict:
    try:
        up = subprocess.run(["uptime"], capture_output=True, text=True, timeout=5).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        up = ""
    return {"load_average": list(os.getloadavg()), "uptime": up}


def _variant(design: Path, size: float | None, work: Path) -> Path:
    """The design copied into work, at mesh size `size` (mm) if given (the TOML written again)."""
    if size is None:
        shutil.copy(design, work / design.name)
        return work / design.name
    import tomllib

    from skelfem.editor.savefile import render
    raw = tomllib.loads(design.read_text())
    raw.setdefault("mesh", {})["size"] = float(size)
    path = work / f"{design.stem}_h{size:g}.toml"
    path.write_text(render(design.read_text(), raw, default_name=design.stem))
    return path


def run_case(design: Path, size: float | None = None, moves: int = 30, drags: int = 4, api: int = 20,
             step_ms: int = 16, screenshot=None) -> dict:
    """One design (at mesh size `size`): the browser's drags, then the API's solves; see the module doc."""
    import tomllib

    from skelfem.editor.browser import Page, chrome
    from skelfem.editor.server import Editor

    work = Path(tempfile.mkdtemp(prefix="skelfem-latency-"))
    path = _variant(design, size, work)
    raw = tomllib.loads(path.read_text())
    bone = len(raw.get("bones", [])) - 1
    before = host_load()
    editor = Editor(path, port=0).start()
    driver = None
    try:
        driver = chrome()
        page = Page(driver, editor.url, timeout=300)
        _vertex_drags(page, 5, 2, step_ms, ["bones", bone, "outline", 0])      # warm-up: draft and full meshes
        _slider_drags(page, 5, 2, step_ms)
        reset_marks(page)
        t0 = time.perf_counter()
        with GcClock(editor.worker) as gc_clock:
            _slider_drags(page, moves, drags, step_ms)
            contraction = _collect(page)
            reset_marks(page)
            _vertex_drags(page, moves, drags, step_ms, ["bones", bone, "outline", 0])
            vertex = _collect(page)
        browser_seconds = time.perf_counter() - t0
        if screenshot is not None:
            Path(screenshot).parent.mkdir(parents=True, exist_ok=True)
            page.screenshot(screenshot)
        answer = page.js("S.answer")
        errors = [e["message"] for e in page.console_errors()]
        api_times = _api(editor.port, raw, api)
    finally:
        if driver is not None:
            driver.quit()
        editor.stop()
        shutil.rmtree(work, ignore_errors=True)
    return {"design": path.name, "mesh_size": float(raw["mesh"]["size"]), "dofs": answer["dofs"],
            "cells": answer["cells"], "moves": moves, "drags": drags, "step_ms": step_ms,
            "contraction": contraction, "vertex": vertex, "api": api_times, "browser_seconds": browser_seconds,
            "gc": gc_clock.to_dict(),
            "console_errors": errors, "before": before, "after": host_load()}


def run(design="geometry/finger.toml", moves: int = 30, drags: int = 4, api: int = 20, step_ms: int = 16,
        out=None, screenshot: bool = True, sizes=SIZES, api_fine: int = 5) -> dict:
    """Drive the editor on design and on finer meshes of it; returns the bundled design's latencies in ms
    (contraction, vertex, api, ...) with ``sizes``, the same for each finer mesh (see the module doc)."""
    from skelfem.editor.engine import FRAME_SECONDS

    design = Path(design)
    if not design.is_absolute() and not design.exists():
        design = ROOT / design
    shot = Path(out) / "editor_latency.png" if screenshot and out is not None else None
    res = run_case(design, None, moves, drags, api, step_ms, shot)
    res["sizes"] = [run_case(design, float(h), moves, drags, api_fine, step_ms) for h in sizes]
    res.update(host_load(), frame_budget_ms=1000 * FRAME_SECONDS)
    if out is not None:
        Path(out).mkdir(parents=True, exist_ok=True)
        (Path(out) / "latency.json").write_text(json.dumps(res, indent=2) + "\n")
    return res


def _row(name: str, p: dict) -> str:
    if not p or not p.get("n"):
        return f"  {name:34s} (none)"
    return f"  {name:34s} p50 {p['p50']:6.0f} ms   p95 {p['p95']:6.0f} ms   (n = {p['n']})"


def _print(res: dict) -> None:
    print(f"{res['design']}: {res['dofs']} DOFs, {res['cells']} cells; drags of {res['moves']} moves, "
          f"one every {res['step_ms']} ms; load {res['before']['load_average'][0]:.1f} -> "
          f"{res['after']['load_average'][0]:.1f}")
    print("input event -> updated picture (the request's own event; every event incl. waiting):")
    print(_row("contraction slider", res["contraction"]["rendered"].get("contraction")))
    print(_row("  every event", res["contraction"]["every_event"].get("contraction")))
    print(_row("vertex drag (draft: moved nodes)", res["vertex"]["rendered"].get("vertex")))
    print(_row("  every event", res["vertex"]["every_event"].get("vertex")))
    print(_row("vertex release (full mesh)", res["vertex"]["rendered"].get("release")))
    print(_row("  release -> converged picture", res["vertex"]["settled"].get("release")))
    print("server time per answer, and from sending the request to having the answer in the page:")
    for how, v in {**res["contraction"]["server_ms"], **res["vertex"]["server_ms"]}.items():
        print(_row(how, v))
    for how, v in {**res["contraction"]["round_trip_ms"], **res["vertex"]["round_trip_ms"]}.items():
        print(_row(f"{how}, round trip", v))
    print(_row("drawing the answer (JavaScript)", res["vertex"]["render_ms"]))
    for kind in ("contraction", "vertex"):
        c = res[kind]["certificates"]
        print(f"  certificates of the {kind} drags: {c['preview']} preview, {c['converged']} converged "
              f"({c['converged_above_tolerance']} of them above the batch tolerance), the last {c['last']}")
    print(f"  console errors: {len(res['console_errors'])}; garbage collections during the drags "
          f"{res['gc']['collections']}, {res['gc']['total_ms']:.0f} ms in all, the longest "
          f"{res['gc']['longest_ms']:.1f} ms; between requests {res['gc']['idle']['collections']}, "
          f"{res['gc']['idle']['total_ms']:.0f} ms")
    print("POST /api/solve from a script:")
    print(_row("one bone vertex moved 0.5 mm", res["api"]["one_vertex_ms"]))
    print(_row("contraction changed 0.5 mm", res["api"]["contraction_ms"]))


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("design", nargs="?", default="geometry/finger.toml")
    p.add_argument("--moves", type=int, default=30, help="pointer moves per drag")
    p.add_argument("--drags", type=int, default=4, help="drags of each kind")
    p.add_argument("--api", type=int, default=20, help="POST /api/solve requests of each kind")
    p.add_argument("--api-fine", type=int, default=5, help="... on the finer meshes")
    p.add_argument("--sizes", type=float, nargs="*", default=list(SIZES),
                   help="finer mesh sizes (mm) also measured (none: the design's own only)")
    p.add_argument("--step-ms", type=int, default=16, help="time between pointer moves")
    p.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "editor_latency")
    args = p.parse_args(argv)
    if any(not h > 0 for h in args.sizes):
        p.exit(1, "error: --sizes: mesh sizes must be positive (mm)\n")
    res = run(args.design, args.moves, args.drags, args.api, args.step_ms, args.out, sizes=args.sizes,
              api_fine=args.api_fine)
    for case in [res] + res["sizes"]:
        _print(case)
        print()
    return res


if __name__ == "__main__":
    main()
