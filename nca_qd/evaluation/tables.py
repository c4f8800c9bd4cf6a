"""The evaluation's tables: their rows and how they are written.

CSV (:func:`write_csv`: NaN and None as empty cells) and Markdown (:func:`markdown_table`);
the columns shared by the tables (:data:`LAYOUT_COLUMNS`, :data:`STAT_COLUMNS`); the rows of
layouts.csv (:func:`layout_record`), of the more-sizes table (:func:`peaks`) and of the main
comparison (:func:`summary_rows`, as Markdown :func:`summary_markdown`).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from nca_qd.errors import NcaQdError
from nca_qd.evaluation.plan import Plan
from nca_qd.evaluation.records import EvalLayout, finite, format_value
from nca_qd.evaluation.stats import request_runs, run_stats
from nca_qd.sim.rhcr import planner_title


def write_csv(
    path: str | Path, rows: Sequence[Mapping[str, Any]], columns: Sequence[str], digits: int = 6
) -> None:
    """Rows as CSV (atomic); NaN and None are empty cells. A path ending in ``.gz`` is written
    gzip-compressed (the same bytes for the same rows: no time stamp), as pandas, R and
    ``zcat`` read it: the per-step and per-tile tables of a 101x102 evaluation are megabytes of
    repeated labels as text, a tenth of that compressed."""
    import gzip

    from nca_qd.io import atomic_write_bytes

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for row in rows:
        w.writerow([format_value(row.get(c), digits) for c in columns])
    data = buf.getvalue().encode()
    if str(path).endswith(".gz"):
        data = gzip.compress(data, compresslevel=9, mtime=0)
    atomic_write_bytes(path, data)


def markdown_table(rows: Sequence[Mapping[str, Any]], columns: Sequence[tuple[str, str]]) -> str:
    """A Markdown table of ``rows``; ``columns`` are (key, header) pairs, values pre-formatted."""
    head = "| " + " | ".join(h for _, h in columns) + " |"
    sep = "|" + "|".join("---" for _ in columns) + "|"
    body = ["| " + " | ".join(str(r.get(k, "")) for k, _ in columns) + " |" for r in rows]
    return "\n".join([head, sep, *body]) + "\n"


STAT_COLUMNS = [
    "runs",
    "completed",
    "timed_out",
    "errors",
    "success_rate",
    "throughput_mean",
    "throughput_se",
    "ci95_low",
    "ci95_high",
    "throughput_success_mean",
    "throughput_success_se",
    "sim_seconds_mean",
]


LAYOUT_COLUMNS = ["layout", "kind", "cell", "size", "which"]


def layout_cols(lay: EvalLayout) -> dict[str, Any]:
    return {"layout": lay.label, "kind": lay.kind, "cell": lay.cell, "size": lay.size, "which": lay.which}


def layout_record(lay: EvalLayout, scenario: str, tiles: str) -> dict[str, Any]:
    """One row of layouts.csv: generation and repair figures of one layout."""
    from nca_qd.io import array_to_rows
    from nca_qd.layouts import get_layout
    from nca_qd.sim.scenario import build_scenario

    rep = lay.repair
    trav = None
    if lay.layout is not None:
        try:
            trav = build_scenario(array_to_rows(lay.layout, tiles), scenario).n_traversable
        except NcaQdError:
            trav = None
    return {
        **layout_cols(lay),
        "nca_iters": lay.nca_iters,
        "gen_seconds": lay.gen_seconds,
        "repair_status": rep.status if rep is not None else "given",
        "repair_seconds": rep.seconds if rep is not None else None,
        "similarity": rep.similarity if rep is not None else None,
        "hamming": rep.hamming if rep is not None else None,
        "repair_error": rep.error if rep is not None else None,
        "n_traversable": trav,
        **placed_counts(lay, get_layout(scenario).gen_tiles),
        "file": f"layouts/{lay.key.replace('@', '_')}.json",
    }


# Readable names of the tiles a generator places, for the columns of layouts.csv.
TILE_NAMES = {"@": "shelves", "e": "endpoints"}


def placed_counts(lay: EvalLayout, tiles: str) -> dict[str, int | None]:
    """Per non-empty tile the generator places (``tiles``: its alphabet, a prefix of the
    layout's; a fixed frame's tiles are not counted): how many the NCA placed (``nca_*``, the
    unrepaired layout), how many the layout holds (``repaired_*``) and how many of the NCA's the
    repair kept (``kept_*``): how much of a layout is the generator's and how much the repair's
    (issue 55). Empty for layouts without an unrepaired version (the human ones)."""
    out: dict[str, int | None] = {}
    nca = None if lay.unrepaired is None else np.asarray(lay.unrepaired)
    fin = None if lay.layout is None else np.asarray(lay.layout)
    for i, ch in enumerate(tiles):
        if ch == ".":
            continue
        name = TILE_NAMES.get(ch, f"tile_{ch}")
        out[f"nca_{name}"] = None if nca is None else int((nca == i).sum())
        out[f"repaired_{name}"] = None if nca is None or fin is None else int((fin == i).sum())
        out[f"kept_{name}"] = None if nca is None or fin is None else int(((nca == i) & (fin == i)).sum())
    return out


def peaks(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per (layout, size, simulator): the best mean throughput and the agent count there."""
    groups: dict[tuple, list] = {}
    for r in rows:
        groups.setdefault((r["layout"], r["size"], r["simulator"]), []).append(r)
    out = []
    for (lab, size, sim), rs in groups.items():
        ok = [r for r in rs if finite(r["throughput_mean"])]
        best = max(ok, key=lambda r: r["throughput_mean"]) if ok else None
        out.append(
            {
                "layout": lab,
                "kind": rs[0]["kind"],
                "cell": rs[0]["cell"],
                "size": size,
                "simulator": sim,
                "agents_tried": " ".join(str(r["n_agents"]) for r in sorted(rs, key=lambda r: r["n_agents"])),
                "max_throughput_mean": best["throughput_mean"] if best else math.nan,
                "max_throughput_se": best["throughput_se"] if best else math.nan,
                "agents_at_max": best["n_agents"] if best else None,
                "success_rate_at_max": best["success_rate"] if best else math.nan,
            }
        )
    return out


