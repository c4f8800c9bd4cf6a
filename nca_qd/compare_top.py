"""The archives' best generators at S_eval, beside the one the paper's protocol evaluates.

The paper's tables 2 and 3 rest on one generator per arm (the best at S). Whether that one is
typical of its archive is checked by three kinds of ``experiments.evaluate`` folders of a run,
found anywhere below the compared paths by their ``evaluate_config.yaml`` (whose ``run_dir`` is
one of the compared runs):

- a **screen** of the archive's ``pool`` best at S (``select.by=s_eval``, no exact ranking):
  ``selection.csv``, each candidate grown to S_eval, repaired and screened ``select.runs`` times;
- an **exact check** of its N best (``elites=N``, N ≥ 2, exact runs at S_eval): ``runs.csv``;
- a **two-stage pick** (``select.by=s_eval select.exact_top>0``): the pick and its exact runs.

:func:`top_markdown` writes one table per kind, a row per run, every figure counted from those
files (flowing = a run that ended without congestion, the ``success`` column). Selections
written before ``selection.csv`` carried the repair's similarity Δ and Hamming distance take them
from the folder's repair records (``repairs.jsonl[.gz]``), matched by the repaired layout.
"""

from __future__ import annotations

import logging
import math
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException

from nca_qd.compare_evaluation import num, read_csv
from nca_qd.io import load_map

log = logging.getLogger(__name__)

CONFIG = "evaluate_config.yaml"
# the files each kind of check is read from (all written when its evaluation finished)
NEEDS = {
    "screen": ("selection.csv",),
    "exact": ("runs.csv",),
    "pick": ("selection.csv", "runs.csv", "summary.csv"),
}


@dataclass
class Check:
    """One check folder of a compared run: its kind (screen, exact, pick) and the run's label."""

    kind: str
    folder: Path
    label: str


def _kind(cfg: Mapping[str, Any]) -> str | None:
    select = cfg.get("select") or {}
    exact = cfg.get("exact") or {}
    elites = cfg.get("elites")
    if select.get("by") == "s_eval":
        if int(select.get("exact_top") or 0) > 0:
            return "pick"
        return "screen" if int(select.get("pool") or 0) >= 2 else None
    if isinstance(elites, int) and not isinstance(elites, bool) and elites >= 2:
        return "exact" if int(exact.get("eval") or 0) > 0 else None
    return None


def _same_run(run: Path, named: str) -> bool:
    """Whether the run directory ``run`` is the one an evaluation named (``run_dir``, as given
    on its command line: relative to where it ran, so matched by its trailing parts too)."""
    p = Path(named)
    if run.resolve() == p.resolve():
        return True
    parts = [x for x in p.parts if x not in (".", "")]
    return bool(parts) and list(run.resolve().parts[-len(parts) :]) == parts


def find_checks(paths: Sequence[str | Path], runs: Sequence[tuple[Path, str, int]]) -> list[Check]:
    """The check folders below ``paths`` of the compared ``runs`` (``(run_dir, label, seed)``)."""
    seen: set[Path] = set()
    checks: list[Check] = []
    for root in paths:
        for cfg_file in sorted(Path(root).rglob(CONFIG)):
            folder = cfg_file.parent
            if folder.resolve() in seen:
                continue
            seen.add(folder.resolve())
            try:
                cfg = OmegaConf.to_container(OmegaConf.load(cfg_file), resolve=True)
            except (OSError, ValueError, yaml.YAMLError, OmegaConfBaseException) as exc:  # not a check
                log.warning("%s: not read (%s); left out of the archives' best", cfg_file, exc)
                continue
            if not isinstance(cfg, dict) or "run_dir" not in cfg:
                continue
            kind = _kind(cfg)
            match = next((r for r in runs if _same_run(r[0], str(cfg["run_dir"]))), None)
            if kind is None or match is None or not all((folder / f).is_file() for f in NEEDS[kind]):
                continue  # not a check, not of a compared run, or one still under way
            checks.append(Check(kind, folder, f"{match[1]}, seed {match[2]}"))
    return sorted(checks, key=lambda c: (c.label, str(c.folder)))


