"""How long the 3D editor's page takes to draw a picture: WebGL against the canvas path, in headless Chromium.

Opens geometry/finger3d.toml at mesh size `--size` (1.35 mm: about 49k DOFs) in `skelfem edit`'s page and
calls its draw3d() (skelfem/editor/static/editor3d.js) `--block` times per block, the view turned a little
before each picture, in blocks that alternate between the surfaces drawn with WebGL (Chromium's software
renderer here: no GPU) and with the canvas path (GL3.failed set), so that both see the same load. The
page's own clock (S.renderMs: the whole picture, the handles included, the GL picture copied onto the
view's canvas). Prints p50 and p95 of each with the host's load.

    python studies/editor_draw3d.py [--size 1.35] [--blocks 4] [--block 10]
"""
from __future__ import annotations

import argparse
import subprocess
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DESIGN = ROOT / "geometry" / "finger3d.toml"


def uptime() -> str:
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True, timeout=5).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""


def run(size: float, blocks: int, block: int) -> dict:
    from skelfem.editor.savefile import render
    from skelfem.editor.browser import Page, chrome
    from skelfem.editor.server import Editor
    from skelfem.editor.worker import Budget
    text = DESIGN.read_text()
    raw = tomllib.loads(text)
    raw["mesh"]["size"] = float(size)
    path = Path(tempfile.mkdtemp(prefix="skelfem-draw3d-")) / f"finger3d_h{size:g}.toml"
    path.write_text(render(text, raw, default_name="finger3d"))
    editor = Editor(path, port=0, max_dofs=80_000, budget=Budget(seconds=600.0)).start()
    driver = None
    out = {"size": size, "uptime_before": uptime(), "ms": {"webgl": [], "canvas": []}}
    try:
        driver = chrome()
        page = Page(driver, editor.url, timeout=900.0)
        out["dofs"], out["faces"] = page.js("S.answer.dofs"), page.js("S.answer.mesh.cells.length")
        for b in range(2 * blocks):
            mode = ("webgl", "canvas")[b % 2]
            ms = page.js(f"""(() => {{ GL3.failed = {str(mode == 'canvas').lower()}; S.renderMs = [];
                for (let i = 0; i < {block}; i++) {{ V3.yaw += 0.01; draw3d(); }}
                GL3.failed = false; return S.renderMs; }})()""")
            out["ms"][mode] += ms
        out["webgl_used"] = page.js("!!GL3.gl")
        out["console_errors"] = [e["message"] for e in page.console_errors()]
    finally:
        if driver is not None:
            driver.quit()
        editor.stop()
    out["uptime_after"] = uptime()
    for mode, v in out["ms"].items():
        out[mode] = {"n": len(v), "p50_ms": float(np.percentile(v, 50)), "p95_ms": float(np.percentile(v, 95))}
    return out


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--size", type=float, default=1.35, help="mesh size of finger3d.toml (mm)")
    p.add_argument("--blocks", type=int, default=4, help="blocks of each mode")
    p.add_argument("--block", type=int, default=10, help="pictures in a block")
    args = p.parse_args(argv)
    if not args.size > 0 or args.blocks < 1 or args.block < 1:
        p.exit(1, "error: --size must be positive, --blocks and --block at least 1\n")
    t0 = time.perf_counter()
    res = run(args.size, args.blocks, args.block)
    print(f"finger3d h={args.size:g} mm, {res['dofs']:,} DOFs, {res['faces']:,} surface triangles; "
          f"{res['uptime_before']}")
    for mode in ("webgl", "canvas"):
        r = res[mode]
        print(f"  {mode:6s}: {r['n']} pictures, p50 {r['p50_ms']:.1f} ms, p95 {r['p95_ms']:.1f} ms")
    print(f"  WebGL used: {res['webgl_used']}; console errors: {len(res['console_errors'])}; "
          f"{time.perf_counter() - t0:.0f} s; {res['uptime_after']}")
    return res


if __name__ == "__main__":
    main()
