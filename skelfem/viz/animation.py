"""motion.gif: an animated run in time, axes fixed over the motion.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from ..io.files import atomic_write
from .plots import plot_deformed



def write_motion_gif(path: Path, frames: list, title: str = "", fps: int = 20) -> None:
    """An animated GIF of 2D snapshots [(t, Snapshot)], axes fixed over the motion (Pillow writer)."""
    from matplotlib.figure import Figure
    from matplotlib.animation import FuncAnimation, PillowWriter

    allpts = np.vstack([np.vstack([s.x + s.u, s.x]) for _, s in frames])
    lo, hi = allpts.min(axis=0), allpts.max(axis=0)
    pad = 0.06 * (hi - lo).max()
    fig = Figure(figsize=(5, 5.5), dpi=80)
    ax = fig.subplots()

    def draw(i):
        ax.clear()
        t, snap = frames[i]
        plot_deformed(None, snap, f"{title}  t = {t:.4g} s", ax=ax)
        if ax.get_legend() is not None:
            ax.get_legend().remove()
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
        return []

    anim = FuncAnimation(fig, draw, frames=len(frames), blit=False)
    atomic_write(path, lambda tmp: anim.save(tmp, writer=PillowWriter(fps=fps)))