def _canonical(a: np.ndarray) -> bytes:
    """A layout up to the naming of its tiles (each value replaced by the order of its first
    appearance): a repair record's tile indices and a map file's characters compare equal."""
    flat = np.asarray(a).ravel()
    _, first, inverse = np.unique(flat, return_index=True, return_inverse=True)
    order = np.argsort(np.argsort(first))
    return np.asarray(a.shape, dtype=np.int64).tobytes() + order[inverse].astype(np.int32).tobytes()


def _repair_figures(folder: Path) -> dict[bytes, tuple[float, float]]:
    """The folder's repairs (``repairs.jsonl`` or ``.gz``): repaired layout -> (Δ, Hamming)."""
    from nca_qd.evaluation.store import RepairStore

    return {
        _canonical(layout): (similarity, float("nan") if hamming is None else float(hamming))
        for layout, similarity, hamming in RepairStore(folder).figures()
    }


def _selection(check: Check) -> list[dict[str, Any]]:
    """selection.csv's rows, with Δ and Hamming from the repair records where it lacks them."""
    rows: list[dict[str, Any]] = [dict(r) for r in read_csv(check.folder / "selection.csv")]
    missing = [r for r in rows if not r.get("similarity")]
    if missing:
        figures = _repair_figures(check.folder)
        for r in missing:
            f = check.folder / str(r.get("file") or "")
            if not f.is_file():
                continue
            layout = np.array([list(row) for row in load_map(f).rows])
            if (hit := figures.get(_canonical(layout))) is not None:
                r["similarity"], r["hamming"] = f"{hit[0]:.6f}", f"{hit[1]:.0f}"
    return rows


def _screened_flowing(row: Mapping[str, Any]) -> tuple[int, int]:
    """A candidate's screened runs that flowed, and its screened runs."""
    n = 0 if not row.get("screen_runs") else int(num(row["screen_runs"]))
    rate = num(row.get("screen_success_rate"))
    return (0 if n == 0 or math.isnan(rate) else round(rate * n)), n


def _median_range(values: Sequence[float], fmt: str) -> str:
    vals = [v for v in values if not math.isnan(v)]
    if not vals:
        return "—"
    return f"{format(float(np.median(vals)), fmt)} ({format(min(vals), fmt)}–{format(max(vals), fmt)})"


def screen_row(check: Check) -> dict[str, Any]:
    """One screen: how many of its candidates flow in every screened run, in none, all runs."""
    rows = _selection(check)
    counts = [_screened_flowing(r) for r in rows]
    return {
        "run": check.label,
        "generators": len(rows),
        "runs_each": max((n for _, n in counts), default=0),
        "all": sum(1 for k, n in counts if n and k == n),
        "none": sum(1 for k, n in counts if n and k == 0),
        "flowing": sum(k for k, _ in counts),
        "runs": sum(n for _, n in counts),
        "delta": _median_range([num(r.get("similarity")) for r in rows], ".3f"),
        "hamming": _median_range([num(r.get("hamming")) for r in rows], ",.0f"),
        "by_cell": {str(r["cell"]): c for r, c in zip(rows, counts)},
        "folder": check.folder,
    }


def _exact_runs(folder: Path) -> dict[str, list[bool]]:
    """cell -> the success of each exact (RHCR) run of an NCA layout at S_eval, in ``runs.csv``."""
    out: dict[str, list[bool]] = defaultdict(list)
    for r in read_csv(folder / "runs.csv"):
        if r.get("which") == "eval" and r.get("kind") == "nca" and r.get("simulator") == "rhcr":
            out[str(r["cell"])].append(str(r.get("success")).lower() == "true")
    return dict(out)


