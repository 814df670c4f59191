"""The casting sequence (the paper's Fig. 3) drawn from the design's own parts: casting.png.

Six panels, each a step a maker takes with the files of `skelfem fabricate`:

1. print the bones and both mould halves (drawn apart along the mould's normal);
2. thread the tendons through the bones' channels and loop the ligaments
   through their anchor holes: the skeleton;
3. set the skeleton on the bottom half's pegs (each bone's sockets);
4. close the mould: the top half's pin holes over the bottom's pins;
5. pour silicone through the pour hole until it rises in the vents;
6. cure, open the mould, pull the robot off the pegs and fill the peg holes.

Parts are drawn as in the exploded view (``picture``); cables as lines along
their sketches (tendons red, ligaments blue); the silicone as the body's
surface, translucent. Each panel draws in the order of assembly (mould, silicone, bones, cables),
so that what lies inside stays visible.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from .parts import Plan, cable_points
from .picture import COLOURS, coarsen, colour_of, draw_surface, frame_axes

STEPS = ("1  print the bones and both mould halves",
         "2  thread the tendons, loop the ligaments: the skeleton",
         "3  set the skeleton on the bottom half's pegs",
         "4  close the mould over its pins",
         "5  pour silicone until it rises in the vents",
         "6  cure, demould, fill the peg holes")
CABLE_COLOURS = {"tendon": "#c0392b", "ligament": "#2e6fbf"}
SILICONE = (0.80, 0.45, 0.55)


def _cable_lines(plan: Plan) -> list[tuple[str, np.ndarray]]:
    return [(c.kind, plan.frame.local(cable_points(plan.design, c))) for c in plan.design.cables]


def casting_sequence(path, parts: list, plan: Plan) -> list[str]:
    """Draw the six steps into path (PNG); returns the panels' titles."""
    from matplotlib.figure import Figure

    from ..io.files import atomic_write

    f = plan.frame
    height = float(f.hi[2] - f.lo[2])
    drawn = {}
    for part in parts:                                  # coarsened once, in frame coordinates
        h = plan.scale / (150 if part.kind == "mould" else 600)
        points, tris = coarsen(part.surface.points, part.surface.tris, h)
        drawn[part.name] = (f.local(points), tris, part.kind)
    body = plan.body_surface
    body_y = f.local(body.points) if body is not None else None
    bones = [n for n, (_, _, kind) in drawn.items() if kind == "bone"]
    cables = _cable_lines(plan)
    pours = [f.local(t.points) for t in plan.mould_tools if t.kind == "pour"]

    fig = Figure(figsize=(13, 8.4), dpi=100)
    box_lo, box_hi = f.lo.copy(), f.hi.copy()
    for k, title in enumerate(STEPS):
        ax = fig.add_subplot(2, 3, k + 1, projection="3d", computed_zorder=False)   # drawn in the order added:
        lo, hi = box_lo.copy(), box_hi.copy()                                     # what is inside shows

        def part(name, shift=0.0, alpha=1.0):
            y, tris, _ = drawn[name]
            y = y + np.array([0.0, 0.0, shift])
            draw_surface(ax, y, tris, colour_of(name), alpha)
            return y

        if k == 0:
            for name, shift in (("mould_bottom", -0.9 * height), ("mould_top", 0.9 * height)):
                y = part(name, shift)
                lo, hi = np.minimum(lo, y.min(axis=0)), np.maximum(hi, y.max(axis=0))
        if k in (2, 3, 4):
            part("mould_bottom", alpha=0.55)
        if k in (0, 1, 2, 3, 5):
            for name in bones:
                part(name)
        if k in (3, 4):
            part("mould_top", alpha=0.25 if k == 3 else 0.15)
        if k in (4, 5) and body_y is not None:
            draw_surface(ax, body_y, body.tris, SILICONE, 0.45 if k == 4 else 0.35)
        if k in (1, 2, 5):
            for kind, y in cables:
                ax.plot(*y.T, color=CABLE_COLOURS[kind], lw=1.6 if kind == "tendon" else 1.1)
        if k == 4:
            for y in pours:                              # the pour: an arrow down into the hole
                top = y[np.argmax(y[:, 2])]
                ax.quiver(*top + np.array([0.0, 0.0, 0.6 * height]), 0.0, 0.0, -0.55 * height,
                          color=COLOURS["bone"], lw=2.0, arrow_length_ratio=0.3)
                hi[2] = max(hi[2], top[2] + 0.6 * height)
        frame_axes(ax, lo, hi, labels=False)
        ax.set_title(title, fontsize=10)
    fig.suptitle(f"{plan.design.name}: casting the robot with the printed parts", fontsize=12)
    fig.subplots_adjust(left=0.0, right=1.0, bottom=0.0, top=0.93, wspace=0.0, hspace=0.05)
    atomic_write(Path(path), lambda tmp: fig.savefig(tmp, format="png"))
    return list(STEPS)
