"""Grasp, lift, carry, turn, put down: the three-finger hand's scenario in 2D, and the 3D gripper lifting its sphere.

    python studies/hand_scenario.py [--size 2] [--density 310] [--contraction 4] [--turn-steps 12]
                                    [--size3d 2.5] [--no-3d] [--no-weightless]
                                    [--out studies/output/hand_scenario] [--figures studies/figures]

2D: geometry/hand.toml (a palm with three skeleton fingers, the object a
46 mm square between them) written as a design with ``[[stages]]``:
close (the outer flexors contracted, gravity off), weigh (gravity on), lift
(the palm pin moved up 20 mm), carry (30 mm sideways), turn (30 degrees
about the palm's centre), put down (the palm lowered until the object rests
on a ground, a ramp parallel to the object's turned bottom face placed
``gap`` below where a rigid grip would carry it, lowered ``gap + push``
along its normal), release (the flexors let go), retreat (the palm backed
away 4 mm along the ramp's normal: lifted straight up, a step's first solve
takes the object off the ramp with the fingers, see the guide). The palm's
turn needs the pin's ``rotate`` (the design gives an angle of 0); three
markers on the pinned edge give the base's pose after every load step. The
object's density is 310 kg/m^3 (a quarter-infill print): in solid PLA it is
heavier than the outer fingers' friction can carry. The held stages run
again with the hand's own materials weightless (``hand_weightless``): how
much of the object's lag in the turn is the fingers bending under their
own weight.

3D: geometry/gripper3d.toml with stages close (both flexors, 3 equal
steps), weigh, lift (the palm up 10 mm).

Each scenario runs through ``Session.run_stages``, what ``skelfem simulate``
runs on a design with stages; a step watcher (``Model.step_watchers``, as
the jump watch) records after every accepted load step the base's pose
(the palm's centre and angle), the object's position and rotation, the
contacts' normal and friction totals on the object and the ground's force.
While the object is held (lift, carry, turn) its position is compared with
where the base's rigid motion would carry it from where it hung after
weighing: ``follow`` = that distance / the object's size (the diagonal of
its bounding box, as the jump watch's).

Writes into out hand_scenario.json (stages, per-step rows, the worst
``follow``), hand_scenario.csv (the rows), hand.toml, hand_weightless.toml and
gripper3d.toml (the designs with their stages: ``skelfem simulate`` runs
them); into figures
hand_scenario.png (the hand at the end of every stage, the trajectories, the
share off the base's motion per load step),
hand_scenario.gif (every load step) and hand_scenario_3d.png (the sphere
lifted). run(**params) returns the numbers.
"""
from __future__ import annotations

import argparse
import csv
import io
import math
import time
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
HAND = ROOT / "geometry" / "hand.toml"
GRIPPER3D = ROOT / "geometry" / "gripper3d.toml"
OUT = ROOT / "studies" / "output" / "hand_scenario"
FIGURES = ROOT / "studies" / "figures"
OUTER = ("left", "right")
BASE_MARKERS = ("palm_left", "palm_centre", "palm_right")
TIPS = ("left_tip", "right_tip")          # the fingertips' markers: the grip's frame
HELD = ("lift", "carry", "turn")          # the stages in which the base carries the object
FOLLOW_SHARE = 0.02                       # the floor: the object within 2 % of its size of the base's rigid motion
WEIGHTLESS = 1e-3                         # kg/m^3: the hand's own materials in the check without their weight


# -- designs ----------------------------------------------------------------------------------------------
def _rigid(point, move, angle_deg: float, centre) -> np.ndarray:
    """Where the base's rigid motion (move, then the turn about the moved centre) takes a point."""
    c = np.asarray(centre, float)
    th = math.radians(angle_deg)
    R = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
    return c + np.asarray(move, float) + R @ (np.asarray(point, float) - c)


