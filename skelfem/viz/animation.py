"""motion.gif: an animated run in time, axes fixed over the motion.

The first frame is drawn in full (``plot_deformed``: mesh, rest outline,
cables, pins, grounds, markers); what does not move (axes, ticks, the rest
outline, pins, grounds) is rendered once as a background, and every frame
restores it and draws only what moves (the mesh's cells, the cables, the
markers and their labels, the title) on it: no new figure, no axis drawn
again. Pillow writes the GIF (one shared palette).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..io.files import atomic_write
from .plots import REGION_COLORS, plot_deformed



def _frame_image(fig):
    """The figure's canvas as it is now, as a Pillow image (RGB)."""
    from PIL import Image
    return Image.frombuffer("RGBA", fig.canvas.get_width_height(), fig.canvas.buffer_rgba(), "raw", "RGBA", 0, 1) \
        .convert("RGB")


def _cells_path(y: np.ndarray, tri: np.ndarray):
    """All the cells as one compound path (one array, not a Path per cell): fast to update."""
    from matplotlib.path import Path as MPath
    v = np.empty((len(tri), 4, 2))
    v[:, :3] = y[tri][:, :, :2]
    v[:, 3] = v[:, 0]
    codes = np.tile(np.array([MPath.MOVETO, MPath.LINETO, MPath.LINETO, MPath.CLOSEPOLY], np.uint8), len(tri))
    return MPath(v.reshape(-1, 2), codes)


def write_motion_gif(path: Path, frames: list, title: str = "", fps: int = 20) -> None:
    """An animated GIF of 2D snapshots [(t, Snapshot)], axes fixed over the motion."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    allpts = np.vstack([np.vstack([s.x + s.u, s.x]) for _, s in frames])
    lo, hi = allpts.min(axis=0), allpts.max(axis=0)
    pad = 0.06 * (hi - lo).max()
    fig = Figure(figsize=(5, 5.5), dpi=80)
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    t0, first = frames[0]
    plot_deformed(None, first, f"{title}  t = {t0:.4g} s", ax=ax)
    if ax.get_legend() is not None:
        ax.get_legend().remove()
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    fig.tight_layout()
    from matplotlib.patches import PathPatch
    ax.collections[0].remove()                           # the cells: one compound path per region instead
    soft = np.isin(first.regions, first.body_tags)
    groups = [(soft, REGION_COLORS["body"]), (~soft, REGION_COLORS["bone"])]
    patches = []
    for mask, colour in groups:
        if mask.any():
            patch = PathPatch(_cells_path(first.x + first.u, first.cells[mask]), facecolor=colour,
                              edgecolor="none", zorder=0.5)     # no cell edges: invisible at 80 dpi, and half the cost
            ax.add_patch(patch)
            patches.append((patch, mask))
    cables = {str(line.get_label()).split(" (")[0]: line for line in ax.lines
              if any(str(line.get_label()).startswith(f"{c['name']} (") for c in first.cables)}
    names = list(first.markers)
    dots = [line for line in ax.lines if line.get_marker() == "o"]
    labels = {t.get_text(): t for t in ax.texts}
    moving = [*(patch for patch, _ in patches), *cables.values(), *dots, *(labels[n] for n in names if n in labels),
              ax.title]
    for artist in moving:
        artist.set_animated(True)
    canvas = fig.canvas
    canvas.draw()                                        # the background: everything that does not move
    background = canvas.copy_from_bbox(fig.bbox)
    images = []
    for i, (t, snap) in enumerate(frames):
        if i:
            for patch, mask in patches:
                patch.set_path(_cells_path(snap.x + snap.u, snap.cells[mask]))
            for c in snap.cables:
                if c["name"] in cables:
                    p = c["deformed"]
                    cables[c["name"]].set_data(p[:, 0], p[:, 1])
                    cables[c["name"]].set_linestyle("-" if c["tension"] > 0 else ":")
            if names and dots:
                pos = np.array([snap.markers[n] for n in names])
                dots[0].set_data(pos[:, 0], pos[:, 1])
                for n, p in zip(names, pos):
                    if n in labels:
                        labels[n].xy = tuple(p[:2])
            ax.title.set_text(f"{title}  t = {t:.4g} s")
        canvas.restore_region(background)
        for artist in moving:
            ax.draw_artist(artist)
        images.append(_frame_image(fig))
    palette = images[len(images) // 2].quantize(colors=255)
    frames_p = [im.quantize(palette=palette) for im in images]

    def save(tmp):
        frames_p[0].save(tmp, format="GIF", save_all=True, append_images=frames_p[1:],
                         duration=int(round(1000 / fps)), loop=0)
    atomic_write(path, save)
