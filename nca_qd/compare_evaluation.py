"""The paper's tables 2, 3 and 5 over arms and seeds, beside the paper's rows.

Each run directory that holds an evaluation (``<run>/evaluation/summary.csv``, written by
``experiments.evaluate``) contributes its best generator's rows: success rate and throughput of
successful runs at S and S_eval (tables 2 and 5; exact RHCR runs only — a screened figure is
never set beside the paper's), NCA generation and repair seconds, the similarity Δ and the
repair's Hamming distance (table 3), and its tiling baseline at S_eval (where the evaluation
repaired the tiled layout more than once, ``baselines.tiling_draws``, a row more gives the
spread over those repairs; the tiling row itself is the first, as the paper ran one). The
human layouts are the same for every arm of a domain: one row per domain, from the first
evaluation that has them.
Over the seeds of an arm each figure is the mean ± s.e. of the seeds' figures; with one seed,
the success rate counts its runs and the throughput carries the runs' s.e. The number of exact
runs stands beside each figure: the paper ran 50 (20 for manufacturing at S_eval).

A run's other evaluations (``<run>/evaluation_<tag>/summary.csv``: the same protocol with some
settings changed, as a campaign plan's ``evaluate_also`` writes them) get a table of their own
per tag, its S_eval rows beside the main evaluation's and the paper's, headed by the settings
that differ (:func:`variants_markdown`): e.g. S_eval at the 2,500 shelves of the paper's code
and released layouts, where the main evaluation keeps table 1's 2,250.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from nca_qd.paper import RUNTIME, SCALING, TILING, Scaling

MAIN = "evaluation"
VARIANT_PREFIX = "evaluation_"
WHICH = ("train", "eval")  # S, S_eval


@dataclass
class Arm:
    """One arm's evaluated seeds: (domain, algorithm label) -> per seed, the summary rows."""

    domain: str
    algorithm: str
    seeds: dict[int, list[dict[str, str]]] = field(default_factory=dict)
    folders: dict[int, Path] = field(default_factory=dict)


def read_csv(path: Path) -> list[dict[str, str]]:
    """The rows of an evaluation's CSV file (summary, curves) as dicts of strings."""
    with Path(path).open(newline="") as fh:
        return list(csv.DictReader(fh))


def read_arms(runs: Sequence[tuple[Path, str, int]], folder: str = MAIN) -> list[Arm]:
    """The arms of the runs (``(run_dir, algorithm label, seed)``) that hold an evaluation in
    ``<run_dir>/<folder>``."""
    arms: dict[tuple[str, str], Arm] = {}
    for run_dir, algorithm, seed in runs:
        path = Path(run_dir) / folder / "summary.csv"
        if not path.is_file():
            continue
        rows = read_csv(path)
        if not rows:
            continue
        domain = rows[0]["domain"]
        arm = arms.setdefault((domain, algorithm), Arm(domain, algorithm))
        arm.seeds[seed] = rows
        arm.folders[seed] = path.parent
    return sorted(arms.values(), key=lambda a: (a.domain, a.algorithm))


def _row(rows: Sequence[Mapping[str, str]], kind: str, which: str) -> Mapping[str, str] | None:
    """The first exact-RHCR row of ``kind`` at ``which`` (the best generator comes first)."""
    return next(iter(_rows(rows, kind, which)), None)


def _rows(rows: Sequence[Mapping[str, str]], kind: str, which: str) -> list[Mapping[str, str]]:
    """Every exact-RHCR row of ``kind`` at ``which`` (the tiling baseline's repair draws)."""
    return [r for r in rows if r["kind"] == kind and r["which"] == which and r["simulator"] == "rhcr"]


def _layout_row(rows: Sequence[Mapping[str, str]], kind: str, which: str) -> Mapping[str, str] | None:
    """The first row of ``kind`` at ``which``, whichever simulator (generation and repair)."""
    return next((r for r in rows if r["kind"] == kind and r["which"] == which), None)


def num(value: str | None) -> float:
    """A CSV cell as a float; an empty cell is NaN."""
    return float(value) if value not in (None, "") else math.nan


def seed_mean_se(values: Sequence[float]) -> tuple[float, float]:
    """Mean and standard error over seeds of the finite values (NaN s.e. for one value: a
    single seed has none, and the tables print it alone)."""
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
        "success": seed_mean_se(success),
        "throughput": seed_mean_se(means),
    }


def _fmt_success(cell: Mapping[str, Any]) -> str:
    if not cell.get("runs"):
        return "—"
    m, se = cell["success"]
    unit = cell.get("unit", "seeds")
    runs = f"{cell['runs']} runs" if cell["seeds"] == 1 else f"{cell['seeds']} {unit} × ≥ {cell['runs']} runs"
    spread = "" if math.isnan(se) else f" ± {100 * se:.0f}"
    return f"{100 * m:.0f}{spread} % ({runs})"