def hand_design(size: float | None = None, density: float = 310.0, contraction: float = 4.0, lift: float = 20.0,
                carry: float = 30.0, turn: float = 30.0, turn_steps: int = 12, gap: float = 2.0, push: float = 0.5,
                down_steps: int = 4, release_steps: int = 4, retreat: float = 4.0) -> dict:
    """geometry/hand.toml with the scenario's stages, a ramp under where the object is put down, and
    markers on the palm's pinned edge."""
    d = tomllib.loads(HAND.read_text())
    d["name"] = "hand_scenario"
    if size is not None:
        d["mesh"]["size"] = float(size)
    d["materials"]["box_pla"]["density"] = float(density)
    centre = [50.0, 115.0]
    palm = next(p for p in d["pins"] if p["name"] == "palm")
    palm["rotate"] = {"angle": 0.0, "centre": centre}
    d["markers"].update(palm_left=[10.0, 115.0], palm_centre=centre, palm_right=[90.0, 115.0])
    box = np.asarray(d["objects"][0]["outline"], float)
    bottom = box[np.argmin(box[:, 1])]                       # a corner of the bottom face
    move = [carry, lift]
    th = math.radians(turn)
    normal = np.array([-math.sin(th), math.cos(th)])         # the turned bottom face's outward normal, negated
    on_face = _rigid(bottom, move, turn, centre)
    point = on_face - gap * normal
    d["grounds"] = [{"name": "ramp", "point": [round(float(v), 4) for v in point],
                     "normal": [round(float(v), 6) for v in normal], "stiffness": 100.0}]
    down = (gap + push) / normal[1]                          # lowered vertically: gap + push along the normal
    flexors = {f"cables.{f}_flexor.contraction": float(contraction) for f in OUTER}
    d["stages"] = [
        {"name": "close", "set": flexors},
        {"name": "weigh", "set": {"gravity.acceleration": [0.0, -9.81]}},
        {"name": "lift", "set": {"pins.palm.move": [0.0, lift]}, "steps": 2},
        {"name": "carry", "set": {"pins.palm.move": [carry, lift]}, "steps": 4},
        {"name": "turn", "set": {"pins.palm.rotate.angle": turn}, "steps": turn_steps},
        {"name": "put_down", "set": {"pins.palm.move": [carry, round(lift - down, 4)]}, "steps": down_steps},
        {"name": "release", "set": {k: 0.0 for k in flexors}, "steps": release_steps},
        {"name": "retreat", "set": {"pins.palm.move": [round(carry + retreat * float(normal[0]), 4),
                                                        round(lift - down + retreat * float(normal[1]), 4)]},
         "steps": max(1, int(round(retreat)))},
    ]
    return d


def gripper3d_design(size: float | None = None, contraction: float = 3.0, lift: float = 10.0) -> dict:
    """geometry/gripper3d.toml with stages close (3 steps), weigh and lift, and markers on the palm's pinned face."""
    d = tomllib.loads(GRIPPER3D.read_text())
    d["name"] = "gripper3d_lift"
    if size is not None:
        d["mesh"]["size"] = float(size)
    d["markers"].update(palm_left=[4.0, 68.0, 6.0], palm_centre=[28.0, 68.0, 6.0], palm_right=[52.0, 68.0, 6.0])
    flexors = {f"cables.{f}_flexor.contraction": float(contraction) for f in OUTER}
    d["stages"] = [
        {"name": "close", "set": flexors, "steps": 3},
        {"name": "weigh", "set": {"gravity.acceleration": [0.0, -9.81, 0.0]}},
        {"name": "lift", "set": {"pins.palm.move": [0.0, lift, 0.0]}, "steps": 2},
    ]
    return d


# -- records ----------------------------------------------------------------------------------------------
def _base(markers: dict) -> tuple[list, float]:
    """The base's pose from the pinned markers: the palm centre's position and the palm's angle (deg,
    in the x-y plane)."""
    left, centre, right = (np.asarray(markers[n]["position"], float) for n in BASE_MARKERS)
    a = right - left
    return [float(v) for v in centre], float(math.degrees(math.atan2(a[1], a[0])))


def _angle_deg(rotation) -> float:
    """An object's rotation read-out in degrees (3D: the z component of its rotation vector)."""
    return float(math.degrees(rotation if np.ndim(rotation) == 0 else rotation[2]))


