"""How often a search's screen was wrong to keep a layout from exact runs, and which crowding
threshold would have sent it there: what set the threshold of the manufacturing and uneven
domains (``simulation.screen_crowd_mean``) from 2026-11-29.

A search screens each layout that comes to an occupied cell of its result archive and gives it
exact runs only when the screen's prediction x (1 + ``eval.exact_margin``) reaches the cell's
elite (plus a random check share). A layout it skipped never enters the result archive, which
takes only exactly-run layouts. This check takes layouts a search skipped — repaired, valid,
never run exactly: the repaired layouts of its ``eval_memo.npz`` that have no exact entry —
runs each exactly as the search would have (its domain's agents, T and N_e runs, its planner
settings, one process), and counts those whose mean throughput beats the elite of their cell as
it was when the layout first came (the best exact mean of earlier iterations in that cell, rebuilt
from the memo; the lowest elite the layout ever faced, so the count errs towards "wrong"). Seeds
come from the layout's key (the search's per-batch seeds are not stored).

One JSON line per layout goes to ``out`` as it finishes (a rerun skips layouts already there,
so the check can be stopped and resumed); the summary comes at the end:

    python -m experiments.calibrate fit=screen_skips run_dir=results/manufacturing_a5 n=300 \
        out=results/manufacturing_a5/screen_skips.jsonl

``replay=[18,22,26]`` then screens the checked layouts again (N_e seeds, the domain's agents
and T) with each crowding threshold and prints which of them the search's rule would now send to
exact runs (prediction x (1 + margin) >= the elite, at the run's ``exact_margin``, 0.2 and 0.3),
improvers and others apart: what a threshold or margin would have caught, and what it costs (the
others). The ``free_flow`` estimate is
replayed with the run's configured efficiency (the search recalibrates it as it goes).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np


def _cells(cfg, layouts: np.ndarray) -> np.ndarray:
    """Result-archive cell of each repaired layout (the domain's measures on its grid)."""
    from nca_qd.domains import make_domain
    from nca_qd.qd.archive import grid_cell_indices

    domain = make_domain(cfg.domain)
    meas = np.concatenate(
        [np.asarray(domain.measures(layouts[a : a + 256])) for a in range(0, len(layouts), 256)]
    )
    spec = cfg.domain.measures
    return np.asarray(grid_cell_indices(meas, list(spec.cells), [list(r) for r in spec.ranges]))


def skipped_layouts(memo, cfg) -> list[dict]:
    """The memo's skipped layouts (valid repair, no exact entry), each with the iteration it first
    came in, its cell and that cell's elite then (``-inf``: empty)."""
    from nca_qd.scoring.keys import layout_key

    exact_keys = [bytes(k) for k in memo["exact_keys"]]
    exact_set = set(exact_keys)
    first: dict[bytes, tuple[int, int]] = {}  # repaired key -> (iteration, memo row)
    for i, (lay, found, it) in enumerate(
        zip(memo["repair_layouts"], memo["repair_found"], memo["repair_iteration"])
    ):
        key = layout_key(lay)
        if found and (key not in first or it < first[key][0]):
            first[key] = (int(it), i)
    by_key = {k: first[k][1] for k in exact_keys if k in first}
    skipped = [k for k in first if k not in exact_set]
    rows = [by_key[k] for k in exact_keys if k in by_key] + [first[k][1] for k in skipped]
    cells = _cells(cfg, memo["repair_layouts"][rows])
    n_ex = len(rows) - len(skipped)
    keep = [i for i, k in enumerate(exact_keys) if k in by_key]
    ex_cell, ex_mean = cells[:n_ex], memo["exact_throughput"].mean(1)[keep]
    ex_it = memo["exact_iteration"][keep]
    out = []
    for j, key in enumerate(skipped):
        it, row = first[key]
        cell = int(cells[n_ex + j])
        earlier = (ex_cell == cell) & (ex_it < it)
        elite = float(ex_mean[earlier].max()) if earlier.any() else -math.inf
        out.append({"key": key.hex(), "row": row, "iteration": it, "cell": cell, "elite": elite})
    return out


def _wilson(k: int, n: int) -> tuple[float, float]:
    """95 % Wilson interval of a share k / n."""
    if n == 0:
        return 0.0, 1.0
    z, p = 1.96, k / n
    mid = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, mid - half), min(1.0, mid + half)


def summarise(records: list[dict]) -> dict:
    """Share of checked layouts that would have entered the result archive."""
    occupied = [r for r in records if math.isfinite(r["elite"])]
    entered = [r for r in occupied if r["mean"] > r["elite"]]
    lo, hi = _wilson(len(entered), len(occupied))
    gains = sorted(round(r["mean"] - r["elite"], 3) for r in entered)
    return {
        "checked": len(records),
        "in_occupied_cells": len(occupied),
        "would_have_entered": len(entered),
        "share": round(len(entered) / max(1, len(occupied)), 4),
        "share_95ci": [round(lo, 4), round(hi, 4)],
        "gains_over_elite": gains,
        "flowing_runs": round(float(np.mean([np.mean(r["success"]) for r in records])), 3) if records else 0,
        "cpu_s_per_layout": round(float(np.mean([sum(r["cpu_s"]) for r in records])), 2) if records else 0,
    }


