"""Printed sheaths: a tube of bone material round a channel that would open a bone's side.

A tendon that enters a bone at a grazing angle, or runs along just under
its surface (a non-planar skeleton: arm3d's lateral tendon meets the
radius at 9 degrees), leaves less than ``min_wall`` between its channel and
the bone's surface, and a channel cut there would be an open groove. Rather
than refuse the design, the printed bone carries a **sheath**: a tube of
outer radius r + min_wall (r the channel's radius) round the channel's
axis, fused to the bone, over the piece of the cable inside the bone and
on out along the cable's straight segment until the axis lies r + min_wall
clear of the bone's surface. The channel is then closed everywhere and
leaves the sheath through its end, square on.

The sheath is bone material outside the bone as designed: the robot as cast
is that much stiffer near the channel's mouth than the one simulated. Its
volume outside the bone is reported (``fabrication.json``: each bone's
``sheath_volume``) with a note; it is small beside the bone (the tube is a
channel's width).

A sheath is refused (FabricationError naming the cable and the point) when
it would leave the body (less than min_wall of silicone over it), come
within min_wall of another bone, crowd another cable, or when the cable's
segment ends (a bend of its sketch) before the axis is clear of the bone.
"""
from __future__ import annotations

import numpy as np
from .parts import Tool, cable_points, cable_radius, where_text
from .routes import dense, segment_distance
from .surfaces import FabricationError, point_triangle_distance

STEP = 0.1        # of the sheath's radius: how finely the way out along the cable is searched


def _outward(cable_pts: np.ndarray, arc: float, sign: float, tol: float) -> tuple[np.ndarray, float]:
    """From the point at arclength arc of the cable, the unit direction out along the cable (sign -1:
    toward its start, +1: toward its end) and the length of straight segment available that way."""
    seg = np.diff(cable_pts, axis=0)
    L = np.linalg.norm(seg, axis=1)
    arc0 = np.r_[0.0, np.cumsum(L)]
    if sign < 0:
        i = int(np.clip(np.searchsorted(arc0, arc - tol) - 1, 0, len(L) - 1))
        return -seg[i] / L[i], max(arc - arc0[i], 0.0)
    i = int(np.clip(np.searchsorted(arc0, arc + tol, side="right") - 1, 0, len(L) - 1))
    return seg[i] / L[i], max(arc0[i + 1] - arc, 0.0)


def sheath(planner, tool: Tool, start: dict, end: dict) -> tuple[Tool, Tool]:
    """(the sheath, the channel through it) for a channel tool whose wall is too thin; see the module doc."""
    design, spec = planner.design, planner.spec
    surface = planner.bones[tool.bone]
    cable = design.cable(tool.cable)
    pts = cable_points(design, cable)
    need = tool.radius + spec.min_wall
    axis = [p for p in tool.points]
    key = f"cables.{cable.name}.path"
    for which, end_ in ((0, start), (-1, end)):
        if end_["at"] != "face":
            continue
        direction, room = _outward(pts, end_["s"], -1.0 if which == 0 else 1.0, planner.tol)
        t = np.arange(0.0, room + 1e-12, STEP * need)
        if not len(t) or t[-1] < room:
            t = np.r_[t, room]
        x = end_["point"] + t[:, None] * direction
        clear = point_triangle_distance(x, surface.corners).min(axis=1) >= need
        if not clear.any():
            raise FabricationError(key, f"its channel runs within {need:g} mm (radius + min_wall) of bone "
                                        f"{tool.bone!r}'s surface from {where_text(end_['point'])} to the end of its "
                                        f"sketch's segment at {where_text(x[-1])}, so no sheath closes it there: "
                                        "move the cable into the bone or away from it")
        out = end_["point"] + float(t[int(np.argmax(clear))]) * direction
        if which == 0:
            axis[0] = out
        else:
            axis[-1] = out
    axis = np.array(axis)
    _check(planner, axis, need, tool, key)
    ext = tuple(0.5 if e["at"] == "face" else 0.0 for e in (start, end))
    return (Tool("sheath", axis, need, tool.bone, cable.name),
            Tool("channel", axis, tool.radius, tool.bone, cable.name, ext))


def _check(planner, axis: np.ndarray, need: float, tool: Tool, key: str) -> None:
    """The sheath inside the body under min_wall of silicone, clear of other bones and other cables."""
    spec = planner.spec
    x = dense(axis, min(0.25, need / 2))
    body = point_triangle_distance(x, planner.body.corners).min(axis=1)
    i = int(np.argmin(body))
    if body[i] < need + spec.min_wall:
        raise FabricationError(key, f"the sheath its channel needs in bone {tool.bone!r} would come within "
                                    f"{max(body[i] - need, 0):.2g} mm of the body's surface near {where_text(x[i])} "
                                    f"(fabrication.min_wall {spec.min_wall:g} mm of silicone is needed over it)")
    for name, other in planner.bones.items():
        if name == tool.bone:
            continue
        d = point_triangle_distance(x, other.corners).min(axis=1)
        if d.min() < need + spec.min_wall:
            raise FabricationError(key, f"the sheath its channel needs in bone {tool.bone!r} would come within "
                                        f"{max(float(d.min()) - need, 0):.2g} mm of bone {name!r} near "
                                        f"{where_text(x[int(np.argmin(d))])}")
    for other in planner.design.cables:
        if other.name == tool.cable:
            continue
        d = segment_distance(x, cable_points(planner.design, other))
        if d.min() < need + cable_radius(spec, other):
            raise FabricationError(key, f"the sheath its channel needs in bone {tool.bone!r} would meet cable "
                                        f"{other.name!r} near {where_text(x[int(np.argmin(d))])}")