def _row(readouts: dict, obj: str) -> dict:
    """One load step's record from the model's read-outs."""
    centre, angle = _base(readouts["markers"])
    o = readouts["objects"][obj]
    pairs = list((readouts.get("contacts") or {}).values())
    held = next((c for c in pairs if c["between"] == ["body", obj]), {})
    ground = next((c for c in pairs if c["between"][1] == obj and c["between"][0] != "body"), {})
    zero = [0.0] * len(centre)
    tips = [[float(v) for v in readouts["markers"][n]["position"]] for n in TIPS]
    return {"base": centre, "base_angle": angle, "object": [float(v) for v in o["position"]],
            "object_angle": _angle_deg(o["rotation"]), "tips": tips,
            "normal": float(held.get("normal_magnitude", 0.0)),
            "normal_force": [float(v) for v in held.get("normal_force", zero)],
            "friction": [float(v) for v in held.get("friction_force", zero)],
            "ground_force": [float(v) for v in ground.get("normal_force", zero)],
            "ground_friction": [float(v) for v in ground.get("friction_force", zero)],
            "weight": [float(v) for v in o["weight"]]}


class Recorder:
    """A step watcher (Model.step_watchers): a row after every accepted load step, 2D snapshots for the
    animation; on_stage names the rows of the stage that just ended."""

    def __init__(self, obj: str, frames: bool, picture: Path | None = None):
        self.obj, self.frames, self.picture = obj, frames, picture
        self.model = self.last = None
        self.rows: list = []
        self.snaps: list = []
        self.stages: list = []
        self._start = 0

    def __call__(self, model) -> None:
        self.rows.append(_row(model.readouts(), self.obj))
        if self.frames:
            from skelfem.io.xdmf import snapshot
            self.snaps.append(snapshot(model))

    def on_stage(self, stage, result) -> None:
        d = result.to_dict()
        rows = self.rows[self._start:]
        for i, row in enumerate(rows):
            row.update(stage=stage.name, step=i + 1)
        self._start = len(self.rows)
        entry = {"name": stage.name, "status": result.status, "converged": bool(result.converged),
                 "newton_iterations": int(result.newton_iterations), "load_steps": int(result.load_steps),
                 "time": float(d["timings"].get("solve", 0.0)), "events": d.get("events", [])}
        if result.converged:
            entry.update(_row(d | {"contacts": {i: c for i, c in enumerate(d.get("contacts") or [])}}, self.obj))
            entry["grounds"] = d.get("grounds") or {}
            if self.picture is not None and stage.name == self.last:       # the last stage's (3D) picture
                from skelfem.viz.plots import plot_deformed_3d
                self.picture.parent.mkdir(parents=True, exist_ok=True)
                plot_deformed_3d(self.picture, self.model, f"after {stage.name}: the object's centroid at "
                                 + ", ".join(f"{v:.2f}" for v in entry["object"]) + " mm", window_size=(700, 700))
        self.stages.append(entry)


def _turned(angle_deg: float, dim: int) -> np.ndarray:
    """The rotation by angle_deg about z (in the x-y plane; 3D: about the z axis)."""
    th = math.radians(angle_deg)
    R = np.eye(dim)
    R[:2, :2] = [[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]]
    return R


def _in_frame(point, left, right) -> np.ndarray:
    """A point in the frame of a segment (origin its midpoint, x along it; in the x-y plane)."""
    left, right = np.asarray(left, float), np.asarray(right, float)
    a = right - left
    R = _turned(math.degrees(math.atan2(a[1], a[0])), len(a))
    return R.T @ (np.asarray(point, float) - (left + right) / 2)


def follow(rows: list, stages: list, size: float) -> dict:
    """While held (HELD stages): the object's distance from where the base's rigid motion would carry it from
    its pose after weighing, per row (``follow``, a share of size; ``carried``, that point), and its motion in
    the fingertips' frame since then (``in_grip``, mm: slip and the tips' own strain); the worst of each."""
    ref = next(s for s in stages if s["name"] == "weigh")
    c0, a0, p0 = np.asarray(ref["base"]), ref["base_angle"], np.asarray(ref["object"])
    g0 = _in_frame(p0, *ref["tips"])
    worst: dict = {"share": 0.0, "mm": 0.0, "in_grip": 0.0, "by_stage": {}}
    for row in rows:
        c, p = np.asarray(row["base"]), np.asarray(row["object"])
        carried = c + _turned(row["base_angle"] - a0, len(c)) @ (p0 - c0)
        row["carried"] = [float(v) for v in carried]
        row["follow"] = float(np.linalg.norm(p - carried) / size)
        row["in_grip"] = float(np.linalg.norm(_in_frame(p, *row["tips"]) - g0))
        if row.get("stage") not in HELD:
            continue
        worst["in_grip"] = max(worst["in_grip"], row["in_grip"])
        worst["by_stage"][row["stage"]] = max(worst["by_stage"].get(row["stage"], 0.0), row["follow"])
        if row["follow"] >= worst["share"]:
            worst.update(share=row["follow"], mm=row["follow"] * size, stage=row["stage"], step=row["step"])
    return worst