def _fmt_pair(pair: tuple[float, float] | None, digits: int = 2) -> str:
    if pair is None or math.isnan(pair[0]):
        return "N/A"
    return f"{pair[0]:.{digits}f}" + ("" if math.isnan(pair[1]) else f" ± {pair[1]:.{digits}f}")


# Issue 55's bounds: a row of tables 2 / 5 differs from the paper's where its success rate is
# more than 15 points away from the paper's, or, where both flowed, its throughput of successful
# runs more than 2 % (at S or at S_eval); such a row's cause is to be found, not guessed.
SUCCESS_POINTS = 15.0
THROUGHPUT_SHARE = 0.02


def _paper(domain: str, label: str) -> Scaling | None:
    return SCALING.get((domain, label)) or TILING.get((domain, label))


def against_paper(row: Mapping[str, Any], paper: Scaling | None) -> str:
    """Whether a table 2 / 5 row is within the bounds above of the paper's ("within"), which
    figures are not ("differs: ..."), or "—" where the paper has no figure to set beside it."""
    if paper is None:
        return "—"
    compared, found = False, []
    for name, size, p_success, p_thr in (
        ("s", "S", paper.success_s, paper.throughput_s),
        ("eval", "S_eval", paper.success_eval, paper.throughput_eval),
    ):
        ours = num(row.get(f"success_{name}"))
        if p_success is None or math.isnan(ours):
            continue
        compared = True
        if abs(gap := 100 * ours - p_success) > SUCCESS_POINTS:
            found.append(f"{size} success {gap:+.0f} points")
        thr = num(row.get(f"throughput_{name}"))
        if p_thr is not None and p_thr[0] > 0 and not math.isnan(thr):
            if abs(rel := thr / p_thr[0] - 1) > THROUGHPUT_SHARE:
                found.append(f"{size} throughput {100 * rel:+.1f} %")
    if not compared:
        return "—"
    return "differs: " + "; ".join(found) if found else "within"


def _set_paper(row: dict[str, Any], domain: str, label: str) -> None:
    """The paper's figures for ``label`` beside ``row``, and the row's verdict against them."""
    p = _paper(domain, label)
    row["paper"], row["against_paper"] = _fmt_paper(p), against_paper(row, p)


