"""What a 3D drag's frame costs the editor's server: the engine alone (no page), one process.

finger3d.toml at mesh size `--size` (2.6 mm: about 10k DOFs); the distal bone dragged (``move``) and turned
(``rotate`` about z) in small steps, each step a draft as the page sends it (skelfem.editor.engine.Engine.solve
with draft=True). Blocks of `--block` drafts alternate between

* ``exact``: every draft's posed bones checked by OpenCASCADE (skelfem.design.solids.check) as before, and
* ``mesh``: a draft that changes the bones' poses only checked by the moved mesh (its tetrahedra keep their
  orientation) and the exact check left to the release (the editor's way now),

so that both see the same load; with ``--compare step``, between

* ``step``: a modified Newton step on every new pose (as before), and
* ``moved``: no step for a new pose when the last took longer than skelfem.editor.frames3d.STEP_SECONDS
  (the moved state; the editor's way now).

Prints the p50 and p95 of each mode's frames (the engine's own ``seconds``) with the load average, and how
many OpenCASCADE checks and modified Newton steps each mode ran.

    python studies/editor_frames3d.py [--size 2.6] [--compare check|step] [--blocks 6] [--block 8] [--json FILE]
"""
from __future__ import annotations

import argparse
import copy
import json
import os
import re
import subprocess
import time
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DESIGN = ROOT / "geometry" / "finger3d.toml"
NEVER = re.compile(r"(?!)")          # a pattern no key matches: every draft parsed and checked exactly


def posed(raw: dict, k: int, n: int) -> dict:
    """The k-th of n drafts of the drag: the distal bone moved along y and turned about z, every pose a new one
    (the OpenCASCADE check is cached by geometry: a pose seen before would cost nothing)."""
    d = copy.deepcopy(raw)
    s = k / n
    d["bones"][2]["move"] = [0.0, round(0.6 * s, 6), 0.0]
    d["bones"][2]["rotate"] = {"angle": round(3.0 * s, 6), "axis": [0.0, 0.0, 1.0], "centre": [10.0, 82.0, 10.0]}
    return d


def uptime() -> str:
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True, timeout=5).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""


MODES = {"check": ("exact", "mesh"), "step": ("step", "moved")}


def run(size: float, blocks: int, block: int, compare: str = "check") -> dict:
    from skelfem.design import solids
    from skelfem.editor import engine as engine_mod
    from skelfem.editor import frames3d
    modes = MODES[compare]
    step_seconds = frames3d.STEP_SECONDS
    raw = tomllib.loads(DESIGN.read_text())
    raw["mesh"]["size"] = float(size)
    checks = {"n": 0}
    exact_check = solids.check

    def counted(*a, **k):
        checks["n"] += 1
        return exact_check(*a, **k)
    solids.check = counted
    pose_key = engine_mod.POSE_KEY
    eng = engine_mod.Engine(copy.deepcopy(raw), "finger3d.toml", max_dofs=80_000)
    out = {"size": size, "dofs": int(eng.session.dofs), "compare": compare, "uptime_before": uptime(),
           "frames": {m: [] for m in modes}, "checks": {m: 0 for m in modes}, "steps": {m: 0 for m in modes},
           "hows": {}}
    k = 0
    try:
        for b in range(2 * blocks):
            mode = modes[b % 2]
            engine_mod.POSE_KEY = NEVER if mode == "exact" else pose_key
            frames3d.STEP_SECONDS = float("inf") if mode == "step" else step_seconds
            n0 = checks["n"]
            for _ in range(block):
                k += 1
                a = eng.solve(posed(raw, k, 2 * blocks * block), draft=True)
                out["frames"][mode].append(a["editor"]["seconds"])
                out["steps"][mode] += int(a.get("newton_iterations") or 0)
                how = a["editor"]["how"]
                out["hows"][how] = out["hows"].get(how, 0) + 1
            out["checks"][mode] += checks["n"] - n0
    finally:
        engine_mod.POSE_KEY = pose_key
        frames3d.STEP_SECONDS = step_seconds
        solids.check = exact_check
        eng.close()
    out["uptime_after"] = uptime()
    out["load_average"] = list(os.getloadavg())
    for mode, v in out["frames"].items():
        out[mode] = {"n": len(v), "p50_ms": 1e3 * float(np.percentile(v, 50)),
                     "p95_ms": 1e3 * float(np.percentile(v, 95))}
    return out


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--size", type=float, default=2.6, help="mesh size of finger3d.toml (mm)")
    p.add_argument("--compare", choices=sorted(MODES), default="check", help="what the modes differ in")
    p.add_argument("--blocks", type=int, default=6, help="blocks of each mode")
    p.add_argument("--block", type=int, default=8, help="drafts in a block")
    p.add_argument("--json", type=Path, help="write the numbers here too")
    args = p.parse_args(argv)
    if not args.size > 0 or args.blocks < 1 or args.block < 1:
        p.exit(1, "error: --size must be positive, --blocks and --block at least 1\n")
    t0 = time.perf_counter()
    res = run(args.size, args.blocks, args.block, args.compare)
    print(f"finger3d h={args.size:g} mm, {res['dofs']:,} DOFs; {res['uptime_before']}")
    for mode in MODES[args.compare]:
        r = res[mode]
        print(f"  {mode:5s}: {r['n']} drafts, frame p50 {r['p50_ms']:.0f} ms, p95 {r['p95_ms']:.0f} ms, "
              f"OpenCASCADE checks {res['checks'][mode]}, steps {res['steps'][mode]}")
    print(f"  how: {res['hows']}; {time.perf_counter() - t0:.0f} s; {res['uptime_after']}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(res, indent=1))
    return res


if __name__ == "__main__":
    main()