def scenario(design: dict, frames: bool, picture: Path | None = None) -> tuple[dict, list]:
    """Run the design's stages in one Session with a Recorder: (the records, the 2D snapshots if frames).
    picture: a 3D picture after the last stage."""
    from skelfem import Session
    obj = design["objects"][0]["name"]
    rec = Recorder(obj, frames, picture)
    t0 = time.perf_counter()
    with Session(design) as s:
        dofs = s.dofs
        rec.model, rec.last = s.model, design["stages"][-1]["name"]
        size = float(s.model.term("objects", obj).size)
        s.model.step_watchers.append(rec)
        r = s.run_stages(rec.on_stage)
        s.model.step_watchers.remove(rec)
        final = r.to_dict()
    out = {"design": design["name"], "dofs": int(dofs), "object": obj, "size": size,
           "converged": bool(r.converged), "status": r.status, "newton_iterations": int(r.newton_iterations),
           "load_steps": int(r.load_steps), "time": time.perf_counter() - t0, "stages": rec.stages,
           "events": final.get("events", []), "failed_stage": final.get("failed_stage")}
    if any(s["name"] == "weigh" and s["converged"] for s in rec.stages):
        out["worst_follow"] = follow(rec.rows, rec.stages, size)
    out["rows"] = rec.rows
    return out, rec.snaps


# -- outputs ----------------------------------------------------------------------------------------------
CSV_COLUMNS = ("scenario", "stage", "step", "base", "base_angle", "object", "object_angle", "carried", "follow",
               "in_grip", "normal", "normal_force", "friction", "ground_force", "ground_friction")


def write_csv(path: Path, runs: dict) -> None:
    """One line per accepted load step of every scenario; vectors as one column per component."""
    from skelfem.io.files import atomic_write
    dims = {name: len(r["rows"][0]["base"]) if r["rows"] else 2 for name, r in runs.items()}
    axes = "xyz"[:max(dims.values(), default=2)]
    header = []
    for col in CSV_COLUMNS:
        vector = col in ("base", "object", "carried", "normal_force", "friction", "ground_force", "ground_friction")
        header += [f"{col}_{a}" for a in axes] if vector else [col]
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(header)
    for name, r in runs.items():
        for row in r["rows"]:
            line = []
            for col in CSV_COLUMNS:
                v = name if col == "scenario" else row.get(col, "")
                if isinstance(v, list):
                    line += [f"{x:.6g}" for x in v] + [""] * (len(axes) - len(v))
                else:
                    line.append(f"{v:.6g}" if isinstance(v, float) else v)
            w.writerow(line)
    atomic_write(path, lambda tmp: Path(tmp).write_text(buf.getvalue()))


def _stage_ends(rows: list, snaps: list) -> list:
    """(stage, snapshot) at the end of every stage."""
    ends = {}
    for row, snap in zip(rows, snaps):
        ends[row["stage"]] = snap
    return list(ends.items())


def _view(runs2d: dict, snaps: list) -> tuple:
    """Axes limits that hold every frame (the hand's nodes and the object's outline)."""
    pts = np.vstack([np.vstack([s.x + s.u] + [o["outline"] for o in s.objects if "outline" in o]) for s in snaps])
    lo, hi = pts.min(axis=0) - 6.0, pts.max(axis=0) + 6.0
    return (lo[0], hi[0]), (lo[1], hi[1])


def _draw_state(ax, snap, title: str, xlim, ylim) -> None:
    from skelfem.viz.plots import plot_deformed
    plot_deformed(None, snap, title, ax=ax, show_rest=False)
    if ax.get_legend() is not None:
        ax.get_legend().remove()
    for t in list(ax.texts):                    # marker names: too many at this scale
        t.remove()
    ax.set_xlim(*xlim)
    ax.set_ylim(*ylim)
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=9)
    ax.tick_params(labelsize=7)


