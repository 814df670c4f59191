"""Pictures of a calibration: the fit against the data per column, the residuals, the parameter intervals.

Each ``draw_*`` draws on a matplotlib Figure it is given (no pyplot, no backend
chosen); ``calibration_figures`` writes the three PNGs of ``skelfem calibrate``.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..io.files import atomic_write

DATA_COLOR, MODEL_COLOR, HOLD_COLOR = "#333333", "#1f77b4", "#d62728"


def _grid(fig, n: int):
    cols = min(3, n)
    rows = math.ceil(n / cols)
    axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False)).ravel()
    for ax in axes[n:]:
        ax.set_visible(False)
    return axes[:n]


def draw_fit(fig, cal) -> None:
    """Model (line) against data (points, +-sigma) per measurement column, row by row."""
    from matplotlib.ticker import MaxNLocator
    data = cal.data
    rows = np.arange(1, data.rows + 1)
    for j, (ax, col) in enumerate(zip(_grid(fig, len(cal.columns)), cal.columns)):
        ax.plot(rows, cal.model_values[:, j], "-", color=MODEL_COLOR, lw=1.5, label="model")
        for mask, color, label in ((data.train, DATA_COLOR, "data"), (~data.train, HOLD_COLOR, "held out")):
            if mask.any():
                ax.errorbar(rows[mask], data.values[mask, j], yerr=data.sigma[j] if data.sigma_given[j] else None,
                            fmt="o", ms=3.5, color=color, lw=0.8, label=label)
        ax.set_title(col, fontsize=8)
        ax.set_xlabel("row", fontsize=8)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.tick_params(labelsize=7)
        if j == 0:
            ax.legend(fontsize=7)


def draw_residuals(fig, cal) -> None:
    """Weighted residuals (model - data) / sigma per column, row by row."""
    data = cal.data
    R = (cal.model_values - data.values) / data.sigma
    ax = fig.subplots()
    rows = np.arange(1, data.rows + 1)
    for j, col in enumerate(cal.columns):
        ax.plot(rows, R[:, j], "o-", ms=3, lw=0.8, label=col)
    if (~data.train).any():
        for i in np.flatnonzero(~data.train):
            ax.axvspan(i + 0.5, i + 1.5, color=HOLD_COLOR, alpha=0.08, lw=0)
    ax.axhline(0.0, color="k", lw=0.6)
    ax.set_xlabel("row (shaded: held out)" if (~data.train).any() else "row")
    ax.set_ylabel("(model - data) / sigma")
    ax.legend(fontsize=7, ncol=2)
    ax.set_title(f"residuals; cost {cal.cost:.3g}, {cal.iterations} iterations", fontsize=9)


def draw_parameters(fig, cal) -> None:
    """Each estimate relative to its start, with its 95 % interval (none: unidentifiable)."""
    ax = fig.subplots()
    n = len(cal.keys)
    y = np.arange(n)[::-1]
    for i, key in enumerate(cal.keys):
        ref = abs(cal.initial[i]) if cal.initial[i] != 0 else 1.0
        v = cal.values[i] / ref
        if math.isfinite(cal.std[i]):
            lo, hi = cal.ci95[i] / ref
            ax.plot([lo, hi], [y[i], y[i]], "-", color=MODEL_COLOR, lw=3, alpha=0.5)
            ax.plot(v, y[i], "o", color=MODEL_COLOR)
        else:
            ax.plot(v, y[i], "x", color=HOLD_COLOR, ms=8, mew=2)
    ax.set_yticks(y)
    ax.set_yticklabels([k + (" (offset)" if k in cal.offsets else "") for k in cal.keys], fontsize=7)
    ax.axvline(1.0, color="k", lw=0.6, ls=":")
    ax.set_xlabel("estimate / |start| (offsets: / 1), 95 % interval; x: unidentifiable")
    ax.set_title("parameters", fontsize=9)


def calibration_figures(folder: Path, cal, title: str = "") -> list:
    """fit.png, residuals.png and parameters.png in folder; returns their paths."""
    from matplotlib.figure import Figure
    out = []
    n = len(cal.columns)
    for name, draw, size in (("fit.png", draw_fit, (3.4 * min(3, n), 2.8 * math.ceil(n / 3) + 0.4)),
                             ("residuals.png", draw_residuals, (7, 4)),
                             ("parameters.png", draw_parameters, (7, 1.2 + 0.35 * len(cal.keys)))):
        fig = Figure(figsize=size, dpi=110)
        draw(fig, cal)
        if title:
            fig.suptitle(title, fontsize=10)
        fig.tight_layout()
        path = Path(folder) / name
        atomic_write(path, lambda tmp, fig=fig: fig.savefig(tmp, format="png"))
        out.append(path)
    return out