def summary_rows(name: str, layouts, requests, results, plan: Plan) -> list[dict[str, Any]]:
    """The main comparison: every layout at S (N_a) and S_eval (N_a_eval), per simulator,
    with generation and repair figures; a layout without a repaired map gets one row."""
    rows = []
    for which, n in (("train", plan.n_train), ("eval", plan.n_eval)):
        reqs = {r.layout: r for r in requests if r.purpose == f"main_{which}"}
        for key, lay in layouts.items():
            if lay.which != which:
                continue
            rep = lay.repair
            base = {
                "domain": name,
                "size": lay.size,
                "which": which,
                "n_agents": n,
                "layout": lay.label,
                "kind": lay.kind,
                "cell": lay.cell,
                "gen_seconds": lay.gen_seconds,
                "repair_status": rep.status if rep is not None else "given",
                "repair_seconds": rep.seconds if rep is not None else None,
                "similarity": rep.similarity if rep is not None else None,
                "hamming": rep.hamming if rep is not None else None,
            }
            runs = request_runs(results, reqs[key]) if key in reqs else {}
            if not runs:
                rows.append({**base, "simulator": "", **{c: None for c in STAT_COLUMNS}})
            for sim, outs in runs.items():
                rows.append({**base, "simulator": sim, **run_stats(outs)})
    return rows


def summary_markdown(name: str, rows: Sequence[Mapping[str, Any]], T: int, planner: str = "rhcr") -> str:
    """The summary as a Markdown table (throughput of successful runs, as in the paper). The
    exact runs are labelled by their ``planner`` (``rhcr``, ``pibt``); the header says which is
    exact."""

    def pm(m, se):
        if not finite(m):
            return "N/A"
        return f"{m:.2f} ± {se:.2f}" if finite(se) else f"{m:.2f}"

    shown = []
    for r in rows:
        shown.append(
            {
                "size": f"{r['size']} ({'S' if r['which'] == 'train' else 'S_eval'})",
                "n": r["n_agents"],
                "layout": r["layout"],
                "sim": r["simulator"] or "-",
                "runs": "-"
                if r.get("runs") is None
                else f"{r['runs']}"
                + (f" ({r['timed_out']} timed out)" if r.get("timed_out") else "")
                + (f" ({r['errors']} failed)" if r.get("errors") else ""),
                "succ": ("-" if not finite(r.get("success_rate")) else f"{100 * r['success_rate']:.0f} %"),
                "thr": pm(r.get("throughput_success_mean"), r.get("throughput_success_se")),
                "thr_all": pm(r.get("throughput_mean"), r.get("throughput_se")),
                "gen": "-" if not finite(r.get("gen_seconds")) else f"{r['gen_seconds']:.3f}",
                "rep": "-" if not finite(r.get("repair_seconds")) else f"{r['repair_seconds']:.1f}",
                "delta": "-" if not finite(r.get("similarity")) else f"{r['similarity']:.3f}",
                "status": r["repair_status"],
            }
        )
    cols = [
        ("size", "size"),
        ("n", "N_a"),
        ("layout", "layout"),
        ("sim", "simulator"),
        ("runs", "runs"),
        ("succ", "success"),
        ("thr", "throughput (successful runs)"),
        ("thr_all", "throughput (all runs)"),
        ("gen", "NCA gen s"),
        ("rep", "repair s"),
        ("delta", "Δ"),
        ("status", "repair"),
    ]
    return (
        f"## {name}: main comparison (T={T}; mean ± standard error; screen = JAX "
        f"screening approximation, {planner} = exact"
        + ("" if planner == "rhcr" else f", here with the {planner_title(planner)} planner instead of RHCR")
        + ")\n\n"
        + markdown_table(shown, cols)
    )