def _trajectories(ax, res: dict) -> None:
    """Since weighing: the object's centroid, where the base's rigid motion carries it, and the palm's centre."""
    rows = res["rows"]
    ref = next(st for st in res["stages"] if st["name"] == "weigh")
    p0, c0 = np.asarray(ref["object"]), np.asarray(ref["base"])
    held = [r for r in rows if r["stage"] in ("weigh",) + HELD]
    obj = np.array([r["object"] for r in rows]) - p0
    base = np.array([r["base"] for r in rows]) - c0
    carried = np.array([r["carried"] for r in held]) - p0
    ax.plot(base[:, 0], base[:, 1], "-o", ms=2, color="0.55", lw=1, label="the palm's centre")
    ax.plot(carried[:, 0], carried[:, 1], "-", color="#c0392b", lw=2.5, alpha=0.5, label="carried rigidly by the palm")
    ax.plot(obj[:, 0], obj[:, 1], "-o", ms=2, color="#1f4e79", lw=1, label="the object's centroid")
    for name in ("lift", "carry", "turn", "put_down"):
        r = next(r for r in rows if r["stage"] == name)
        ax.annotate(name, r["object"][:2] - p0[:2], textcoords="offset points", xytext=(3, 4), fontsize=7)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("moved since weighed, x [mm]", fontsize=8)
    ax.set_ylabel("y [mm]", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=7, loc="lower right")
    ax.set_title("trajectories since weighed", fontsize=9)


def _follow(ax, runs: dict) -> None:
    """The object's distance from the base's rigid motion of it, a share of its size, per load step held."""
    styles = {"hand": ("#1f4e79", "hand"), "hand_weightless": ("#5dade2", "hand, its own weight off"),
              "gripper3d": ("#c0392b", "3D gripper (lift)")}
    for name, r in runs.items():
        rows = [row for row in r["rows"] if row.get("stage") in HELD]
        if rows and name in styles:
            colour, label = styles[name]
            ax.plot(range(1, len(rows) + 1), [100 * row["follow"] for row in rows], "-o", ms=2, color=colour,
                    label=label)
    ax.axhline(100 * FOLLOW_SHARE, color="k", lw=0.8, ls="--", label="2 % of the size")
    hand = [row["stage"] for row in runs["hand"]["rows"] if row.get("stage") in HELD]
    for name in HELD:
        if name in hand:
            ax.annotate(name, (hand.index(name) + 1, 0), textcoords="offset points", xytext=(0, -12), fontsize=7)
    ax.set_xlabel("load step while held (lift, carry, turn)", fontsize=8)
    ax.set_ylabel("off the base's motion [% of the size]", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=7, loc="upper left")
    ax.set_title("the object following the base", fontsize=9)


