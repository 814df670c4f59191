"""The exploded view of the parts (matplotlib, no pyplot).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from .parts import Plan


# -- the picture ---------------------------------------------------------------------------------------------------
def coarsen(points: np.ndarray, tris: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertex clustering, for drawing: corners in one cube of side h merge at their mean, triangles
    that collapse are dropped. Keeps the look of a surface at a fraction of its triangles."""
    keys = np.floor(points / h).astype(np.int64)
    _, cluster, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    cluster = cluster.ravel()
    merged = np.zeros((len(counts), 3))
    np.add.at(merged, cluster, points)
    t = cluster[tris]
    keep = (t[:, 0] != t[:, 1]) & (t[:, 1] != t[:, 2]) & (t[:, 0] != t[:, 2])
    return merged / counts[:, None], t[keep]


COLOURS = {"bone": (0.93, 0.55, 0.18), "mould_bottom": (0.45, 0.62, 0.85), "mould_top": (0.55, 0.75, 0.60),
           "body": (0.80, 0.45, 0.55)}
LEGEND = {"mould_top": "mould top (translucent)", "bone": "bones", "mould_bottom": "mould bottom",
          "body": "body (translucent)"}
TRANSLUCENT = ("mould_top", "body")


ELEV, AZIM = math.radians(22), math.radians(-58)
EYE = np.array([math.cos(ELEV) * math.cos(AZIM), math.cos(ELEV) * math.sin(AZIM), math.sin(ELEV)])
LIGHT = np.array([0.4, -0.6, 0.7]) / np.linalg.norm([0.4, -0.6, 0.7])


def colour_of(name: str) -> tuple:
    return COLOURS.get(name, COLOURS["bone"])


def draw_surface(ax, y: np.ndarray, tris: np.ndarray, base, alpha: float = 1.0) -> None:
    """Triangles (points y in the frame's u, v, n) into a 3D axes, Lambert-shaded (see picture)."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection
    tri = y[tris]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
    facing = n @ EYE > 0                # back faces are hidden in a closed solid: not drawn
    tri, n = tri[facing], n[facing]
    shade = 0.35 + 0.65 * np.clip(n @ LIGHT, 0.0, 1.0)
    colours = np.column_stack([np.clip(shade[:, None] * np.asarray(base), 0, 1), np.full(len(tri), alpha)])
    ax.add_collection3d(Poly3DCollection(tri, facecolors=colours, edgecolors=colours,
                                         linewidths=0.2 if alpha == 1.0 else 0.0))


def frame_axes(ax, lo: np.ndarray, hi: np.ndarray, labels: bool = True) -> None:
    """Equal scales over the box lo..hi, the common view."""
    centre, span = (lo + hi) / 2, np.maximum(hi - lo, 1e-9)
    for set_lim, c, s in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre, span):
        set_lim(c - s / 2, c + s / 2)
    ax.set_box_aspect(span)
    ax.view_init(elev=math.degrees(ELEV), azim=math.degrees(AZIM))
    if labels:
        ax.set_xlabel("u [mm]"), ax.set_ylabel("v [mm]"), ax.set_zlabel("n [mm]")
        ax.tick_params(labelsize=7)
    else:
        ax.set_axis_off()


def picture(path, parts: list, plan: Plan, title: str = "") -> None:
    """Exploded view of the parts (matplotlib, headless): mould halves drawn apart along the mould's
    normal (up in the picture), bones between them where they are cast; a printed body (part "body")
    translucent around its bones.

    Each triangle is shaded by Lambert's law, colour x (0.35 + 0.65 max(0, n . l)),
    with n its outward normal and l a fixed light from above and in front;
    triangles facing away from the eye (n . e <= 0) are left out, which also
    spares matplotlib's painter's algorithm most of its depth-order mistakes.
    """
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    from ..io.files import atomic_write

    f = plan.frame
    height = float(f.hi[2] - f.lo[2])
    shift = {"mould_bottom": -0.9 * height, "mould_top": 0.9 * height}
    fig = Figure(figsize=(9, 7), dpi=110)
    ax = fig.add_subplot(projection="3d")
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for part in parts:
        h = plan.scale / (150 if part.kind == "mould" else 600)     # the mould halves carry most triangles
        points, tris = coarsen(part.surface.points, part.surface.tris, h)
        y = f.local(points)
        y[:, 2] += shift.get(part.name, 0.0)
        draw_surface(ax, y, tris, colour_of(part.name), 0.35 if part.name in TRANSLUCENT else 1.0)
        lo, hi = np.minimum(lo, y.min(axis=0)), np.maximum(hi, y.max(axis=0))
    frame_axes(ax, lo, hi)
    shown = [k for k in LEGEND if any((p.name if p.name in COLOURS else "bone") == k for p in parts)]
    ax.legend([Rectangle((0, 0), 1, 1, color=COLOURS[k]) for k in shown], [LEGEND[k] for k in shown],
              loc="upper left", fontsize=8)
    ax.set_title(title or f"{plan.design.name}: parts, exploded along the mould's normal", fontsize=10)
    fig.subplots_adjust(left=0.0, right=1.0, bottom=0.04, top=0.94)
    atomic_write(Path(path), lambda tmp: fig.savefig(tmp, format="png"))
