"""Every file the evaluation writes under its output folder.

:func:`write_outputs` writes the layouts (JSON and pictures), every run (runs.csv), the agent
curves, tasks over time and tile usage (:func:`_write_detail`), the more-sizes curve and the
summary (CSV and Markdown). :data:`OUTPUT_PATTERNS` names these files, so that
:func:`remove_stale_outputs` can delete the ones an earlier evaluation left in the folder.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

import numpy as np

from nca_qd.evaluation.plan import Plan
from nca_qd.evaluation.plots import plot_curves, plot_sizes, plot_tasks, plot_tile_usage
from nca_qd.evaluation.records import EvalLayout, Request, Results
from nca_qd.evaluation.stats import request_runs, run_stats
from nca_qd.evaluation.tables import (
    LAYOUT_COLUMNS,
    STAT_COLUMNS,
    layout_cols,
    layout_record,
    peaks,
    summary_markdown,
    summary_rows,
    write_csv,
)
from nca_qd.sim.rhcr import planner_title

log = logging.getLogger("nca_qd.evaluate")


# Files this command writes (patterns under ``out``); one of them older than this evaluation's
# writing is left from an earlier evaluation into the same folder (e.g. a curve turned off).
OUTPUT_PATTERNS = (
    "summary.csv",
    "summary.md",
    "runs.csv",
    "layouts.csv",
    "layouts_*.png",
    "selection.csv",
    "selection/*.json",
    "layouts/*.json",
    "throughput_vs_agents_*.csv",
    "throughput_vs_agents_*.png",
    "tasks_over_time_*.csv",
    "tasks_over_time_*.csv.gz",
    "tasks_over_time_*.png",
    "tile_usage_*.csv",
    "tile_usage_*.csv.gz",
    "tile_usage_*.png",
    "scaling_sizes.csv",
    "scaling_sizes.png",
    "scaling_sizes_grid.csv",
)


def remove_stale_outputs(out: Path, before: float) -> list[Path]:
    """Delete this command's output files in ``out`` last written before ``before`` (epoch
    seconds): leftovers of an earlier evaluation that this one did not rewrite."""
    stale = [
        p for pat in OUTPUT_PATTERNS for p in out.glob(pat) if p.is_file() and p.stat().st_mtime < before
    ]
    for p in stale:
        log.info("removing %s (left from an earlier evaluation)", p)
        p.unlink()
    return stale


def write_outputs(
    out: Path,
    plan: Plan,
    domain,
    layouts: dict[str, EvalLayout],
    requests: list[Request],
    results: Results,
):
    """Every CSV and PNG, the summary table (CSV and Markdown); returns (rows, markdown)."""
    from nca_qd.io import atomic_write_text

    tiles, T, name = domain.layout_tiles, plan.T, plan.name
    exact = plan.exact.planner.get("planner", "rhcr")

    def lab(sim: str) -> str:  # the runs' internal "rhcr" means exact, by whichever planner
        return exact if sim == "rhcr" else sim

    _write_layouts(out, name, layouts, tiles, domain.palette)
    _write_runs(out, layouts, results, lab)
    stat_rows: dict[str, list[dict[str, Any]]] = {}
    for r in requests:
        for sim, outs in request_runs(results, r).items():
            stat_rows.setdefault(r.purpose, []).append(
                {
                    **layout_cols(layouts[r.layout]),
                    "n_agents": r.n_agents,
                    "simulator": lab(sim),
                    **run_stats(outs),
                }
            )
    for which in ("train", "eval"):
        _write_sweep(out, which, name, stat_rows.get(f"sweep_{which}", []), T)
        if plan.detail:
            _write_detail(out, which, name, layouts, requests, results, T, plan.tasks_smooth, tiles, lab)
    _write_sizes(out, stat_rows.get("sizes", []))
    summary = summary_rows(name, layouts, requests, results, plan)
    for row in summary:
        row["simulator"] = lab(row["simulator"])
    write_csv(out / "summary.csv", summary, list(summary[0]) if summary else ["layout"])
    md = summary_markdown(name, summary, T, exact)
    atomic_write_text(out / "summary.md", md)
    return summary, md


_CURVE_COLUMNS = LAYOUT_COLUMNS + ["n_agents", "simulator"] + STAT_COLUMNS


def _write_layouts(out: Path, name: str, layouts: dict[str, EvalLayout], tiles, palette) -> None:
    """Each layout as a map file (and its unrepaired version), layouts.csv, a picture per size."""
    from nca_qd.io import MapFile, array_to_rows, save_map
    from nca_qd.viz import render_layouts

    lay_rows = [layout_record(l, name, tiles) for l in layouts.values()]
    for lay in layouts.values():
        stem = lay.key.replace("@", "_")
        if lay.layout is not None:
            save_map(
                out / "layouts" / f"{stem}.json",
                MapFile(f"{stem}", array_to_rows(lay.layout, tiles), {"kind": lay.kind, "cell": lay.cell}),
            )
        if lay.unrepaired is not None:
            save_map(
                out / "layouts" / f"{stem}_unrepaired.json",
                MapFile(f"{stem}_unrepaired", array_to_rows(lay.unrepaired, tiles)),
            )
    write_csv(out / "layouts.csv", lay_rows, list(lay_rows[0]))
    for size in dict.fromkeys(l.size for l in layouts.values()):
        shown = [l for l in layouts.values() if l.size == size and l.layout is not None]
        if shown:
            render_layouts(
                out / f"layouts_{size}.png",
                [l.layout for l in shown],
                tiles,
                palette,
                [f"{l.label} {l.size}" for l in shown],
            )


def _write_runs(out: Path, layouts: dict[str, EvalLayout], results: Results, lab) -> None:
    """runs.csv: every run of every layout, agent count and simulator (``lab``: its label)."""
    run_rows = []
    for (key, n, sim), outs in results.items():
        for o in outs:
            run_rows.append(
                {
                    **layout_cols(layouts[key]),
                    "n_agents": n,
                    "simulator": lab(sim),
                    "seed": o.seed,
                    "throughput": o.throughput,
                    "success": o.success,
                    "stop_time": o.stop_time,
                    "timed_out": o.timed_out,
                    "seconds": o.seconds,
                    "error": o.error,
                }
            )
    write_csv(
        out / "runs.csv",
        run_rows,
        LAYOUT_COLUMNS
        + [
            "n_agents",
            "simulator",
            "seed",
            "throughput",
            "success",
            "stop_time",
            "timed_out",
            "seconds",
            "error",
        ],
    )


def _write_sweep(out: Path, which: str, name: str, rows: list[dict[str, Any]], T: int) -> None:
    """Throughput against agents at the training (S) or evaluation (S_eval) size: CSV and PNG."""
    if not rows:
        return
    stem = f"throughput_vs_agents_{which}"
    write_csv(out / f"{stem}.csv", rows, _CURVE_COLUMNS)
    plot_curves(
        out / f"{stem}.png",
        rows,
        "n_agents",
        f"{name}: throughput vs agents at {rows[0]['size']} (T={T})",
        "agents",
    )


def _write_sizes(out: Path, size_rows: list[dict[str, Any]]) -> None:
    """Throughput over map sizes: every point, each layout's peak per size, its picture."""
    if not size_rows:
        return
    write_csv(out / "scaling_sizes_grid.csv", size_rows, _CURVE_COLUMNS)
    peak = peaks(size_rows)
    write_csv(
        out / "scaling_sizes.csv",
        peak,
        [
            "layout",
            "kind",
            "cell",
            "size",
            "simulator",
            "agents_tried",
            "max_throughput_mean",
            "max_throughput_se",
            "agents_at_max",
            "success_rate_at_max",
        ],
    )
    plot_sizes(out / "scaling_sizes.png", peak)


