"""Every printed part through a real slicer: PrusaSlicer's command line on the STL files of `skelfem fabricate`.

For each design: `skelfem fabricate` into a temporary folder, then for every
STL file `prusa-slicer --info` (manifold, parts, volume) and
`prusa-slicer --export-gcode --support-material` (automatic support on, as
printed: the file's orientation is kept). Per part it records the exit
code, warnings or errors the slicer logs, and the number of G-code sections
of support material (0: the part prints without support), beside skelfem's
own estimate from fabrication.json (``print.support_area``).

Then the single-process print: `skelfem fabricate --format 3mf` and the 3MF
sliced on a two-extruder printer (``--nozzle-diameter 0.4,0.4``), with
automatic support on the build plate only (support inside a channel could
not be removed) and, for comparison, everywhere. Per design (under
``prints``): the slicer's parts, manifold flag and volume, the filament each
extruder uses, the support sections, or the one-line error of a design that
cannot be printed so. Writes studies/output/slice_check/slice_check.json.

    python studies/slice_check.py [--designs finger gripper ...]

Needs Debian's `prusa-slicer` (the Makefile installs it).
"""
from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "studies" / "output" / "slice_check"
SKELFEM = str(Path(sys.executable).parent / "skelfem")
DESIGNS = ("finger", "finger_knuckles", "thumb", "finger_tapered", "gripper", "finger3d", "gripper3d", "arm3d")
SUPPORT = ";TYPE:Support material"


def _info(slicer: str, stl: Path) -> dict:
    out = subprocess.run([slicer, "--info", str(stl)], capture_output=True, text=True, timeout=300).stdout
    pairs = dict(line.split(" = ", 1) for line in out.splitlines() if " = " in line)
    return {"manifold": pairs.get("manifold", "").strip() == "yes",
            "parts": int(pairs.get("number_of_parts", "0").strip() or 0),
            "volume": float(pairs.get("volume", "nan"))}


def _slice(slicer: str, stl: Path, gcode: Path) -> dict:
    r = subprocess.run([slicer, "--loglevel", "2", "--export-gcode", "--support-material", "--output", str(gcode),
                        str(stl)], capture_output=True, text=True, timeout=600)
    log = (r.stdout + r.stderr).splitlines()
    warnings = [line for line in log if "[warning]" in line.lower() or "[error]" in line.lower()]
    text = gcode.read_text() if gcode.exists() else ""
    return {"returncode": r.returncode, "warnings": warnings, "support_sections": text.count(SUPPORT),
            "layers": text.count(";LAYER_CHANGE")}


def _filament(gcode: Path) -> list[float]:
    """cm^3 of filament per extruder, from the G-code's summary."""
    line = next((x for x in gcode.read_text().splitlines() if x.startswith("; filament used [cm3] =")), "")
    return [float(v) for v in line.split("=", 1)[1].split(",")] if line else []


def _print(slicer: str, name: str, folder: Path) -> dict:
    """skelfem fabricate --format 3mf, then the 3MF sliced on two extruders."""
    r = subprocess.run([SKELFEM, "fabricate", str(ROOT / "geometry" / f"{name}.toml"), "--format", "3mf",
                        "--out", str(folder), "-q", "--no-picture"], capture_output=True, text=True, timeout=900)
    if r.returncode != 0:
        return {"design": name, "error": r.stderr.strip().splitlines()[-1] if r.stderr.strip() else r.returncode}
    report = json.loads((folder / "fabrication.json").read_text())
    three = folder / report["file"]
    row = {"design": name, "down": report["print"]["down"], "volume_3mf": sum(
        p["mesh_volume"] for p in report["parts"].values()), **_info(slicer, three)}
    two = ["--nozzle-diameter", "0.4,0.4", "--filament-diameter", "1.75,1.75"]
    for key, extra in (("plate", ["--support-material-buildplate-only"]), ("everywhere", [])):
        g = folder / f"print_{key}.gcode"
        res = subprocess.run([slicer, "--loglevel", "2", "--export-gcode", "--support-material", *two, *extra,
                              "--output", str(g), str(three)], capture_output=True, text=True, timeout=600)
        log = (res.stdout + res.stderr).splitlines()
        text = g.read_text() if g.exists() else ""
        row[key] = {"returncode": res.returncode, "support_sections": text.count(SUPPORT),
                    "warnings": [x for x in log if "[warning]" in x.lower() or "[error]" in x.lower()],
                    "layers": text.count(";LAYER_CHANGE"), "filament_cm3": _filament(g) if g.exists() else []}
    return row


def run(designs=DESIGNS, out: Path | None = OUT, prints: bool = True) -> dict:
    slicer = shutil.which("prusa-slicer")
    if slicer is None:
        raise SystemExit("error: prusa-slicer is not installed (make setup installs Debian's)")
    rows, printed = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for name in designs:
            folder = Path(tmp) / name
            r = subprocess.run([SKELFEM, "fabricate", str(ROOT / "geometry" / f"{name}.toml"), "--out", str(folder),
                                "-q", "--no-picture"], capture_output=True, text=True, timeout=900)
            if r.returncode != 0:
                raise SystemExit(f"error: skelfem fabricate {name} failed: {r.stderr.strip()}")
            report = json.loads((folder / "fabrication.json").read_text())
            for part, entry in report["parts"].items():
                stl = folder / entry["stl"]
                row = {"design": name, "part": part, "down": entry["print"]["down"],
                       "estimated_support_area": entry["print"]["support_area"],
                       "stl_volume": entry["stl_volume"], **_info(slicer, stl),
                       **_slice(slicer, stl, folder / f"{part}.gcode")}
                rows.append(row)
                print(f"{name:16s} {part:20s} down {row['down']}: support sections {row['support_sections']:3d} "
                      f"of {row['layers']} layers (estimate {row['estimated_support_area']:.1f} mm^2), "
                      f"manifold {row['manifold']}, warnings {len(row['warnings'])}", flush=True)
        for name in designs if prints else ():
            row = _print(slicer, name, Path(tmp) / f"{name}_3mf")
            printed.append(row)
            if "error" in row:
                print(f"{name:16s} 3MF: not printable: {row['error']}", flush=True)
                continue
            a, b = row["plate"], row["everywhere"]
            print(f"{name:16s} 3MF: {row['parts']} parts, manifold {row['manifold']}, filament "
                  f"{', '.join(f'{v:.2f}' for v in a['filament_cm3'])} cm^3 per extruder; support sections "
                  f"{a['support_sections']} (build plate only), {b['support_sections']} (everywhere) of "
                  f"{a['layers']} layers, warnings {len(a['warnings'])}", flush=True)
    help_text = subprocess.run([slicer, "--help"], capture_output=True, text=True).stdout.splitlines()
    version = [line.split(" ")[0] for line in help_text if line.startswith("PrusaSlicer")]
    res = {"slicer": version[0] if version else "prusa-slicer", "designs": list(designs), "rows": rows,
           "all_sliced": all(r["returncode"] == 0 and not r["warnings"] for r in rows),
           "moulds_without_support": all(r["support_sections"] == 0 for r in rows if r["part"].startswith("mould")),
           "prints": printed,
           "prints_sliced": all(p["plate"]["returncode"] == 0 and not p["plate"]["warnings"]
                                for p in printed if "plate" in p)}
    if out is not None:
        from skelfem.io.files import write_json
        out.mkdir(parents=True, exist_ok=True)
        write_json(out / "slice_check.json", res)
    return res


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--designs", nargs="+", default=list(DESIGNS))
    a = p.parse_args(argv)
    run(a.designs)


if __name__ == "__main__":
    main()
