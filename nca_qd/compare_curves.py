"""Throughput against the number of agents over arms: the paper's figure 3 (its S and S_eval
panels) from each arm's evaluation, with the exact verdicts on the curve's points.

An evaluation's curves (``<run>/evaluation/throughput_vs_agents_{train,eval}.csv``, written by
``experiments.evaluate``) hold, per layout and agent count, the screened runs and, at the counts
that got them, exact RHCR runs. The screen alone cannot carry a curve's verdict: it reads about
a fifth below RHCR's throughput and its congestion verdicts disagree with RHCR's near a
layout's limit, either way (results/warehouse_even_qd/README.md). So the picture
draws the screened curves as lines and the exact points as markers, and the table lists every
exact point beside the screened figure at the same count. The paper reports the figure as a
plot only: there are no numbers to set beside these.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from nca_qd.compare_evaluation import num, read_csv

CURVE = "evaluation/throughput_vs_agents_{which}.csv"
PANELS = (("train", "S"), ("eval", "S_eval"))
# Layout kinds drawn, in this order; the human layouts are the same in every arm: drawn once.
KINDS = ("nca", "tiling", "human")


def read_curves(runs: Sequence[tuple[Path, str, int]]) -> list[dict[str, Any]]:
    """Every curve row of the runs (``(run_dir, algorithm label, seed)``) that hold one, with
    ``algorithm`` and ``seed`` added; and, as exact points of the same curves, the main
    comparison's exact runs at N_a and N_a_eval (``summary.csv``: the best generator, its
    tiling, the human layout) where the curve has none at that count."""
    out = []
    for run_dir, algorithm, seed in runs:
        summary = Path(run_dir) / "evaluation" / "summary.csv"
        main = read_csv(summary) if summary.is_file() else []
        for which, _ in PANELS:
            path = Path(run_dir) / CURVE.format(which=which)
            if not path.is_file():
                continue
            rows = [{**r, "which": which} for r in read_csv(path)]
            have = {(r["kind"], int(r["n_agents"]), r["simulator"]) for r in rows}
            first: set[str] = set()
            for r in main:
                if r["which"] != which or r["simulator"] != "rhcr" or r["kind"] in first:
                    continue
                first.add(r["kind"])  # the best generator's rows come first
                if (r["kind"], int(r["n_agents"]), "rhcr") not in have:
                    rows.append(dict(r))
            out += [{**r, "algorithm": algorithm, "seed": seed} for r in rows]
    return out


def _label(r: Mapping[str, Any]) -> str:
    return "human" if r["kind"] == "human" else f"{r['kind']}, {r['algorithm']} s{r['seed']}"


def _series(rows: Sequence[Mapping[str, Any]], which: str) -> dict[tuple[str, str], list[Mapping[str, Any]]]:
    """(label, simulator) -> rows sorted by agents, for one panel; human from its first arm."""
    series: dict[tuple[str, str], list[Mapping[str, Any]]] = {}
    human_from = None
    for r in rows:
        if r["which"] != which or r["kind"] not in KINDS:
            continue
        if r["kind"] == "human":
            arm = (r["algorithm"], r["seed"])
            human_from = human_from or arm
            if arm != human_from:
                continue
        series.setdefault((_label(r), r["simulator"]), []).append(r)
    for v in series.values():
        v.sort(key=lambda r: int(r["n_agents"]))
    return series


def curves_markdown(rows: Sequence[Mapping[str, Any]], picture: str) -> str:
    """The section: the picture's link and a table of every exact point ('' without curves)."""
    if not rows:
        return ""
    lines = [
        "",
        "## Throughput against agents (the paper's figure 3)",
        "",
        f"![throughput against agents]({picture}): lines are screened runs (mean over all runs, "
        "95 % interval), markers exact RHCR runs. The paper shows this figure as a plot only.",
        "",
        "| Size | Layout | Agents | exact RHCR: runs, success, throughput (all runs) | "
        "screen: runs, success, throughput (all runs) |",
        "|---|---|---|---|---|",
    ]
    for which, size in PANELS:
        series = _series(rows, which)
        for (label, sim), pts in series.items():
            if sim != "rhcr":
                continue
            screened = {int(r["n_agents"]): r for r in series.get((label, "screen"), [])}
            for r in pts:
                n = int(r["n_agents"])
                s = screened.get(n)
                lines.append(
                    f"| {size} ({r['size']}) | {label} | {n} | {_point(r)} | {_point(s) if s else '—'} |"
                )
    return "\n".join(lines) + "\n"


def _point(r: Mapping[str, Any]) -> str:
    m, se = num(r["throughput_mean"]), num(r["throughput_se"])
    spread = "" if math.isnan(se) else f" ± {se:.2f}"
    return f"{r['runs']}, {100 * num(r['success_rate']):.0f} %, {m:.2f}{spread}"


def plot_curves(path: Path, rows: Sequence[Mapping[str, Any]]) -> None:
    """Two panels (S, S_eval): each layout's screened curve with its 95 % interval, its exact
    points as markers with their 95 % intervals, one colour per layout."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from nca_qd.viz import save_figure

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    for ax, (which, size) in zip(axes, PANELS):
        series = _series(rows, which)
        colours: dict[str, Any] = {}
        for (label, sim), pts in sorted(series.items(), key=lambda kv: kv[0][1] != "screen"):
            x = [int(r["n_agents"]) for r in pts]
            y = [num(r["throughput_mean"]) for r in pts]
            lo = [num(r["ci95_low"]) for r in pts]
            hi = [num(r["ci95_high"]) for r in pts]
            style = {"color": colours[label]} if label in colours else {}
            if sim == "screen":
                line = ax.plot(x, y, label=f"{label} (screen)", lw=1.2, **style)[0]
                colours.setdefault(label, line.get_color())
                ax.fill_between(x, [max(v, 0.0) for v in lo], hi, alpha=0.15, color=line.get_color())
            else:
                # the interval's lower end clipped at 0, as the screened band is (no negative throughput)
                down = [max(a - max(b, 0.0), 0.0) for a, b in zip(y, lo)]
                err = [down, [max(b - a, 0.0) for a, b in zip(y, hi)]]
                bar = ax.errorbar(x, y, yerr=err, fmt="o", ms=5, capsize=3, label=f"{label} (exact)", **style)
                colours.setdefault(label, bar[0].get_color())
        ax.set_title(f"{size}: throughput against agents", fontsize=9)
        ax.set_xlabel("agents")
        ax.set_ylabel("throughput (tasks / step)")
        ax.grid(alpha=0.3)
        if series:
            ax.legend(fontsize=6)
    save_figure(fig, path)
