"""deformed.png: the deformed design in 2D (matplotlib, no pyplot) or 3D (PyVista, off-screen), and IK tracks.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from ..io.files import atomic_write
from ..io.xdmf import gathered_snapshot


REGION_COLORS = {"body": "#f4b6a6", "bone": "#e8e4d8", "object": "#b9d3ee"}
FORCE_COLORS = {"normal": "#c0392b", "friction": "#1e8449"}
CABLE_COLORS = {"tendon": "#1f5fbf", "ligament": "#d9822b"}


def plot_deformed(path: Path, state, title: str = "", ax=None, show_rest: bool = True):
    """Rest outline, deformed mesh coloured by region, cables, markers and pins (2D)."""
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle
    from matplotlib.collections import PolyCollection

    snap = gathered_snapshot(state)
    if snap is None:
        return
    design = snap.design
    x, u, tri = snap.x, snap.u, snap.cells
    y = x + u
    own = ax is None
    if own:
        fig = Figure(figsize=(6, 7), dpi=120)
        ax = fig.subplots()
    regions = snap.regions
    colors = np.where(np.isin(regions, snap.body_tags), REGION_COLORS["body"], REGION_COLORS["bone"])
    object_tags = {tag for name, tag in (getattr(snap, "tags", None) or {}).items() if name.startswith("object:")}
    if object_tags:
        colors = np.where(np.isin(regions, list(object_tags)), REGION_COLORS["object"], colors)
    ax.add_collection(PolyCollection(y[tri], facecolors=colors, edgecolors="#7a6a66",
                                     linewidths=0.15))
    if show_rest:
        loops = [*design.body_loops, *(b.outline for b in design.bones)]
        for loop in loops:
            closed = np.vstack([loop, loop[:1]])
            ax.plot(closed[:, 0], closed[:, 1], color="0.55", lw=0.8, ls="--", zorder=1)
    _draw_cables(ax, snap.cables)
    for pin in design.pins:
        (x0, y0), (x1, y1) = pin.region
        ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, hatch="////",
                                   ec="0.3", lw=0.6, zorder=2))
    for g in design.grounds:
        t = np.array([-g.normal[1], g.normal[0]])
        ends = np.array([g.point - 1e3 * t, g.point + 1e3 * t])
        ax.plot(ends[:, 0], ends[:, 1], color="k", lw=1.5, zorder=2)
    if snap.markers:
        pos = np.array(list(snap.markers.values()))
        ax.plot(pos[:, 0], pos[:, 1], "o", color="#222222", ms=4, zorder=4)
        for name, p in snap.markers.items():
            ax.annotate(name, p, textcoords="offset points", xytext=(5, 5), fontsize=8)
    draw_objects(ax, getattr(snap, "objects", []), show_rest=show_rest,
                 rest={o.name: o.outline for o in design.objects})
    allpts = np.vstack([y, x]) if show_rest else y
    lo, hi = allpts.min(axis=0), allpts.max(axis=0)
    pad = 0.06 * (hi - lo).max()
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    if title:
        ax.set_title(title, fontsize=10)
    if snap.cables:
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.09), ncol=2, fontsize=7, frameon=False)
    if own:
        fig.tight_layout()
        atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))


def _draw_cables(ax, cables: list) -> None:
    """Cables over the mesh: one colour per kind, or, for a cable whose tension varies along it
    (friction), every segment coloured by its tension on one scale for all such cables (with a colour
    bar); dotted when slack. Each cable is one legend entry with its tension at the actuated end
    (and at the far end when they differ)."""
    from matplotlib.collections import LineCollection
    from matplotlib.colors import Normalize
    varying = [c for c in cables if np.ptp(c.get("tensions", [0.0])) > 1e-9 * max(c["tension"], 1e-300)]
    norm = Normalize(0.0, max((float(np.max(c["tensions"])) for c in varying), default=1.0))
    mappable = None
    for c in cables:
        p = c["deformed"]
        taut = c["tension"] > 0 or (c in varying)
        lw = 1.2 + (1.5 if taut else 0.0)
        label = f"{c['name']} ({c['kind']}): {c['tension']:.3g} N"
        if c in varying:
            label += f" to {c['tensions'][-1]:.3g} N"
            mappable = LineCollection(np.stack([p[:-1], p[1:]], axis=1), array=np.asarray(c["tensions"]),
                                      cmap="viridis", norm=norm, linewidths=lw + 0.6, zorder=3)
            ax.add_collection(mappable)
            ax.plot([], [], color=mappable.cmap(0.6), lw=lw, label=label)
            continue
        ax.plot(p[:, 0], p[:, 1], color=CABLE_COLORS[c["kind"]], lw=lw, zorder=3,
                ls="-" if taut else ":", label=label)
    if mappable is not None:
        ax.figure.colorbar(mappable, ax=ax, shrink=0.6, pad=0.02, label="cable tension [N]")


def draw_objects(ax, objects: list, show_rest: bool = True, rest: dict | None = None,
                 arrow_length: float | None = None) -> None:
    """Free objects (Snapshot.objects): each outline moved by its rigid motion, its rest outline dashed,
    and the contact forces on it as arrows at the contact nodes (barrier force red, friction green),
    every arrow on one scale (the largest nodal force is arrow_length mm long, default a fifth of the
    largest object's size)."""
    if not objects:
        return
    forces = [np.linalg.norm(o[k], axis=1) for o in objects if "points" in o for k in ("normal", "friction")
              if len(o[k])]
    fmax = max((float(f.max()) for f in forces), default=0.0)
    size = max((float(np.linalg.norm(np.ptp(o["outline"], axis=0))) for o in objects if "outline" in o),
               default=0.0) or float(np.linalg.norm(np.ptp(ax.dataLim.get_points(), axis=0))) / 2
    scale = (arrow_length or 0.2 * size) / fmax if fmax > 0 else 0.0
    for o in objects:
        if "outline" not in o:                 # a body something touches: only the forces on it
            _force_arrows(ax, o, scale, fmax)
            continue
        closed = np.vstack([o["outline"], o["outline"][:1]])
        ax.plot(closed[:, 0], closed[:, 1], color="#1f4e79", lw=1.4, zorder=5)
        if show_rest and rest and o["name"] in rest:
            loop = np.asarray(rest[o["name"]], float)
            loop = np.vstack([loop, loop[:1]])
            ax.plot(loop[:, 0], loop[:, 1], color="#1f4e79", lw=0.7, ls="--", zorder=1)
        ax.annotate(o["name"], o["outline"].mean(axis=0), ha="center", va="center", fontsize=8, color="#1f4e79")
        _force_arrows(ax, o, scale, fmax)


def _force_arrows(ax, o: dict, scale: float, fmax: float) -> None:
    """The contact forces on one piece as arrows at its contact nodes (barrier red, friction green)."""
    if scale <= 0 or "points" not in o:
        return
    for key, label in (("normal", "contact (normal) force"), ("friction", "friction force")):
        f = o[key]
        keep = np.linalg.norm(f, axis=1) > 1e-3 * fmax
        if keep.any():
            p = o["points"][keep]
            ax.quiver(p[:, 0], p[:, 1], scale * f[keep, 0], scale * f[keep, 1], angles="xy",
                      scale_units="xy", scale=1.0, color=FORCE_COLORS[key], width=0.004, zorder=6,
                      label=f"{label} on {o['name']}")


def plot_deformed_3d(path: Path, state, title: str = "", window_size=(900, 900),
                     points=(), paths=()) -> None:
    """Off-screen PNG of a 3D result: translucent body, opaque bones, cables, markers.

    `points` are extra (xyz, colour) dots (e.g. IK targets), `paths` extra
    ((n, 3) array, colour) polylines (e.g. a target path). Rendered with
    pyvista/VTK through EGL, so it needs no display.
    """
    os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    import pyvista as pv

    snap = gathered_snapshot(state)
    if snap is None:
        return
    x, u, tets = snap.x, snap.u, snap.cells
    y = x + u
    regions = snap.regions
    soft = np.isin(regions, snap.body_tags)
    cells = np.column_stack([np.full(len(tets), 4), tets]).ravel()
    grid = pv.UnstructuredGrid(cells, np.full(len(tets), pv.CellType.TETRA, dtype=np.uint8), y)
    grid.cell_data["region"] = regions
    rest = pv.UnstructuredGrid(cells, np.full(len(tets), pv.CellType.TETRA, dtype=np.uint8), x)
    p = pv.Plotter(off_screen=True, window_size=window_size)
    p.set_background("white")
    body = grid.extract_cells(np.flatnonzero(soft)).extract_surface(algorithm=None)
    p.add_mesh(rest.extract_surface(algorithm=None).extract_feature_edges(30.0), color="#888888", line_width=1.0)
    p.add_mesh(body, color=REGION_COLORS["body"], opacity=0.35, show_edges=False)
    bones = np.flatnonzero(~soft)
    if len(bones):
        p.add_mesh(grid.extract_cells(bones).extract_surface(algorithm=None), color=REGION_COLORS["bone"],
                   show_edges=True, edge_color="#9a9080", line_width=0.3)
    top = max((float(np.max(c["tensions"])) for c in snap.cables if "tensions" in c), default=0.0)
    coloured = False
    for c in snap.cables:
        line = pv.lines_from_points(c["deformed"])
        width = 5 if c["tension"] > 0 else 2
        if np.ptp(c.get("tensions", [0.0])) > 1e-9 * max(c["tension"], 1e-300):   # friction: by tension
            line.cell_data["tension"] = np.asarray(c["tensions"], float)
            p.add_mesh(line, scalars="tension", cmap="viridis", clim=(0.0, top), line_width=5,
                       show_scalar_bar=False)      # (VTK's scalar bar crashes off-screen here: a legend line instead)
            coloured = True
            continue
        p.add_mesh(line, color=CABLE_COLORS[c["kind"]], line_width=width, render_lines_as_tubes=True)
    if coloured:
        p.add_text(f"cables with friction coloured by tension (viridis): 0 to {top:.3g} N", position="upper_left",
                   font_size=10, color="#333333")
    if snap.markers:
        pos = np.array(list(snap.markers.values()))
        p.add_point_labels(pos, list(snap.markers), point_size=12, font_size=14, point_color="#222222",
                           shape=None, always_visible=True)
    for xyz, colour in points:
        p.add_mesh(pv.PolyData(np.atleast_2d(np.asarray(xyz, float))), color=colour, point_size=16,
                   render_points_as_spheres=True)
    for pts, colour in paths:
        p.add_mesh(pv.lines_from_points(np.asarray(pts, float)), color=colour, line_width=4)
    if title:
        p.add_text(title, font_size=11, color="black")
    p.add_axes(color="black")
    extent = np.ptp(x, axis=0)
    if extent[2] < 0.5 * extent[:2].max():   # a slab (extruded 2D design) bends in x-y: look along z
        p.view_xy()
        p.camera.Elevation(-20)
        p.camera.Azimuth(25)
    else:
        p.view_isometric()
    p.reset_camera()
    atomic_write(path, lambda tmp: p.screenshot(tmp))
    p.close()


# -- tracking pictures (ik, track, the IK study) ---------------------------------------------------
TARGET_COLOR, ACHIEVED_COLOR = "#d62728", "#2ca02c"


def include_points(ax, points: np.ndarray, pad: float = 3.0) -> None:
    """Widen the axis limits to show points."""
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    lo, hi = points[:, :2].min(axis=0) - pad, points[:, :2].max(axis=0) + pad
    ax.set_xlim(min(x0, lo[0]), max(x1, hi[0]))
    ax.set_ylim(min(y0, lo[1]), max(y1, hi[1]))


def plot_poses(ax, model, poses: list, alpha: float = 0.3) -> None:
    """Deformed poses (local DOF arrays) drawn faded on one axis; model.u is restored after."""
    from matplotlib.legend import Legend

    keep = model.u.x.array.copy()
    lims = []
    for i, pose in enumerate(poses):
        model.u.x.array[:] = pose
        before = set(ax.get_children())
        plot_deformed(None, model, ax=ax, show_rest=(i == 0))
        for artist in set(ax.get_children()) - before:
            if hasattr(artist, "set_alpha") and not isinstance(artist, Legend):
                artist.set_alpha(alpha if i < len(poses) - 1 else min(1.0, 2 * alpha))
        lims.append((*ax.get_xlim(), *ax.get_ylim()))
    model.u.x.array[:] = keep
    if lims:
        lims = np.array(lims)
        ax.set_xlim(lims[:, 0].min(), lims[:, 1].max())
        ax.set_ylim(lims[:, 2].min(), lims[:, 3].max())


def draw_track(ax, model, results, poses: list, title: str = "") -> None:
    """Target and achieved paths over a few faded deformed poses, on one axis."""
    plot_poses(ax, model, poses)
    if ax.get_legend() is not None:
        ax.get_legend().remove()                # the cables' legend: too long for several poses
    target = np.array([r.target for r in results])
    achieved = np.array([r.position for r in results])
    h1, = ax.plot(target[:, 0], target[:, 1], "x--", color=TARGET_COLOR, ms=5, lw=1, zorder=6, label="target")
    h2, = ax.plot(achieved[:, 0], achieved[:, 1], "o-", color=ACHIEVED_COLOR, ms=3, lw=1.2, zorder=7,
                  mfc="none", label="achieved")
    include_points(ax, np.vstack([target, achieved]))
    ax.legend(handles=[h1, h2], loc="upper right", fontsize=8)
    if title:
        ax.set_title(title, fontsize=10)


