"""ParaView opens every kind of file skelfem writes, and renders it (the pictures in the output guide).

    python studies/paraview_renders.py [--out studies/output/paraview] [--figures studies/figures]

Needs Debian's ParaView (``apt install paraview python3-paraview xvfb``;
not a dependency of skelfem, so the tests do not run this). Makes, in a
temporary folder: solution.xdmf of finger.toml (2D) and pillar3d.toml (3D),
trajectory.xdmf of flick.toml (a run in time) and the STL parts of
``skelfem fabricate`` on finger.toml; then renders each with ``pvbatch``
under ``xvfb-run`` through the scripts in docs/paraview/. Writes
paraview.json (per file kind: the file, what pvbatch printed, the picture)
and the pictures.
"""
from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from skelfem.io.files import copy_figure, say

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "studies" / "output" / "paraview"
SCRIPTS = ROOT / "docs" / "paraview"
NEEDS = ("pvbatch", "xvfb-run")

# (kind, skelfem command on a bundled design, file or folder to open, script, picture)
RENDERS = [
    ("solution.xdmf, 2D", ["simulate", "geometry/finger.toml"], "solution.xdmf", "skelfem_view.py",
     "paraview_finger.png"),
    ("solution.xdmf, 3D", ["simulate", "geometry/pillar3d.toml"], "solution.xdmf", "skelfem_view.py",
     "paraview_pillar3d.png"),
    ("trajectory.xdmf", ["simulate", "geometry/flick.toml"], "trajectory.xdmf", "skelfem_series.py",
     "paraview_flick.png"),
    ("STL parts", ["fabricate", "geometry/finger.toml"], ".", "skelfem_parts.py", "paraview_parts.png"),
]


def missing() -> list[str]:
    return [tool for tool in NEEDS if shutil.which(tool) is None]


def render(work: Path, kind: str, command: list, target: str, script: str, picture: str, out: Path) -> dict:
    folder = work / picture.removesuffix(".png")
    subprocess.run([sys.executable, "-m", "skelfem", command[0], str(ROOT / command[1]), "--out", str(folder), "-q"],
                   check=True, cwd=work)
    png = out / picture
    p = subprocess.run(["xvfb-run", "-a", "-s", "-screen 0 1600x1200x24", "pvbatch", str(SCRIPTS / script),
                        str(folder / target), str(png)], capture_output=True, text=True, timeout=600, cwd=work)
    printed = [line for line in p.stdout.splitlines() if line.strip()]
    ok = p.returncode == 0 and png.exists() and png.stat().st_size > 5000
    if not ok:
        say(p.stderr[-2000:])
    return {"kind": kind, "design": command[1], "file": target, "script": f"docs/paraview/{script}",
            "rendered": ok, "pvbatch": printed, "picture": picture, "bytes": png.stat().st_size if png.exists() else 0}


def run(out: Path = OUT, figures: Path | None = None) -> dict:
    from skelfem.io.files import write_json
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    version = subprocess.run(["pvbatch", "--version"], capture_output=True, text=True).stdout.strip()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for kind, command, target, script, picture in RENDERS:
            row = render(Path(tmp), kind, command, target, script, picture, out)
            rows.append(row)
            say(f"{kind:18s} {'rendered' if row['rendered'] else 'FAILED':9s} {picture}  {' '.join(row['pvbatch'])}")
            if row["rendered"]:
                copy_figure(out / picture, figures)
    result = {"paraview": version, "renders": rows}
    write_json(out / "paraview.json", result)
    return result


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=OUT)
    p.add_argument("--figures", type=Path, default=ROOT / "studies" / "figures")
    a = p.parse_args(argv)
    if missing():
        print(f"error: this study needs ParaView: {', '.join(missing())} not found "
              "(apt install paraview python3-paraview xvfb)", file=sys.stderr)
        return 1
    res = run(a.out, a.figures)
    return 0 if all(r["rendered"] for r in res["renders"]) else 2


if __name__ == "__main__":
    raise SystemExit(main())