def exact_row(check: Check, screens: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """One exact check: its runs flowing, its generators flowing in all / some / none of theirs,
    and the same generators' screened runs where a screen of the same run holds them."""
    runs = _exact_runs(check.folder)
    flows = [sum(v) for v in runs.values()]
    screened = [0, 0]
    for s in screens:
        if s["run"] == check.label and set(runs) <= set(s["by_cell"]):
            screened = [sum(s["by_cell"][c][i] for c in runs) for i in (0, 1)]
            break
    return {
        "run": check.label,
        "generators": len(runs),
        "flowing": sum(flows),
        "runs": sum(len(v) for v in runs.values()),
        "all": sum(1 for f, v in zip(flows, runs.values()) if f == len(v)),
        "some": sum(1 for f, v in zip(flows, runs.values()) if 0 < f < len(v)),
        "none": sum(1 for f in flows if f == 0),
        "screened": tuple(screened) if screened[1] else None,
        "folder": check.folder,
    }


def pick_row(check: Check) -> dict[str, Any]:
    """One two-stage pick: the S-best, the pick, and the pick's exact runs at S_eval."""
    rows = read_csv(check.folder / "selection.csv")
    picked = next((r["cell"] for r in rows if str(r.get("selected")).lower() == "true"), None)
    runs = _exact_runs(check.folder).get(str(picked), []) if picked is not None else []
    row = next(
        (
            r
            for r in read_csv(check.folder / "summary.csv")
            if r.get("which") == "eval" and r.get("simulator") == "rhcr" and str(r.get("cell")) == str(picked)
        ),
        None,
    )
    best = max(rows, key=lambda r: num(r.get("objective_s")), default=None)
    return {
        "run": check.label,
        "pool": len(rows),
        "s_best": None if best is None else best["cell"],
        "picked": picked,
        "flowing": sum(runs),
        "runs": len(runs),
        "throughput": None if row is None else (num(row["throughput_mean"]), num(row["throughput_se"])),
        "folder": check.folder,
    }


def _pct(k: int, n: int) -> str:
    return f"{k} ({100 * k / n:.0f} %)" if n else "—"


def _table(title: str, header: Sequence[str], rows: Sequence[Sequence[Any]]) -> list[str]:
    return [
        f"\n### {title}\n",
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
        *("| " + " | ".join(str(c) for c in row) + " |" for row in rows),
    ]


def top_markdown(checks: Sequence[Check], base: Path | None = None) -> str:
    """The three tables (those with rows), each row a run, its folder named relative to ``base``."""
    if not checks:
        return ""

    def where(p: Path) -> str:
        try:
            return f"`{p.resolve().relative_to(base.resolve())}`" if base is not None else f"`{p}`"
        except ValueError:
            return f"`{p}`"

    screens = [screen_row(c) for c in checks if c.kind == "screen"]
    exacts = [exact_row(c, screens) for c in checks if c.kind == "exact"]
    picks = [pick_row(c) for c in checks if c.kind == "pick"]
    md = [
        "\n## The archives' best generators at S_eval (is the evaluated one typical?)\n",
        "Each check is an `experiments.evaluate` folder of the run (its `evaluate_config.yaml` holds"
        " the command's settings); flowing: a run that ended without congestion.",
    ]
    if screens:
        md += _table(
            "Screened: the archive's best at S, grown to S_eval and repaired",
            ["run", "generators", "flowing in every screened run", "in none", "screened runs flowing"]
            + ["Δ at S_eval: median (range)", "Hamming: median (range)", "folder"],
            [
                [s["run"], f"{s['generators']} × {s['runs_each']} runs", s["all"], s["none"]]
                + [f"{_pct(s['flowing'], s['runs'])} of {s['runs']}", s["delta"], s["hamming"]]
                + [where(s["folder"])]
                for s in screens
            ],
        )
    if exacts:
        md += _table(
            "Exact RHCR: the archive's best at S, at S_eval",
            ["run", "generators", "exact runs flowing"]
            + ["generators flowing in all / some / none of their runs"]
            + ["the same generators screened: runs flowing", "folder"],
            [
                [e["run"], e["generators"], f"{_pct(e['flowing'], e['runs'])} of {e['runs']}"]
                + [f"{e['all']} / {e['some']} / {e['none']}"]
                + ["—" if e["screened"] is None else f"{_pct(*e['screened'])} of {e['screened'][1]}"]
                + [where(e["folder"])]
                for e in exacts
            ],
        )
    if picks:
        md += _table(
            "The two-stage pick (screen, then exact runs of the screen's best)",
            ["run", "pool", "S-best", "picked", "its exact runs at S_eval flowing"]
            + ["throughput (all its runs) ± s.e.", "folder"],
            [
                [p["run"], p["pool"], p["s_best"], p["picked"], f"{p['flowing']} of {p['runs']}"]
                + ["—" if p["throughput"] is None else f"{p['throughput'][0]:.2f} ± {p['throughput'][1]:.2f}"]
                + [where(p["folder"])]
                for p in picks
            ],
        )
    return "\n".join(md) + "\n"
