"""Pictures: layouts in the paper's colours, archive heatmaps, metric curves.

Matplotlib only. No backend is forced: on a headless machine matplotlib falls back to Agg by
itself, and in Jupyter the inline backend keeps working. Files are written with ``savefig``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.colors import to_rgb

from nca_qd.io import atomic_write_bytes


def layout_rgb(layout: np.ndarray, tiles: str, palette: Mapping[str, str]) -> np.ndarray:
    """``[h, w]`` tile indices -> ``[h, w, 3]`` float RGB image using ``palette`` (char -> colour)."""
    colours = np.array([to_rgb(palette[ch]) for ch in tiles])
    return colours[np.asarray(layout)]


def draw_layout(ax, layout: np.ndarray, tiles: str, palette: Mapping[str, str], title: str = "") -> None:
    """Draw one layout on ``ax`` with thin grid lines between tiles."""
    img = layout_rgb(layout, tiles, palette)
    h, w = img.shape[:2]
    ax.imshow(img, interpolation="nearest")
    if max(h, w) <= 70:
        ax.set_xticks(np.arange(-0.5, w, 1), minor=True)
        ax.set_yticks(np.arange(-0.5, h, 1), minor=True)
        ax.grid(which="minor", color="#b0b0b0", linewidth=0.3)
    ax.tick_params(which="both", bottom=False, left=False, labelbottom=False, labelleft=False)
    if title:
        ax.set_title(title, fontsize=9)


def save_figure(fig, path: str | os.PathLike, dpi: int = 120) -> None:
    """Save a figure as PNG atomically and close it."""
    import io as _io

    buf = _io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())


def render_layouts(
    path: str | os.PathLike,
    layouts: Sequence[np.ndarray],
    tiles: str,
    palette: Mapping[str, str],
    titles: Sequence[str] | None = None,
    tile_inches: float = 0.12,
) -> None:
    """Render layouts side by side into one PNG (e.g. unrepaired | repaired)."""
    n = len(layouts)
    titles = list(titles) if titles is not None else [""] * n
    hmax = max(l.shape[0] for l in layouts)
    wsum = sum(l.shape[1] for l in layouts)
    scale = max(tile_inches, 3.0 / hmax)
    fig, axes = plt.subplots(
        1, n, figsize=(max(3.0, wsum * scale + n * 0.3), hmax * scale + 0.5), squeeze=False
    )
    import textwrap

    for ax, lay, title in zip(axes[0], layouts, titles):
        width = max(20, int(lay.shape[1] * scale * 9))  # ~9 title characters per inch
        draw_layout(ax, lay, tiles, palette, "\n".join(textwrap.wrap(title, width)))
    save_figure(fig, path)


def archive_heatmap(path, objective: np.ndarray, cells, ranges, names, title: str = "") -> None:
    """Heatmap of an archive's objective over its 2-D grid (empty cells white)."""
    grid = np.asarray(objective, dtype=float).reshape(tuple(cells))
    grid = np.where(np.isfinite(grid), grid, np.nan)
    fig, ax = plt.subplots(figsize=(6, 4.5))
    (x0, x1), (y0, y1) = ranges[0], ranges[1]
    im = ax.imshow(
        grid.T,
        origin="lower",
        aspect="auto",
        extent=(x0, x1, y0, y1),
        cmap="viridis",
        interpolation="nearest",
    )
    ax.set_xlabel(names[0])
    ax.set_ylabel(names[1])
    fig.colorbar(im, ax=ax, label="objective")
    filled = np.isfinite(grid).mean() * 100
    ax.set_title(f"{title}  coverage {filled:.1f} %", fontsize=9)
    save_figure(fig, path)


def metric_curves(path, metrics_csv) -> None:
    """QD-score and coverage of the result archive against evaluations, from ``metrics.csv``."""
    import csv

    with open(metrics_csv) as fh:
        rows = list(csv.DictReader(fh))
    if not rows:
        return
    evals = [float(r["evaluations"]) for r in rows]
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.2))
    for ax, key, label in zip(
        axes, ("qd_score", "coverage", "best_objective"), ("QD-score", "coverage", "best objective")
    ):
        ax.plot(evals, [float(r[key]) for r in rows])
        ax.set_xlabel("evaluations")
        ax.set_title(label, fontsize=9)
        ax.grid(alpha=0.3)
    save_figure(fig, path)
