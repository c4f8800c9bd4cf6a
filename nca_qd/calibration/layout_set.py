"""The calibration set of 33x36 warehouse layouts the screen's constants are fitted and checked
on, and their exact RHCR and screened figures.

The set (:func:`make_layouts`): the paper's human-designed layout, its generated one and that
one unrepaired, human variants with shelf runs removed, paper variants with random tile
mutations, and random-aisle warehouses (shelf runs of random length, gaps and row spacing); all
valid by :func:`~nca_qd.sim.scenario.build_scenario`. Seed 0 draws the set the congested-run
model is fitted on (:mod:`nca_qd.calibration.congested`), seed 1 the held-out set
``benchmarks/bench_screen.py`` reports fidelity on. Exact figures: 5 seeds, 200 agents,
T = 1,000, warehouse_even, RHCR with the search's node budget (``pbs_max_nodes=2000``).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from nca_qd.errors import NcaQdError
from nca_qd.io import load_map
from nca_qd.sim.scenario import build_scenario

SCENARIO, AGENTS, T, SEEDS = "warehouse_even", 200, 1000, [0, 1, 2, 3, 4]
PBS_MAX_NODES: int | str = 2000  # the search's per-call node budget (same verdicts as auto)


def _load(maps: Path | None, name: str) -> list[str] | None:
    p = None if maps is None else maps / name
    return load_map(p).rows if p is not None and p.is_file() else None


def _valid(rows: list[str]) -> bool:
    try:
        build_scenario(rows, SCENARIO, n_agents=AGENTS)
        return True
    except NcaQdError:
        return False


def _human_variant(rows: list[str], rng: np.random.Generator, p: float) -> list[str]:
    """Remove each horizontal shelf run with probability p (its endpoints sometimes too)."""
    g = np.array([list(r) for r in rows])
    for r in range(g.shape[0]):
        c = 0
        while c < g.shape[1]:
            if g[r, c] != "@":
                c += 1
                continue
            e = c
            while e < g.shape[1] and g[r, e] == "@":
                e += 1
            if rng.random() < p:
                g[r, c:e] = "."
                for rr in (r - 1, r + 1):
                    if 0 <= rr < g.shape[0] and rng.random() < 0.5:
                        g[rr, c:e] = np.where(g[rr, c:e] == "e", ".", g[rr, c:e])
            c = e
    return ["".join(x) for x in g]


def _mutate(rows: list[str], rng: np.random.Generator, m: int) -> list[str]:
    """Set m random interior tiles to '.', '@' or 'e' (workstations kept)."""
    g = np.array([list(r) for r in rows])
    h, w = g.shape
    for _ in range(m):
        r, c = rng.integers(1, h - 1), rng.integers(2, w - 2)
        if g[r, c] != "w":
            g[r, c] = rng.choice(list(".@@e"))
    return ["".join(x) for x in g]


def _random_warehouse(rng: np.random.Generator, h: int = 33, w: int = 36) -> list[str]:
    """Shelf rows with random run lengths, aisle gaps and row spacing; workstations on the
    left and right borders; endpoints above and below shelves."""
    g = np.full((h, w), ".")
    for r in range(1, h - 1, 3):
        g[r, 0] = g[r, w - 1] = "w"
    r = 2
    while r < h - 2:
        c = 2 + int(rng.integers(0, 2))
        while c < w - 3:
            run = int(rng.integers(2, 12))
            end = min(c + run, w - 2)
            g[r, c:end] = "@"
            for rr in (r - 1, r + 1):
                g[rr, c:end] = np.where(g[rr, c:end] == ".", "e", g[rr, c:end])
            c = end + int(rng.integers(1, 4))
        r += int(rng.integers(3, 5))
    return ["".join(x) for x in g]


def make_layouts(maps: Path | None, n_min: int = 40, seed: int = 1) -> list[tuple[str, list[str]]]:
    """The set: (name, rows), all valid 33x36 warehouse layouts. ``maps``: a folder holding
    the paper's ``human_33x36.json``, ``paper_cma-mae_a5_even_33x36.json`` and its
    ``_unrepaired`` version (the variants of these are drawn only where they are there)."""
    rng = np.random.default_rng(seed)
    out = []
    human = _load(maps, "human_33x36.json")
    paper = _load(maps, "paper_cma-mae_a5_even_33x36.json")
    unrep = _load(maps, "paper_cma-mae_a5_even_33x36_unrepaired.json")
    for name, rows in (("human", human), ("paper", paper), ("paper_unrepaired", unrep)):
        if rows is not None and _valid(rows):
            out.append((name, list(rows)))
    i = 0
    while human is not None and i < 12:
        rows = _human_variant(human, rng, p=0.1 + 0.05 * i)
        if _valid(rows):
            out.append((f"human_minus_{i}", rows))
            i += 1
    i = 0
    while paper is not None and i < 12:
        rows = _mutate(paper, rng, m=15 + 15 * i)
        if _valid(rows):
            out.append((f"paper_mut_{i}", rows))
            i += 1
    i = 0
    while len(out) < n_min or i < 14:
        rows = _random_warehouse(rng)
        if _valid(rows):
            out.append((f"random_{i}", rows))
            i += 1
    return out


def rhcr_figures(
    layouts,
    cache: str | Path | None,
    seeds: list[int] = SEEDS,
    scenario: str = SCENARIO,
    pbs_max_nodes: int | str = PBS_MAX_NODES,
) -> dict:
    """name -> list of (throughput, success, CPU-s) over ``seeds``, exact RHCR, threads=1
    (cached in the JSON file ``cache`` under the layout's name for SEEDS, ``name@<first seed>``
    for other seeds: the RHCR figures cost CPU-hours and outlive one call)."""
    from nca_qd.sim.rhcr import simulate_many

    done = json.loads(Path(cache).read_text()) if cache and Path(cache).is_file() else {}
    tag = "" if list(seeds) == SEEDS else f"@{seeds[0]}"
    for name, rows in layouts:
        if name + tag in done:
            continue
        runs = simulate_many(rows, scenario, AGENTS, T, list(seeds), threads=1, pbs_max_nodes=pbs_max_nodes)
        done[name + tag] = [[r.throughput, r.success, r.cpu_seconds] for r in runs]
        if cache:
            Path(cache).write_text(json.dumps(done))
    return {name: done[name + tag] for name, _ in layouts}


def screen_figures(layouts, congestion: str, planner: str = "pibt") -> tuple[dict, float]:
    """name -> list of (throughput, success, mean crowding over the run's checks, stop time / T)."""
    from nca_qd.sim.screen import simulate_batch

    t0 = time.perf_counter()
    res = simulate_batch(
        [rows for _, rows in layouts], SCENARIO, AGENTS, T, SEEDS, congestion=congestion, planner=planner
    )
    wall = time.perf_counter() - t0
    return {
        name: [[r.throughput, r.success, float(np.mean(r.crowding)), r.stop_time / T] for r in runs]
        for (name, _), runs in zip(layouts, res)
    }, wall


def spearman(x, y) -> float:
    from scipy.stats import spearmanr

    return float(spearmanr(x, y).statistic)
