"""The paper's tables 2, 3 and 5 over arms and seeds, beside the paper's rows.

Each run directory that holds an evaluation (``<run>/evaluation/summary.csv``, written by
``experiments.evaluate``) contributes its best generator's rows: success rate and throughput of
successful runs at S and S_eval (tables 2 and 5; exact RHCR runs only — a screened figure is
never set beside the paper's), NCA generation and repair seconds, the similarity Δ and the
repair's Hamming distance (table 3), and its tiling baseline at S_eval. The human layouts are
the same for every arm of a domain: one row per domain, from the first evaluation that has them.
Over the seeds of an arm each figure is the mean ± s.e. of the seeds' figures; with one seed,
the success rate counts its runs and the throughput carries the runs' s.e. The number of exact
runs stands beside each figure: the paper ran 50 (20 for manufacturing at S_eval).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from nca_qd.paper import RUNTIME, SCALING, TILING

SUMMARY = Path("evaluation") / "summary.csv"
WHICH = ("train", "eval")  # S, S_eval


@dataclass
class Arm:
    """One arm's evaluated seeds: (domain, algorithm label) -> per seed, the summary rows."""

    domain: str
    algorithm: str
    seeds: dict[int, list[dict[str, str]]] = field(default_factory=dict)


def read_csv(path: Path) -> list[dict[str, str]]:
    """The rows of an evaluation's CSV file (summary, curves) as dicts of strings."""
    with Path(path).open(newline="") as fh:
        return list(csv.DictReader(fh))


def read_arms(runs: Sequence[tuple[Path, str, int]]) -> list[Arm]:
    """The arms of the runs (``(run_dir, algorithm label, seed)``) that hold an evaluation."""
    arms: dict[tuple[str, str], Arm] = {}
    for run_dir, algorithm, seed in runs:
        path = Path(run_dir) / SUMMARY
        if not path.is_file():
            continue
        rows = read_csv(path)
        if not rows:
            continue
        domain = rows[0]["domain"]
        arm = arms.setdefault((domain, algorithm), Arm(domain, algorithm))
        arm.seeds[seed] = rows
    return sorted(arms.values(), key=lambda a: (a.domain, a.algorithm))


def _row(rows: Sequence[Mapping[str, str]], kind: str, which: str) -> Mapping[str, str] | None:
    """The first exact-RHCR row of ``kind`` at ``which`` (the best generator comes first)."""
    for r in rows:
        if r["kind"] == kind and r["which"] == which and r["simulator"] == "rhcr":
            return r
    return None


def _layout_row(rows: Sequence[Mapping[str, str]], kind: str, which: str) -> Mapping[str, str] | None:
    """The first row of ``kind`` at ``which``, whichever simulator (generation and repair)."""
    return next((r for r in rows if r["kind"] == kind and r["which"] == which), None)


def num(value: str | None) -> float:
    """A CSV cell as a float; an empty cell is NaN."""
    return float(value) if value not in (None, "") else math.nan


def _mean_se(values: Sequence[float]) -> tuple[float, float]:
    v = np.asarray([x for x in values if math.isfinite(x)], float)
    if v.size == 0:
        return math.nan, math.nan
    return float(v.mean()), float(v.std(ddof=1) / math.sqrt(v.size)) if v.size > 1 else math.nan


def scaling_cell(rows_by_seed: Sequence[Mapping[str, str] | None]) -> dict[str, Any]:
    """Success and throughput of one layout kind at one size over seeds (None: not run)."""
    found = [r for r in rows_by_seed if r is not None and int(r["completed"] or 0) > 0]
    if not found:
        return {"runs": 0}
    success = [num(r["success_rate"]) for r in found]
    runs = [int(r["completed"]) for r in found]
    if len(found) == 1:
        r = found[0]
        thr = (num(r["throughput_success_mean"]), num(r["throughput_success_se"]))
        return {"seeds": 1, "runs": runs[0], "success": (success[0], math.nan), "throughput": thr}
    means = [num(r["throughput_success_mean"]) for r in found]
    return {
        "seeds": len(found),
        "runs": min(runs),
        "success": _mean_se(success),
        "throughput": _mean_se(means),
    }


def _fmt_success(cell: Mapping[str, Any]) -> str:
    if not cell.get("runs"):
        return "—"
    m, se = cell["success"]
    runs = f"{cell['runs']} runs" if cell["seeds"] == 1 else f"{cell['seeds']} seeds × ≥ {cell['runs']} runs"
    spread = "" if math.isnan(se) else f" ± {100 * se:.0f}"
    return f"{100 * m:.0f}{spread} % ({runs})"


def _fmt_pair(pair: tuple[float, float] | None, digits: int = 2) -> str:
    if pair is None or math.isnan(pair[0]):
        return "N/A"
    return f"{pair[0]:.{digits}f}" + ("" if math.isnan(pair[1]) else f" ± {pair[1]:.{digits}f}")


def _paper_scaling(domain: str, label: str) -> str:
    p = SCALING.get((domain, label)) or TILING.get((domain, label))
    if p is None:
        return "—"
    parts = []
    for success, thr in ((p.success_s, p.throughput_s), (p.success_eval, p.throughput_eval)):
        parts.append("N/A" if success is None else f"{success:.0f} %, {_fmt_pair(thr)}")
    return " / ".join(parts)


