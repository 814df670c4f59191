"""The fabrication guide's volumes, from the runs themselves: `skelfem fabricate` on the bundled designs.

For each design: `skelfem fabricate` into a temporary folder, timed (the
command's wall time, start-up included), and from its fabrication.json

- per bone: the STL's volume against the kernel's exact one (OpenCASCADE's
  volume of the cut bone), and the volume its channels, anchor holes and
  sockets removed (the kernel's);
- the mould: its cavity (block minus both halves) against the body's volume,
  and the closed cavity (the pour hole, vents, exits, clamp holes, pins and
  pegs accounted for) against it;
- per part: how it lies on the bed (face down, bed area, support estimate).

Writes studies/output/fabrication_volumes/fabrication_volumes.json, which
the fabrication guide's tables are built from.

    python studies/fabrication_volumes.py [--designs finger arm3d ...]
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "studies" / "output" / "fabrication_volumes"
SKELFEM = str(Path(sys.executable).parent / "skelfem")
DESIGNS = ("finger", "finger4", "finger_bones", "finger_knuckles", "finger_soft", "finger3d", "arm3d")


def measure(name: str, folder: Path) -> dict:
    """One design's row: skelfem fabricate, then its own report's numbers."""
    t0 = time.perf_counter()
    r = subprocess.run([SKELFEM, "fabricate", str(ROOT / "geometry" / f"{name}.toml"), "--out", str(folder),
                        "-q", "--no-picture"], capture_output=True, text=True, timeout=1800)
    seconds = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"error: skelfem fabricate {name} failed (exit {r.returncode}): {r.stderr.strip()}")
    report = json.loads((folder / "fabrication.json").read_text())
    mould = report["mould"]
    bones = {b: {"stl_volume": e["stl_volume"], "volume": e["volume"], "relative_error": e["relative_error"],
                 "removed_volume": e["removed_volume"], "sheath_volume": e["sheath_volume"]}
             for b, e in report["bones"].items()}
    parts = {p: {k: e["print"][k] for k in ("down", "bed_area", "support_area")} for p, e in report["parts"].items()}
    return {"design": name, "seconds": seconds, "bones": bones, "parts": parts,
            "body_volume": mould["body_volume"], "cavity_volume": mould["cavity_volume"],
            "cavity_relative_error": mould["relative_error"],
            "closed_relative_error": mould["closed_relative_error"], "passed": report["checks"]["passed"]}


def run(designs=DESIGNS, out: Path | None = OUT) -> dict:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in designs:
            row = measure(name, Path(tmp) / name)
            rows.append(row)
            print(f"{name:16s} cavity {100 * row['cavity_relative_error']:+.2f} % "
                  f"(closed {100 * row['closed_relative_error']:+.3f} %), bones' STL against the kernel "
                  + (", ".join(f"{100 * b['relative_error']:+.3f} %" for b in row["bones"].values()) or "(none)")
                  + f", least bed area {min(p['bed_area'] for p in row['parts'].values()):.1f} mm^2, "
                  f"{row['seconds']:.1f} s", flush=True)
    res = {"command": "skelfem fabricate DESIGN --no-picture", "designs": list(designs), "rows": rows,
           "all_passed": all(r["passed"] for r in rows)}
    if out is not None:
        from skelfem.io.files import write_json
        out.mkdir(parents=True, exist_ok=True)
        write_json(out / "fabrication_volumes.json", res)
    return res


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--designs", nargs="+", default=list(DESIGNS))
    a = p.parse_args(argv)
    run(a.designs)


if __name__ == "__main__":
    main()
