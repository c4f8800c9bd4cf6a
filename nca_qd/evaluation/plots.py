"""The evaluation's figures: throughput curves (:func:`plot_curves`), tile-usage heatmaps
(:func:`plot_tile_usage`), the more-sizes figure (:func:`plot_sizes`) and tasks over time
(:func:`plot_tasks`). One colour per layout in every figure; the screen's lines are dashed,
RHCR's solid, and each legend names the simulator.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from nca_qd.evaluation.records import finite, parse_size
from nca_qd.sim.rhcr import planner_title


def _style(labels: Sequence[str]) -> dict[str, Any]:
    """A fixed colour per layout label: NCA greens/blues, human grey, tiling orange."""
    nca = ["#2a9d3a", "#1f5fbf", "#7b3fb5", "#17a2a2", "#8c564b", "#bcbd22"]
    colours, i = {}, 0
    for lab in labels:
        if lab.startswith("human"):
            colours[lab] = "#555555"
        elif lab.startswith("tiling"):
            colours[lab] = "#e67e22"
        else:
            colours[lab] = nca[i % len(nca)]
            i += 1
    return colours


def _legend_note(ax) -> None:
    ax.legend(fontsize=7, loc="best")
    ax.grid(alpha=0.3)


def _simulators(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """The simulators of ``rows`` in legend order: the exact planner's label (``rhcr``,
    ``pibt``), then the screen."""
    present = {r["simulator"] for r in rows}
    return sorted(s for s in present if s != "screen") + (["screen"] if "screen" in present else [])


def plot_curves(
    path: str | Path,
    rows: Sequence[Mapping[str, Any]],
    x: str,
    title: str,
    xlabel: str,
    y: str = "throughput_mean",
    ylabel: str = "throughput",
    band: tuple[str, str] | None = ("ci95_low", "ci95_high"),
) -> None:
    """Lines per (layout, simulator): screen dashed with a shaded band, RHCR solid with
    markers and error bars; the legend names the simulator."""
    import matplotlib.pyplot as plt

    from nca_qd.viz import save_figure

    labels = list(dict.fromkeys(r["layout"] for r in rows))
    colours = _style(labels)
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for lab in labels:
        for sim in _simulators(rows):
            pts = sorted(
                (r for r in rows if r["layout"] == lab and r["simulator"] == sim), key=lambda r: r[x]
            )
            pts = [r for r in pts if finite(r.get(y))]
            if not pts:
                continue
            xs = np.array([r[x] for r in pts], dtype=float)
            ys = np.array([r[y] for r in pts], dtype=float)
            c = colours[lab]
            if sim == "screen":
                ax.plot(xs, ys, "--", color=c, marker="o", mfc="none", ms=4, label=f"{lab} (screen)")
            else:
                ax.plot(xs, ys, "-", color=c, marker="s", ms=5, label=f"{lab} ({planner_title(sim)})")
            if band is not None:
                lo = np.array(
                    [r.get(band[0]) if finite(r.get(band[0])) else np.nan for r in pts], dtype=float
                )
                hi = np.array(
                    [r.get(band[1]) if finite(r.get(band[1])) else np.nan for r in pts], dtype=float
                )
                if sim == "screen" and len(xs) > 1:
                    ax.fill_between(xs, lo, hi, color=c, alpha=0.15, linewidth=0)
                else:
                    ok = np.isfinite(lo) & np.isfinite(hi)
                    if ok.any():
                        ax.errorbar(
                            xs[ok],
                            ys[ok],
                            yerr=[ys[ok] - lo[ok], hi[ok] - ys[ok]],
                            fmt="none",
                            ecolor=c,
                            capsize=3,
                        )
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    screened = "screen" in _simulators(rows)
    note = "screen = JAX screening approximation (~25 % below RHCR); " if screened else ""
    ax.set_title(f"{title}\n{note}band/bars: 95 % CI", fontsize=8)
    _legend_note(ax)
    save_figure(fig, path)


def plot_tile_usage(
    path: str | Path, panels: Sequence[tuple[str, np.ndarray, np.ndarray]], label: str = "visits per run"
) -> None:
    """Tile-usage heatmaps side by side: (title, mean visits [H, W], traversable [H, W]);
    ``label`` names what the colour measures."""
    import matplotlib.pyplot as plt

    from nca_qd.viz import save_figure

    n = len(panels)
    h, w = panels[0][1].shape
    scale = min(0.08, 4.0 / max(h, w)) if max(h, w) > 40 else 0.12
    fig, axes = plt.subplots(1, n, figsize=(max(3.5, n * (w * scale + 1.2)), h * scale + 1.0), squeeze=False)
    for ax, (title, visits, trav) in zip(axes[0], panels):
        img = np.where(trav, visits, np.nan).astype(float)
        cmap = plt.get_cmap("viridis").with_extremes(bad="#d0d0d0")
        im = ax.imshow(img, cmap=cmap, interpolation="nearest")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(title, fontsize=8)
        fig.colorbar(im, ax=ax, fraction=0.046, pad=0.02, label=label)
    save_figure(fig, path)


def plot_sizes(path: str | Path, rows: Sequence[Mapping[str, Any]]) -> None:
    """The "more sizes" figure: best mean throughput over the agent counts tried at each
    size, and the agent count where it peaks (the paper's "maximum scalability")."""
    import matplotlib.pyplot as plt

    from nca_qd.viz import save_figure

    sizes = sorted({r["size"] for r in rows}, key=lambda s: math.prod(parse_size(s)))
    pos = {s: i for i, s in enumerate(sizes)}
    labels = list(dict.fromkeys(r["layout"] for r in rows))
    colours = _style(labels)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for lab in labels:
        for sim in _simulators(rows):
            pts = sorted(
                (
                    r
                    for r in rows
                    if r["layout"] == lab and r["simulator"] == sim and finite(r.get("max_throughput_mean"))
                ),
                key=lambda r: pos[r["size"]],
            )
            if not pts:
                continue
            xs = [pos[r["size"]] for r in pts]
            style = dict(ls="--", marker="o", mfc="none") if sim == "screen" else dict(ls="-", marker="s")
            name = f"{lab} ({'screen' if sim == 'screen' else planner_title(sim)})"
            axes[0].plot(xs, [r["max_throughput_mean"] for r in pts], color=colours[lab], label=name, **style)
            err = [
                (x, r["max_throughput_mean"], r["max_throughput_se"])
                for x, r in zip(xs, pts)
                if finite(r.get("max_throughput_se"))
            ]
            if err:
                axes[0].errorbar(
                    [a for a, _, _ in err],
                    [b for _, b, _ in err],
                    yerr=[c for _, _, c in err],
                    fmt="none",
                    ecolor=colours[lab],
                    capsize=3,
                )
            axes[1].plot(xs, [r["agents_at_max"] for r in pts], color=colours[lab], label=name, **style)
    for ax, yl in zip(axes, ("max mean throughput (bars: s.e.)", "agents at the max (max scalability)")):
        ax.set_xticks(range(len(sizes)))
        ax.set_xticklabels(sizes, rotation=30, fontsize=8)
        ax.set_xlabel("map size")
        ax.set_ylabel(yl)
        _legend_note(ax)
    fig.suptitle("Scaling to more sizes (screen = JAX screening approximation)", fontsize=9)
    save_figure(fig, path)


def plot_tasks(
    path: str | Path,
    series: Sequence[tuple[str, str, np.ndarray, np.ndarray, np.ndarray]],
    smooth: int,
    title: str,
) -> None:
    """Tasks finished per timestep: (layout, simulator, mean, low, high), moving average over
    ``smooth`` steps for the picture (the CSV keeps every step)."""
    import matplotlib.pyplot as plt

    from nca_qd.viz import save_figure

    def ma(a: np.ndarray) -> np.ndarray:
        if smooth <= 1 or a.size < smooth:
            return a
        return np.convolve(np.nan_to_num(a), np.ones(smooth) / smooth, mode="valid")

    colours = _style(list(dict.fromkeys(s[0] for s in series)))
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for lab, sim, m, lo, hi in series:
        t = np.arange(1, m.size + 1)[(smooth - 1 if smooth > 1 and m.size >= smooth else 0) :]
        ls = "--" if sim == "screen" else "-"
        ax.plot(
            t,
            ma(m),
            ls,
            color=colours[lab],
            lw=1,
            label=f"{lab} ({'screen' if sim == 'screen' else planner_title(sim)})",
        )
        if np.isfinite(lo).any():
            ax.fill_between(t, ma(lo), ma(hi), color=colours[lab], alpha=0.15, linewidth=0)
    ax.set_xlabel("timestep")
    ax.set_ylabel(
        f"tasks finished per step ({smooth}-step moving average)" if smooth > 1 else "tasks finished per step"
    )
    ax.set_title(title + "\nband: 95 % CI over runs; a congested run adds zeros after it stops", fontsize=8)
    _legend_note(ax)
    save_figure(fig, path)
