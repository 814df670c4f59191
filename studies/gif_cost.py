"""What motion.gif costs in a run in time: its share of the whole command's wall time.

Runs ``skelfem simulate`` on a design with [dynamics] (the bundled flick by
default) ``repeats`` times, each with the GIF and without it (A B A B, so both
see the same machine), and reads each output's own time from result.json
(``timings.write_gif``, ``write_xdmf``, ``write_csv``). Prints and returns the
medians; writes studies/output/gif_cost/gif_cost.json.

    python studies/gif_cost.py [--design geometry/flick.toml] [--repeats 3]
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "studies" / "output" / "gif_cost"
SKELFEM = str(Path(sys.executable).parent / "skelfem")


def _once(design: Path, folder: Path, picture: bool, overrides=()) -> dict:
    args = [SKELFEM, "simulate", str(design), "--out", str(folder), "-q", "--force"]
    args += [a for o in overrides for a in ("--set", o)]
    if not picture:
        args.append("--no-picture")
    t0 = time.perf_counter()
    subprocess.run(args, check=True, capture_output=True)
    wall = time.perf_counter() - t0
    timings = json.loads((folder / "result.json").read_text())["timings"]
    return {"wall": wall, **timings}


def run(design: str | Path = ROOT / "geometry" / "flick.toml", repeats: int = 3, overrides=(),
        out: Path | None = OUT) -> dict:
    design = Path(design)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(repeats):
            for picture in (True, False):
                r = _once(design, Path(tmp) / f"r{k}{int(picture)}", picture, overrides)
                rows.append({"picture": picture, **r})
    with_gif = [r for r in rows if r["picture"]]
    without = [r for r in rows if not r["picture"]]
    med = statistics.median
    res = {
        "design": design.name, "repeats": repeats,
        "wall_with_gif": med(r["wall"] for r in with_gif),
        "wall_without_gif": med(r["wall"] for r in without),
        "solve": med(r["solve"] for r in with_gif),
        "write_gif": med(r["write_gif"] for r in with_gif),
        "write_xdmf": med(r["write_xdmf"] for r in with_gif),
        "write_csv": med(r["write_csv"] for r in with_gif),
    }
    res["gif_share_of_wall"] = res["write_gif"] / res["wall_with_gif"]
    res["rows"] = rows
    if out is not None:
        Path(out).mkdir(parents=True, exist_ok=True)
        (Path(out) / "gif_cost.json").write_text(json.dumps(res, indent=2))
    return res


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--design", default=str(ROOT / "geometry" / "flick.toml"))
    p.add_argument("--repeats", type=int, default=3)
    a = p.parse_args(argv)
    r = run(a.design, a.repeats)
    print(f"{r['design']}: wall {r['wall_with_gif']:.2f} s with motion.gif, {r['wall_without_gif']:.2f} s without; "
          f"solve {r['solve']:.2f} s, motion.gif {r['write_gif']:.2f} s ({100 * r['gif_share_of_wall']:.0f} % of the "
          f"wall time), trajectory.xdmf {r['write_xdmf']:.2f} s, trajectory.csv {r['write_csv']:.3f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