def scaling_rows(arms: Sequence[Arm]) -> list[dict[str, Any]]:
    """Table 2 (5): per arm its best generator (NCA) and its tiling baseline; per domain the
    human layouts."""
    out: list[dict[str, Any]] = []
    humans_done: set[str] = set()
    for arm in arms:
        seeds = sorted(arm.seeds)
        for kind, label in (("nca", arm.algorithm), ("tiling", f"tiling of {arm.algorithm}")):
            cells = {w: scaling_cell([_row(arm.seeds[s], kind, w) for s in seeds]) for w in WHICH}
            if kind == "tiling" and not cells["eval"].get("runs"):
                continue
            out.append({"domain": arm.domain, "layout": label, "seeds": seeds, **_cells(cells)})
            out[-1]["paper"] = _paper_scaling(arm.domain, label)
        if arm.domain not in humans_done:
            rows = arm.seeds[seeds[0]]
            cells = {w: scaling_cell([_row(rows, "human", w)]) for w in WHICH}
            if any(c.get("runs") for c in cells.values()):
                humans_done.add(arm.domain)
                out.append({"domain": arm.domain, "layout": "human", "seeds": seeds[:1], **_cells(cells)})
                out[-1]["paper"] = _paper_scaling(arm.domain, "human")
    return out


def _cells(cells: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for w, name in zip(WHICH, ("s", "eval")):
        c = cells[w]
        out[f"success_{name}"] = c["success"][0] if c.get("runs") else math.nan
        out[f"success_{name}_se"] = c["success"][1] if c.get("runs") else math.nan
        out[f"throughput_{name}"] = c["throughput"][0] if c.get("runs") else math.nan
        out[f"throughput_{name}_se"] = c["throughput"][1] if c.get("runs") else math.nan
        out[f"runs_{name}"] = c.get("runs", 0)
        out[f"text_{name}"] = f"{_fmt_success(c)}, {_fmt_pair(c.get('throughput'))}" if c.get("runs") else "—"
    return out


def runtime_rows(arms: Sequence[Arm]) -> list[dict[str, Any]]:
    """Table 3: the best generator's NCA and repair seconds, Δ and Hamming at S and S_eval."""
    out = []
    for arm in arms:
        row: dict[str, Any] = {"domain": arm.domain, "algorithm": arm.algorithm, "seeds": sorted(arm.seeds)}
        for w, name in zip(WHICH, ("s", "eval")):
            rows = [_layout_row(arm.seeds[s], "nca", w) for s in sorted(arm.seeds)]
            for col, key in (
                ("gen_seconds", "nca"),
                ("repair_seconds", "repair"),
                ("similarity", "delta"),
                ("hamming", "hamming"),
            ):
                row[f"{key}_{name}"] = _mean_se([num(r[col]) if r else math.nan for r in rows])
        p = RUNTIME.get((arm.domain, arm.algorithm))
        row["paper"] = (
            f"{p.nca_s:g} s, {p.milp_s:,g} s, Δ {p.delta_s:.2f} / {p.nca_eval:g} s, {p.milp_eval:,g} s, "
            f"Δ {p.delta_eval:.2f}"
            if p
            else "—"
        )
        out.append(row)
    return out


def _fmt_runtime(row: Mapping[str, Any], name: str) -> str:
    nca, rep, delta, ham = (row[f"{k}_{name}"] for k in ("nca", "repair", "delta", "hamming"))
    if math.isnan(nca[0]):
        return "—"
    return f"{_fmt_pair(nca, 3)} s, {_fmt_pair(rep, 1)} s, Δ {_fmt_pair(delta)}, Hamming {_fmt_pair(ham, 0)}"


def tables_markdown(arms: Sequence[Arm]) -> str:
    """Tables 2/5 and 3 as Markdown ('' without any evaluation)."""
    if not arms:
        return ""
    lines = [
        "",
        "## Success and throughput at S and S_eval (the paper's tables 2 and 5)",
        "",
        "Exact RHCR; success = runs that ended without congestion; throughput over successful runs.",
        "",
        "| Domain | Layout | Seeds | S (N_a) | S_eval (N_a_eval) | Paper: S / S_eval |",
        "|---|---|---|---|---|---|",
    ]
    for r in scaling_rows(arms):
        seeds = ",".join(map(str, r["seeds"]))
        lines.append(
            f"| {r['domain']} | {r['layout']} | {seeds} | {r['text_s']} | {r['text_eval']} | {r['paper']} |"
        )
    lines += [
        "",
        "## Generation and repair (the paper's table 3)",
        "",
        "NCA generation and repair seconds (this machine, HiGHS; the paper's: a 16-core desktop, "
        "CPLEX), the similarity Δ of the repaired layout to the generated one, the repair's "
        "Hamming distance.",
        "",
        "| Domain | Algorithm | Seeds | S | S_eval | Paper: S / S_eval |",
        "|---|---|---|---|---|---|",
    ]
    for r in runtime_rows(arms):
        seeds = ",".join(map(str, r["seeds"]))
        lines.append(
            f"| {r['domain']} | {r['algorithm']} | {seeds} | {_fmt_runtime(r, 's')} "
            f"| {_fmt_runtime(r, 'eval')} | {r['paper']} |"
        )
    return "\n".join(lines) + "\n"


SCALING_COLUMNS = [
    "domain",
    "layout",
    "seeds",
    *(f"{k}_{n}{se}" for n in ("s", "eval") for k in ("success", "throughput") for se in ("", "_se")),
    "runs_s",
    "runs_eval",
]


def write_scaling_csv(path: Path, arms: Sequence[Arm]) -> None:
    """Tables 2/5 as CSV (the evaluation's own writer: NaN as empty cells, atomic)."""
    from nca_qd.evaluation.tables import write_csv

    rows = [{**r, "seeds": " ".join(map(str, r["seeds"]))} for r in scaling_rows(arms)]
    write_csv(path, rows, SCALING_COLUMNS)
