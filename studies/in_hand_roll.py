"""In-hand rotation planned through contact: two skeleton fingers roll a disk (geometry/two_finger_roll.toml).

The load path of one Session: the fingers' bases press 1 mm towards the disk
with gravity off (the grip), then gravity is switched on (the disk, held by
friction alone, settles), then Soft IK (``track``) moves a marker on the
disk's rim along an arc about the disk's centre, ``step`` degrees at a time,
using the two flexors (the top of the left finger, the bottom of the right):
the tips move in opposite directions and the disk rolls between them. Per
target it records the disk's rotation, the marker's error, the contractions,
each contact's sticking share and the smallest distance between pieces.
Writes studies/output/in_hand_roll/in_hand_roll.json, and into figures
in_hand_roll.png (the start, the middle and the last pose, contact forces as
arrows) and in_hand_roll.gif (every pose).

    python studies/in_hand_roll.py [--to 50] [--step 5] [--size 2] [--max-solves 20]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
OUT = ROOT / "studies" / "output" / "in_hand_roll"
FIGURES = ROOT / "studies" / "figures"
DESIGN = ROOT / "geometry" / "two_finger_roll.toml"
MARKER = "disk_mark"


def _state(s) -> dict:
    disk = s.model.term("objects", "disk").readout(s.model)["disk"]
    pieces = s.model.term("contacts", "pieces")
    contacts = s.model.readouts().get("contacts", {})
    return {"rotation_deg": float(np.degrees(disk["rotation"])), "centre": [float(v) for v in disk["position"]],
            "sticking": {k: float(c.get("sticking", 1.0)) for k, c in contacts.items()},
            "min_distance": float(pieces.min_distance(s.model.u.x.array))}


def run(to: float = 50.0, step: float = 5.0, size: float | None = None, max_solves: int = 20,
        out: Path | None = OUT, figures: Path | None = FIGURES) -> dict:
    from skelfem import Session
    from skelfem.analysis.control import SoftIK, track
    from skelfem.design import load_design
    from skelfem.io.files import write_json
    from skelfem.io.xdmf import snapshot

    t0 = time.perf_counter()
    design = load_design(DESIGN, [f"mesh.size={size}"] if size is not None else [])
    s = Session(design)
    r = s.solve()                                    # the grip, gravity off (as the design says)
    if not r.converged:
        raise SystemExit(f"error: the grip failed ({r.status})")
    s.set({"gravity.acceleration": [0.0, -9.81]})
    r = s.solve()
    if not r.converged:
        raise SystemExit(f"error: the disk is not held under gravity ({r.status})")
    start = _state(s)
    c0 = np.array(r.objects["disk"]["position"])
    p0 = np.array(r.markers[MARKER]["position"])
    radius, a0 = float(np.linalg.norm(p0 - c0)), float(np.arctan2(p0[1] - c0[1], p0[0] - c0[0]))
    angles = np.arange(step, to + 1e-9, step)
    targets = c0 + radius * np.column_stack([np.cos(a0 - np.radians(angles)), np.sin(a0 - np.radians(angles))])
    ik = SoftIK(s, MARKER, max_solves=max_solves)
    frames = [(0.0, snapshot(s.model))]
    rows = []

    def on_target(i, res):
        row = {"target_deg": float(angles[i]), "error": float(res.error), "status": res.status,
               "contractions": [float(u) for u in res.contractions], "forward_solves": int(res.forward_solves),
               **_state(s)}
        rows.append(row)
        frames.append((float(angles[i]), snapshot(s.model)))
        print(f"target {angles[i]:4.0f} deg: disk turned {row['rotation_deg']:6.1f} deg, marker {res.error:.3f} mm "
              f"off ({res.status}), u = {np.round(res.contractions, 2)} mm, sticking "
              f"{[round(v, 2) for v in row['sticking'].values()]}", flush=True)
    track(ik, targets, on_target)
    res = {"design": DESIGN.name, "dofs": int(s.dofs), "tendons": ik.names, "start": start, "rows": rows,
           "largest_rotation_deg": float(max(abs(r["rotation_deg"]) for r in rows)),
           "reached": int(sum(r["status"] == "reached" for r in rows)),
           "approximate_jacobians": int(ik.approximate_jacobians),
           "min_distance": float(min(r["min_distance"] for r in rows)), "seconds": time.perf_counter() - t0}
    s.close()
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        write_json(out / "in_hand_roll.json", res)
    if figures is not None:
        figures.mkdir(parents=True, exist_ok=True)
        _poses(figures / "in_hand_roll.png", frames, rows)
        _gif(figures / "in_hand_roll.gif", frames, rows)
    return res


def _title(angle: float, rows: list) -> str:
    if angle == 0:
        return "gripped, gravity on"
    row = next(r for r in rows if r["target_deg"] == angle)
    return f"target {angle:.0f}°: disk turned {abs(row['rotation_deg']):.0f}°"


def _draw(ax, angle: float, snap, rows: list) -> None:
    """One pose around the disk: the fingertips, the disk and the contact forces."""
    from skelfem.viz.plots import plot_deformed
    plot_deformed(None, snap, _title(angle, rows), ax=ax)
    if ax.get_legend() is not None:
        ax.get_legend().remove()
    ax.set_xlim(45, 95)
    ax.set_ylim(-20, 14)


def _poses(path: Path, frames: list, rows: list) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from skelfem.io.files import atomic_write
    picks = [frames[0], frames[len(frames) // 2], frames[-1]]
    fig = Figure(figsize=(13, 4.4), dpi=110)
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 3)
    for ax, (angle, snap) in zip(axes, picks):
        _draw(ax, angle, snap, rows)
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))


def _gif(path: Path, frames: list, rows: list) -> None:
    import io

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from PIL import Image
    from skelfem.io.files import atomic_write
    images = []
    for angle, snap in frames:
        fig = Figure(figsize=(5, 4), dpi=80)
        FigureCanvasAgg(fig)
        _draw(fig.subplots(), angle, snap, rows)
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format="png")
        images.append(Image.open(io.BytesIO(buf.getvalue())).convert("RGB"))
    palette = images[-1].quantize(colors=255)
    frames_p = [im.quantize(palette=palette) for im in images]

    def save(tmp):
        frames_p[0].save(tmp, format="GIF", save_all=True, append_images=frames_p[1:], duration=500, loop=0)
    atomic_write(path, save)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--to", type=float, default=50.0, help="the last target's angle, degrees")
    p.add_argument("--step", type=float, default=5.0, help="degrees between targets")
    p.add_argument("--size", type=float, default=None, help="mesh size, mm (default: the design's)")
    p.add_argument("--max-solves", type=int, default=20)
    a = p.parse_args(argv)
    run(a.to, a.step, a.size, a.max_solves)


if __name__ == "__main__":
    main()