def figure(path: Path, runs: dict, snaps: list) -> None:
    """The hand at the end of every stage, the trajectories, and how closely the object follows the base."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from skelfem.io.files import atomic_write
    res = runs["hand"]
    ends = _stage_ends(res["rows"], snaps)
    xlim, ylim = _view(res, snaps)
    fig = Figure(figsize=(16, 8.6), dpi=90)
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, 5).ravel()
    stages = {s["name"]: s for s in res["stages"]}
    for ax, (name, snap) in zip(axes, ends):
        s = stages[name]
        _draw_state(ax, snap, f"{name}: object at ({s['object'][0]:.1f}, {s['object'][1]:.1f}), "
                              f"{round(s['object_angle'], 1) + 0.0:.1f}°", xlim, ylim)
    _trajectories(axes[len(ends)], res)
    _follow(axes[len(ends) + 1], runs)
    for ax in axes[len(ends) + 2:]:
        ax.set_visible(False)
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))


def animation(path: Path, res: dict, snaps: list, ms: int = 250) -> None:
    """Every accepted load step, axes fixed (a GIF, one palette)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from PIL import Image
    from skelfem.io.files import atomic_write
    xlim, ylim = _view(res, snaps)
    images = []
    for row, snap in zip(res["rows"], snaps):
        fig = Figure(figsize=(3.6, 3.6), dpi=72)
        FigureCanvasAgg(fig)
        ax = fig.subplots()
        _draw_state(ax, snap, f"{row['stage']} {row['step']}", xlim, ylim)
        ax.collections[0].set_edgecolor("face")          # no cell edges: noise at this size, and twice the bytes
        fig.tight_layout()
        fig.canvas.draw()                                  # the canvas's pixels, no PNG in between
        images.append(Image.frombuffer("RGBA", fig.canvas.get_width_height(), fig.canvas.buffer_rgba(), "raw",
                                       "RGBA", 0, 1).convert("RGB"))
    palette = images[len(images) // 2].quantize(colors=32)
    frames = [im.quantize(palette=palette) for im in images]

    def save(tmp):
        frames[0].save(tmp, format="GIF", save_all=True, append_images=frames[1:], duration=ms, loop=0)
    atomic_write(path, save)


def run(size: float | None = None, density: float = 310.0, contraction: float = 4.0, turn_steps: int = 12,
        size3d: float | None = None, three_d: bool = True, weightless: bool = True, out: Path | None = OUT,
        figures: Path | None = FIGURES, say=print) -> dict:
    """Both scenarios, and (weightless) the hand's held stages again with its own materials weightless (the
    object keeps its weight); writes the JSON, CSV and designs into out and the pictures into figures (None:
    not)."""
    from skelfem.io.files import design_toml, write_json
    t0 = time.perf_counter()
    designs = {"hand": hand_design(size, density, contraction, turn_steps=turn_steps)}
    if weightless:
        d = hand_design(size, density, contraction, turn_steps=turn_steps)
        d["name"] = "hand_weightless"
        for material in ("ecoflex", "pla"):
            d["materials"][material]["density"] = WEIGHTLESS
        d["stages"] = [st for st in d["stages"] if st["name"] in ("close", "weigh") + HELD]
        designs["hand_weightless"] = d
    if three_d:
        designs["gripper3d"] = gripper3d_design(size3d)
    runs, snaps = {}, []
    for name, d in designs.items():
        picture = Path(figures) / "hand_scenario_3d.png" if figures is not None and d["dim"] == 3 else None
        runs[name], frames = scenario(d, frames=figures is not None and name == "hand", picture=picture)
        snaps = frames or snaps
        r = runs[name]
        say(f"{name}: {r['status']}, {r['newton_iterations']} Newton iterations over {r['load_steps']} load steps, "
            f"{r['dofs']} DOFs, {r['time']:.1f} s")
        for st in r["stages"]:
            say(f"  {st['name']:8s} {st['status']}, {st['newton_iterations']} its / {st['load_steps']} steps: "
                + "object at " + (", ".join(f"{v:.2f}" for v in st["object"]) if st["converged"] else "-")
                + (f", turned {st['object_angle']:.2f} deg" if st["converged"] else ""))
        w = r.get("worst_follow")
        if w:
            say(f"  held: {', '.join(f'{k} {100 * v:.2f} %' for k, v in w['by_stage'].items())} of the size "
                f"({r['size']:.1f} mm) from the base's rigid motion; {w['in_grip']:.3f} mm in the grip")
    res = {"params": {"size": size, "density": density, "contraction": contraction, "turn_steps": turn_steps,
                      "size3d": size3d, "weightless": WEIGHTLESS if weightless else None},
           **runs, "time": time.perf_counter() - t0}
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        write_json(out / "hand_scenario.json", res)
        write_csv(out / "hand_scenario.csv", runs)
        for name, d in designs.items():
            (out / f"{name}.toml").write_text(design_toml(d))
    if figures is not None and snaps:
        Path(figures).mkdir(parents=True, exist_ok=True)
        figure(Path(figures) / "hand_scenario.png", runs, snaps)
        animation(Path(figures) / "hand_scenario.gif", runs["hand"], snaps)
    return res


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=float, default=None, help="the hand's mesh size, mm (default: the design's)")
    p.add_argument("--density", type=float, default=310.0, help="the object's density, kg/m^3")
    p.add_argument("--contraction", type=float, default=4.0, help="the outer flexors' contraction, mm")
    p.add_argument("--turn-steps", type=int, default=12)
    p.add_argument("--size3d", type=float, default=None, help="the 3D gripper's mesh size, mm (default: the design's)")
    p.add_argument("--no-3d", action="store_true")
    p.add_argument("--no-weightless", action="store_true", help="skip the turn with the hand's own weight off")
    p.add_argument("--out", type=Path, default=OUT)
    p.add_argument("--figures", type=Path, default=FIGURES)
    a = p.parse_args(argv)
    res = run(a.size, a.density, a.contraction, a.turn_steps, a.size3d, not a.no_3d, not a.no_weightless, a.out,
              a.figures)
    ok = all(res[k]["converged"] for k in ("hand", "hand_weightless", "gripper3d") if k in res)
    return 0 if ok else 2


if __name__ == "__main__":
    raise SystemExit(main())