def _write_detail(
    out: Path, which: str, scenario: str, layouts, requests, results, T: int, smooth: int, tiles: str, lab
) -> None:
    """Tasks over time and tile-usage heatmaps of the main comparison's runs at one size."""
    from nca_qd.io import array_to_rows
    from nca_qd.sim.scenario import build_scenario

    reqs = [r for r in requests if r.purpose == f"main_{which}"]
    series, task_rows, panels, heat_rows = [], [], [], []
    for r in reqs:
        lay = layouts[r.layout]
        runs = request_runs(results, r)
        for sim, outs in runs.items():
            tps = [o.tasks_per_step for o in outs if o.completed and o.tasks_per_step is not None]
            if tps:
                mat = np.zeros((len(tps), T))
                for i, tp in enumerate(tps):
                    mat[i, : min(T, tp.size)] = tp[:T]
                m = mat.mean(0)
                if len(tps) > 1:
                    from scipy import stats

                    h = stats.t.ppf(0.975, len(tps) - 1) * mat.std(0, ddof=1) / math.sqrt(len(tps))
                    lo, hi = m - h, m + h
                else:
                    lo = hi = np.full(T, np.nan)
                series.append((lay.label, lab(sim), m, lo, hi))
                task_rows += [
                    {
                        "layout": lay.label,
                        "kind": lay.kind,
                        "size": lay.size,
                        "n_agents": r.n_agents,
                        "simulator": lab(sim),
                        "runs": len(tps),
                        "t": t + 1,
                        "tasks_mean": m[t],
                        "ci95_low": lo[t],
                        "ci95_high": hi[t],
                    }
                    for t in range(T)
                ]
        # heatmap: RHCR runs where there are any, else the screen's
        for sim in ("rhcr", "screen"):
            vis = [o.tile_visits for o in runs.get(sim, []) if o.completed and o.tile_visits is not None]
            if vis:
                mean = np.mean(np.stack(vis), axis=0)
                trav = build_scenario(array_to_rows(lay.layout, tiles), scenario).traversable
                panels.append(
                    (
                        f"{lay.label} ({planner_title(lab(sim)) if sim == 'rhcr' else 'screen'}, "
                        f"{len(vis)} run(s), N_a={r.n_agents})",
                        mean,
                        trav,
                    )
                )
                heat_rows += [
                    {
                        "layout": lay.label,
                        "kind": lay.kind,
                        "size": lay.size,
                        "n_agents": r.n_agents,
                        "simulator": lab(sim),
                        "runs": len(vis),
                        "row": i,
                        "col": j,
                        "tile": tiles[lay.layout[i, j]],
                        "visits_mean": float(mean[i, j]),
                    }
                    for i in range(mean.shape[0])
                    for j in range(mean.shape[1])
                ]
                break
    if series:
        write_csv(
            out / f"tasks_over_time_{which}.csv.gz",
            task_rows,
            [
                "layout",
                "kind",
                "size",
                "n_agents",
                "simulator",
                "runs",
                "t",
                "tasks_mean",
                "ci95_low",
                "ci95_high",
            ],
        )
        plot_tasks(
            out / f"tasks_over_time_{which}.png",
            series,
            smooth,
            f"{scenario}: tasks finished over time at {layouts[reqs[0].layout].size}",
        )
    if panels:
        write_csv(
            out / f"tile_usage_{which}.csv.gz",
            heat_rows,
            ["layout", "kind", "size", "n_agents", "simulator", "runs", "row", "col", "tile", "visits_mean"],
        )
        plot_tile_usage(out / f"tile_usage_{which}.png", panels)