def _fmt_paper(p: Scaling | None) -> str:
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
            _set_paper(out[-1], arm.domain, label)
        draws = [r for s in seeds for r in _rows(arm.seeds[s], "tiling", "eval")]
        if len(draws) > len(seeds):  # baselines.tiling_draws > 1: the spread over the repair's draws
            cell = {**scaling_cell(draws), "unit": "repair draws"}
            rates = sorted(num(r["success_rate"]) for r in draws if int(r["completed"] or 0) > 0)
            label = f"tiling of {arm.algorithm}, {len(draws)} repair draws"
            out.append(
                {"domain": arm.domain, "layout": label, "seeds": seeds, **_cells({"train": {}, "eval": cell})}
            )
            if rates:
                out[-1]["text_eval"] += f"; per draw {', '.join(f'{100 * x:.0f}' for x in rates)} %"
            _set_paper(out[-1], arm.domain, f"tiling of {arm.algorithm}")
        if arm.domain not in humans_done:
            rows = arm.seeds[seeds[0]]
            cells = {w: scaling_cell([_row(rows, "human", w)]) for w in WHICH}
            if any(c.get("runs") for c in cells.values()):
                humans_done.add(arm.domain)
                out.append({"domain": arm.domain, "layout": "human", "seeds": seeds[:1], **_cells(cells)})
                _set_paper(out[-1], arm.domain, "human")
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
                row[f"{key}_{name}"] = seed_mean_se([num(r[col]) if r else math.nan for r in rows])
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
        "Exact RHCR; success = runs that ended without congestion; throughput over successful runs. "
        f"Against the paper: a success rate more than {SUCCESS_POINTS:g} points from the paper's, or a "
        f"throughput more than {100 * THROUGHPUT_SHARE:g} % from it, differs (issue 55's bounds; "
        "the means over seeds, their errors beside them).",
        "",
        "| Domain | Layout | Seeds | S (N_a) | S_eval (N_a_eval) | Paper: S / S_eval | Against the paper |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in scaling_rows(arms):
        seeds = ",".join(map(str, r["seeds"]))
        lines.append(
            f"| {r['domain']} | {r['layout']} | {seeds} | {r['text_s']} | {r['text_eval']} | {r['paper']} "
            f"| {r.get('against_paper', '—')} |"
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


# The evaluation settings an S_eval figure depends on (the run counts stand beside each figure).
_SETTINGS = (
    "elites",
    "select",
    "seed",
    "T",
    "agents",
    "baselines.tiling_from",
    "baselines.tiling_draws",
    "n_shelves",
    "repair",
    "exact",
)
_NOT_SETTINGS = {
    "exact.train",
    "exact.eval",
    "exact.sweep_train",
    "exact.sweep_eval",
    "exact.reuse",
    "repair.reuse",
}


def read_variants(runs: Sequence[tuple[Path, str, int]]) -> dict[str, list[Arm]]:
    """The runs' other evaluations by tag: ``<run_dir>/evaluation_<tag>/summary.csv``."""
    tags = sorted(
        {
            p.parent.name[len(VARIANT_PREFIX) :]
            for run_dir, _, _ in runs
            for p in Path(run_dir).glob(f"{VARIANT_PREFIX}*/summary.csv")
        }
    )
    return {tag: arms for tag in tags if (arms := read_arms(runs, VARIANT_PREFIX + tag))}


def _flat(node: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(node, dict):
        out: dict[str, Any] = {}
        for k, v in node.items():
            out.update(_flat(v, f"{prefix}{k}."))
        return out
    return {prefix[:-1]: node}


def settings_differing(variant: Path, main: Path) -> list[str]:
    """``key=value (main evaluation: value)`` for each setting an S_eval figure depends on that
    the evaluation in folder ``variant`` set otherwise than the one in ``main``."""
    from omegaconf import OmegaConf

    from nca_qd.evaluation.plan import ADDED_LATER

    def flat(folder: Path) -> dict[str, Any]:
        path = folder / "evaluate_config.yaml"
        if not path.is_file():
            return {}
        cfg = {**ADDED_LATER, **_flat(OmegaConf.to_container(OmegaConf.load(path), resolve=True))}
        return {k: v for k, v in cfg.items() if k.startswith(_SETTINGS) and k not in _NOT_SETTINGS}

    a, b = flat(variant), flat(main)
    return [
        f"`{k}={a.get(k)}` (main evaluation: `{b.get(k)}`)"
        for k in sorted(set(a) | set(b))
        if a.get(k) != b.get(k)
    ]


def variants_markdown(variants: Mapping[str, Sequence[Arm]], main: Sequence[Arm]) -> str:
    """Per tag, the S_eval rows (best generator, tiling, human) of the runs' other evaluation
    beside the main evaluation's and the paper's, headed by the settings that differ (from the
    first seed's ``evaluate_config.yaml`` against its main evaluation's)."""
    if not variants:
        return ""
    main_by = {(a.domain, a.algorithm): a for a in main}
    lines = [
        "",
        "## S_eval in the runs' other evaluations",
        "",
        "Each `evaluation_<tag>` folder: the same protocol with the settings named changed (`None`: "
        "the run's domain setting, e.g. table 1's shelf count). Exact RHCR, as table 2.",
    ]
    for tag, arms in variants.items():
        first = arms[0]
        seed = sorted(first.folders)[0]
        differs = settings_differing(first.folders[seed], first.folders[seed].parent / MAIN)
        lines += [
            "",
            f"### `{VARIANT_PREFIX}{tag}`: " + ("; ".join(differs) or "the main evaluation's settings"),
            "",
            "| Domain | Layout | Seeds | S_eval (N_a_eval) | Main evaluation: S_eval | Paper: S_eval |",
            "|---|---|---|---|---|---|",
        ]
        # the main evaluation's figures over the same seeds as this one's
        paired = [
            Arm(ma.domain, ma.algorithm, {s: ma.seeds[s] for s in a.seeds if s in ma.seeds})
            for a in arms
            if (ma := main_by.get((a.domain, a.algorithm))) is not None and set(a.seeds) & set(ma.seeds)
        ]
        main_rows = {(r["domain"], r["layout"]): r for r in scaling_rows(paired)}
        for r in scaling_rows(arms):
            if not r["runs_eval"]:
                continue
            seeds = ",".join(map(str, r["seeds"]))
            m = main_rows.get((r["domain"], r["layout"]))
            paper = r["paper"].split(" / ")[-1] if r["paper"] != "—" else "—"
            lines.append(
                f"| {r['domain']} | {r['layout']} | {seeds} | {r['text_eval']} "
                f"| {m['text_eval'] if m else '—'} | {paper} |"
            )
    return "\n".join(lines) + "\n"


SCALING_COLUMNS = [
    "domain",
    "layout",
    "seeds",
    *(f"{k}_{n}{se}" for n in ("s", "eval") for k in ("success", "throughput") for se in ("", "_se")),
    "runs_s",
    "runs_eval",
    "against_paper",
    "evaluation",
]


def write_scaling_csv(
    path: Path, arms: Sequence[Arm], variants: Mapping[str, Sequence[Arm]] | None = None
) -> None:
    """Tables 2/5 as CSV (the evaluation's own writer: NaN as empty cells, atomic); the rows of
    the runs' other evaluations after the main one's, ``evaluation`` naming the folder."""
    from nca_qd.evaluation.tables import write_csv

    rows = [{**r, "seeds": " ".join(map(str, r["seeds"])), "evaluation": MAIN} for r in scaling_rows(arms)]
    for tag, v_arms in (variants or {}).items():
        rows += [
            {**r, "seeds": " ".join(map(str, r["seeds"])), "evaluation": VARIANT_PREFIX + tag}
            for r in scaling_rows(v_arms)
        ]
    write_csv(path, rows, SCALING_COLUMNS)
