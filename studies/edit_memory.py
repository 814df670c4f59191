"""Memory over many re-meshing edits of one Session: does anything leak per edit?

    python studies/edit_memory.py [--edits 1000] [--every 100] [--out studies/output/edit_memory]

geometry/finger.toml at P1; each edit changes the mesh size by a micrometre
(so Gmsh re-meshes and a new model is built) and solves. After 20 warm-up
edits the resident set size (malloc_trim'd, /proc/self/statm) is read every
`every` edits. Prints the growth and writes edit_memory.json.
"""
from __future__ import annotations

import argparse
import ctypes
import gc
import os
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def rss_kb() -> float:
    ctypes.CDLL("libc.so.6").malloc_trim(0)
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1024


def run(edits: int = 1000, every: int = 100, warmup: int = 20) -> dict:
    from skelfem import Session
    from skelfem.design.parse import parse_design
    base = tomllib.loads((ROOT / "geometry" / "finger.toml").read_text())

    def finger(h):
        return parse_design(dict(base, mesh={"size": h, "degree": 1}), "finger.toml")
    t0 = time.perf_counter()
    rows = []
    with Session(finger(2.0)) as s:
        s.solve()
        for i in range(warmup):
            s.edit(finger(2.0 + 1e-3 * i))
            s.solve()
        gc.collect()
        r0 = rss_kb()
        for i in range(1, edits + 1):
            s.edit(finger(2.05 + 1e-6 * i))
            assert s.solve().converged
            if i % every == 0 or i == edits:
                gc.collect()
                rows.append({"edits": i, "rss_growth_kb": rss_kb() - r0, "time": time.perf_counter() - t0})
                print(f"{i:6d} edits: RSS {rows[-1]['rss_growth_kb'] / 1024:+.2f} MB ({rows[-1]['time']:.0f} s)",
                      flush=True)
    return {"edits": edits, "rows": rows, "growth_mb": rows[-1]["rss_growth_kb"] / 1024,
            "per_edit_kb": rows[-1]["rss_growth_kb"] / edits}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--edits", type=int, default=1000)
    ap.add_argument("--every", type=int, default=100)
    ap.add_argument("--out", type=Path, default=ROOT / "studies" / "output" / "edit_memory")
    args = ap.parse_args(argv)
    res = run(args.edits, args.every)
    from skelfem.io.files import write_json
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(args.out / "edit_memory.json", res)
    print(f"{res['edits']} edits: RSS grew {res['growth_mb']:.2f} MB ({res['per_edit_kb']:.2f} KB per edit)")
    return res


if __name__ == "__main__":
    main()