def replay(records: list[dict], cfg, scoring, thresholds: list[float]) -> Iterator[dict]:
    """Per crowding threshold: the checked layouts the search's exact-run rule would choose."""
    from nca_qd.sim.free_flow import free_flow_throughput, rhcr_estimate
    from nca_qd.sim.scenario import build_scenario
    from nca_qd.sim.screen import simulate_scenarios

    name, sim = cfg.domain.name, cfg.domain.simulation
    T, n_agents = int(sim.T), int(cfg.domain.n_agents.train)
    scens = [build_scenario(r["rows"], name, n_agents=n_agents) for r in records]
    flow = np.array([free_flow_throughput(s, n_agents) for s in scens])
    elite = np.array([r["elite"] for r in records])
    better = np.array([r["mean"] > r["elite"] for r in records])
    seeds = list(range(int(sim.n_runs)))  # (the screen's streams are not RHCR's anyway)
    for threshold in thresholds:
        runs = [
            row
            for a in range(0, len(scens), 64)
            for row in simulate_scenarios(scens[a : a + 64], n_agents, T, seeds, crowd_mean=threshold)
        ]
        thr = np.array([[r.throughput for r in row] for row in runs])
        ok = np.array([[r.success for r in row] for row in runs])
        stop = np.array([[r.stop_time / T for r in row] for row in runs])
        if scoring.screen_estimate == "free_flow":
            pred = rhcr_estimate(thr, ok, stop, flow, scoring.screen_efficiency, scoring.screen_congested)
        else:
            pred = scoring.screen_scale * thr.mean(1)
        row: dict = {"crowd_mean": threshold, "screen_flowing_runs": round(float(ok.mean()), 3)}
        for margin in dict.fromkeys([scoring.exact_margin, 0.2, 0.3]):  # the run's margin first
            chosen = pred * (1 + margin) >= elite
            row[f"margin_{margin:g}"] = {
                "improvers_chosen": f"{int((chosen & better).sum())} of {int(better.sum())}",
                "others_chosen": f"{int((chosen & ~better).sum())} of {int((~better).sum())}",
            }
        yield row


def _done(out: Path) -> dict[str, dict]:
    """The records ``out`` holds by key (a last line cut short by a stop is dropped)."""
    if not out.is_file():
        return {}
    lines = [line for line in out.read_text().splitlines() if line.strip()]
    try:
        return {r["key"]: r for r in map(json.loads, lines)}
    except json.JSONDecodeError:
        return {r["key"]: r for r in map(json.loads, lines[:-1])}


def _run_exactly(p: dict, rows: list[str], cfg, scoring) -> dict:
    """One skipped layout's exact runs as the search would have made them (seeds from its key)."""
    from nca_qd.scoring.jobs import ExactSettings, exact_job
    from nca_qd.sim.rhcr import REPLAN, WINDOW

    sim = cfg.domain.simulation
    T, n_runs, n_agents = int(sim.T), int(sim.n_runs), int(cfg.domain.n_agents.train)
    seed0 = int(p["key"][:8], 16) % (2**31 - n_runs)
    t0 = time.process_time()
    settings = ExactSettings(T, scoring.exact_time_limit_s, WINDOW, REPLAN, dict(scoring.planner or {}))
    runs = [exact_job(rows, cfg.domain.name, n_agents, seed0 + s, settings) for s in range(n_runs)]
    return {
        **{k: p[k] for k in ("key", "iteration", "cell", "elite")},
        "seeds": [seed0 + s for s in range(n_runs)],
        "throughput": [round(r.throughput, 4) for r in runs],
        "success": [bool(r.success) for r in runs],
        "cpu_s": [round(r.cpu_seconds, 2) for r in runs],
        "errors": [r.error for r in runs if r.error],
        "mean": round(float(np.mean([r.throughput for r in runs])), 4),
        "process_cpu_s": round(time.process_time() - t0, 2),
    }


def check(
    run_dir: Path,
    n: int,
    seed: int,
    out: Path,
    thresholds: list[float] | None = None,
    replay_only: bool = False,
) -> Iterator[dict]:
    """Check ``n`` skipped layouts of the search in ``run_dir`` drawn with ``seed`` (those
    ``out`` holds are not run again; each new one is appended as it ends), then replay the
    screen at ``thresholds``. Yields what to print: what was looked at, the summary, the replay.
    ``replay_only``: every layout ``out`` holds, none run now."""
    from omegaconf import OmegaConf

    from nca_qd.io import array_to_rows
    from nca_qd.layouts import get_layout
    from nca_qd.run_dir import load_run_config
    from nca_qd.scoring.settings import ScoringConfig

    cfg = load_run_config(run_dir)
    memo = np.load(run_dir / "eval_memo.npz")
    scoring = ScoringConfig.from_cfg(OmegaConf.to_container(cfg.get("eval", {}), resolve=True))
    tiles = get_layout(cfg.domain.name, "domain").tiles
    pool = skipped_layouts(memo, cfg)
    order = np.random.default_rng(seed).permutation(len(pool))[:n]
    done = _done(out)
    yield {
        "run_dir": str(run_dir),
        "skipped": len(pool),
        "in_occupied_cells": sum(math.isfinite(p["elite"]) for p in pool),
        "checking": 0 if replay_only else len(order),
        "already_in_out": len(done),
    }
    records = [done[pool[i]["key"]] for i in order if pool[i]["key"] in done]
    if replay_only:
        order, known = np.array([], int), {p["key"] for p in pool}
        records = [r for k, r in done.items() if k in known]
    for i in order:
        p = pool[i]
        if p["key"] in done:
            continue
        rec = _run_exactly(p, array_to_rows(memo["repair_layouts"][p["row"]], tiles), cfg, scoring)
        out.parent.mkdir(parents=True, exist_ok=True)
        with out.open("a") as fh:
            fh.write(json.dumps(rec) + "\n")
        records.append(rec)
    yield summarise(records)
    if thresholds:
        by_key = {p["key"]: p for p in pool}
        for r in records:
            r["rows"] = array_to_rows(memo["repair_layouts"][by_key[r["key"]]["row"]], tiles)
        yield from replay(records, cfg, scoring, thresholds)
