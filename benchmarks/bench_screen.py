"""Screening simulator (nca_qd.sim.screen): fidelity against exact RHCR, and speed.

    .venv/bin/python -m benchmarks.bench_screen            # everything (~10 CPU-minutes)
    BENCH_SCREEN_PARTS=speed .venv/bin/python -m benchmarks.bench_screen

Fidelity: >= 40 varied 33x36 warehouse layouts (the human-designed one, the paper's generated
one and its unrepaired version, human variants with shelf blocks removed, paper variants
with random tile mutations, random-aisle warehouses; all valid by ``build_scenario``), 200
agents, T=1,000, 5 seeds each, warehouse_even. Reports the Spearman rank correlation of mean
throughput (screen vs RHCR, threads=1) and the agreement on congestion (majority success over
the seeds, and per run). ``BENCH_SCREEN_RHCR_CACHE=<file.json>`` keeps the RHCR figures
outside git between runs (optional). The layout generator runs with seed 1: the screen's
"crowding" congestion constants were calibrated on the seed-0 set, so these figures are
held out. Both congestion rules are reported ("crowding", the default, and "moved", RHCR's
rule alone). Two bounds are printed beside them: the per-run congestion agreement that no
screen with its own random streams can exceed (RHCR's seed-to-seed spread), and the Spearman
correlation of RHCR's mean throughput with minus the screen's mean crowding in full-horizon runs.
And RHCR's split-half agreement with itself (seeds 0-4 against seeds 5-9: Spearman of mean
throughput, agreement of the majority verdicts): the ceiling of the fidelity targets.

Free-flow estimate (:mod:`nca_qd.sim.free_flow`): beside each PIBT setting's raw figures,
the Spearman of RHCR's mean throughput against the screen's RHCR estimate (a flowing screened
run counts ``BENCH_SCREEN_EFFICIENCY`` x the layout's free-flow throughput, default 0.932:
RHCR's mean share of free flow on 278 layouts of the warehouse search's memo whose 5 RHCR runs
all flowed, none of them in this set; a congested run counts 1.3 x its own throughput).
``BENCH_SCREEN_PBS_MAX_NODES`` sets exact RHCR's per-call node budget (default RHCR's ``auto``;
2000 is the search's, which reaches the same verdicts at a fraction of the cost).

The search's own layouts (``BENCH_SCREEN_PARTS=search``, not in the default set: a few
minutes of screening): ``BENCH_SCREEN_SEARCH_N`` (default 300) distinct repaired layouts drawn at random
from a warehouse (even) search's evaluation memo (``BENCH_SCREEN_MEMO``, default
``results/warehouse_even_a5/eval_memo.npz``), whose exact RHCR throughputs (5 seeds, T=1,000,
200 agents) the memo holds. Screened with 5 seeds; reports the Spearman of RHCR's mean against
the screen's, the free-flow estimate's and free flow alone, and how many of RHCR's top 10 %
each ranks in its own top 10 %. The estimate's efficiency is fitted on one half of the layouts
(those on which all 5 RHCR runs flow) and scored on the other half. With the run's
``config.yaml`` beside the memo it also replays the search's exact-run choice on the scored
half: each layout against its result cell's elite as it was when the layout came (rebuilt from
the memo), per ``exact_margin``, for the scaled screen and the estimate.

Planners: ``BENCH_SCREEN_PLANNERS`` (default ``pibt,windowed``) picks the screen's planners that
fidelity and speed measure: PIBT with both congestion rules, the windowed prioritized planner
(``nca_qd.sim.screen_windowed``) with RHCR's rule. ``BENCH_SCREEN_CACHED_ONLY=1`` restricts the
fidelity set to the layouts whose RHCR figures ``BENCH_SCREEN_RHCR_CACHE`` already holds (a
subset; it says which) and runs no RHCR.

Speed: 50 layouts x 5 seeds x 200 agents x 1,000 steps as one vmapped batch (after
compilation), and 101x102 with 1,400 agents x 5,000 steps (one run); each the best of
``BENCH_SCREEN_REPEATS`` (default 3) timed calls.

Scale (``BENCH_SCREEN_PARTS=scale``, not in the default set: minutes): the human 101x102
warehouse tiled 2x2 (202x204) with 5,600 agents x 5,000 steps.

Refit of the free-flow estimate's congested-layout share (``BENCH_SCREEN_PARTS=fit_congested``,
not in the default set: RHCR on the generator's seed-0 set, about 1.5 CPU-hours unless
``BENCH_SCREEN_RHCR_CACHE_SEED0`` holds it): prints the refitted coefficients beside
:data:`nca_qd.sim.free_flow.CONGESTED_MODEL` and both estimates' held-out Spearman on the
seed-1 set.

Fidelity at a large size (``BENCH_SCREEN_PARTS=fidelity_large``, not in the default set: about
2 CPU-hours at 101x102): every layout JSON of ``BENCH_SCREEN_LAYOUTS`` (a directory, e.g. an
evaluation's ``layouts/``; ``*_unrepaired.json`` skipped) with ``BENCH_SCREEN_LARGE_AGENTS``
agents (default 1000,1400), seeds ``BENCH_SCREEN_LARGE_SEEDS`` (default 0,1), T=1,000, in the
domain ``BENCH_SCREEN_LARGE_DOMAIN`` (default warehouse_even; the screen uses that domain's
crowding threshold): exact RHCR (threads: all CPUs; cached in ``BENCH_SCREEN_RHCR_CACHE`` if
set) against the screen, run by run and by each layout's majority verdict; where both flow,
the screen's throughput (raw, scaled by 1.3 and the free-flow estimate) against RHCR's.

Drift of a calibrated threshold (``BENCH_SCREEN_PARTS=crowd_drift``, not in the default set:
minutes of screening, no RHCR): the exactly-run layouts of a search's memo
(``BENCH_SCREEN_MEMO``, here default ``results/manufacturing_a5/eval_memo.npz``) from iteration
``BENCH_SCREEN_MEMO_FROM`` to ``BENCH_SCREEN_MEMO_UNTIL``, each threshold's majority verdicts
against RHCR's: a threshold fitted on a search's first, mostly random layouts may misjudge the
denser ones it finds later.

A domain's crowding threshold (``BENCH_SCREEN_PARTS=crowd_threshold``, not in the default set:
minutes of screening, no RHCR): the exactly-run layouts of a search's memo
(``BENCH_SCREEN_MEMO``, here default ``results/warehouse_uneven_a5/eval_memo.npz``; only the
iterations up to ``BENCH_SCREEN_MEMO_UNTIL``, default 28, the ones ``simulation.screen_crowd_mean``
of warehouse_uneven.yaml was calibrated on) in two random halves. On the calibration half the
screen runs under RHCR's rule alone, and the crowding rule is replayed on their crowding
records for each threshold (the same verdicts, stop times and throughputs as screening with it);
the threshold whose majority verdicts agree best with RHCR's is then screened for real on the
other half, beside the domain's configured threshold and the default (17): majority agreement,
Spearman of mean throughput, and the error of both estimates: scaled (1.3 x the screen's
throughput) and free flow (its efficiency fitted on the calibration half's flowing layouts,
the default congested share), so a domain's ``eval.screen_estimate`` is chosen on the same data.

Issue 20's fidelity set as it reads (``BENCH_SCREEN_PARTS=fidelity_mixed``, not in the default
set: about an hour of RHCR on 2 cores unless ``BENCH_SCREEN_RHCR_CACHE`` holds it): the 41
held-out synthetic layouts above plus ``BENCH_SCREEN_MIXED_N`` (default 14) layouts from each
of the three searches' memos (warehouse even and uneven, manufacturing; ``MIXED_SOURCES``:
only iterations no screen calibration used), each screened the way its domain's configuration
screens (crowding threshold, estimate) and run with exact RHCR seeds 0-9 at the search's node
budget (set ``BENCH_SCREEN_PBS_MAX_NODES=2000``). Prints, pooled and per group: RHCR's split
half (Spearman, majority agreement) beside the screen's against RHCR seeds 0-4.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np

from nca_qd.errors import NcaQdError
from nca_qd.io import load_map
from nca_qd.sim.free_flow import free_flow_throughput, rhcr_estimate
from nca_qd.sim.scenario import build_scenario

MAPS = Path("/work/shared/reference/maps/warehouse")
SCENARIO, AGENTS, T, SEEDS = "warehouse_even", 200, 1000, [0, 1, 2, 3, 4]
# Timed calls per speed figure (the best is reported: this machine's run-to-run spread is
# about 15 %).
REPEATS = int(os.environ.get("BENCH_SCREEN_REPEATS", 3))
_NODES = os.environ.get("BENCH_SCREEN_PBS_MAX_NODES", "auto")
PBS_MAX_NODES: int | str = int(_NODES) if _NODES.isdigit() else _NODES
# RHCR's share of free-flow throughput where it flows (warehouse even, 33x36, 200 agents),
# measured on the warehouse search's memo; the screen's scale for congested runs.
EFFICIENCY = float(os.environ.get("BENCH_SCREEN_EFFICIENCY", 0.932))
CONGESTED_SCALE = 1.3  # the scaled screen's (eval.screen_scale)


def _find(name: str) -> Path | None:
    env = os.environ.get("NCA_QD_MAPS")
    dirs = [Path(env) / "warehouse"] if env else []
    repo = Path(__file__).resolve().parents[1]
    for d in dirs + [repo / "maps" / "warehouse", MAPS]:
        if (d / name).is_file():
            return d / name
    return None


def _load(name: str) -> list[str] | None:
    p = _find(name)
    return None if p is None else load_map(p).rows


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


def make_layouts(n_min: int = 40, seed: int = 1) -> list[tuple[str, list[str]]]:
    """The fidelity set: (name, rows), all valid 33x36 warehouse layouts."""
    rng = np.random.default_rng(seed)
    out = []
    human = _load("human_33x36.json")
    paper = _load("paper_cma-mae_a5_even_33x36.json")
    unrep = _load("paper_cma-mae_a5_even_33x36_unrepaired.json")
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


def rhcr_figures(layouts, cache: str | None, seeds: list[int] = SEEDS, scenario: str = SCENARIO) -> dict:
    """name -> list of (throughput, success, CPU-s) over ``seeds``, exact RHCR, threads=1
    (cached under the layout's name for SEEDS, ``name@<first seed>`` for other seeds)."""
    from nca_qd.sim.rhcr import simulate_many

    done = json.loads(Path(cache).read_text()) if cache and Path(cache).is_file() else {}
    tag = "" if list(seeds) == SEEDS else f"@{seeds[0]}"
    for name, rows in layouts:
        if name + tag in done:
            continue
        runs = simulate_many(rows, scenario, AGENTS, T, list(seeds), threads=1, pbs_max_nodes=PBS_MAX_NODES)
        done[name + tag] = [[r.throughput, r.success, r.cpu_seconds] for r in runs]
        if cache:
            Path(cache).write_text(json.dumps(done))
    return {name: done[name + tag] for name, _ in layouts}


def split_half(layouts, exact: dict, cache: str | None) -> dict:
    """RHCR against itself: its mean throughput and majority verdict over SEEDS against those
    over the next as many seeds — the agreement no screen can be expected to exceed."""
    other = [s + len(SEEDS) for s in SEEDS]
    again = rhcr_figures(layouts, cache, other)
    names = [n for n, _ in layouts]
    a = np.array([np.mean([r[0] for r in exact[n]]) for n in names])
    b = np.array([np.mean([r[0] for r in again[n]]) for n in names])
    ok_a = np.array([np.mean([r[1] for r in exact[n]]) > 0.5 for n in names])
    ok_b = np.array([np.mean([r[1] for r in again[n]]) > 0.5 for n in names])
    return {
        "rhcr_split_half": f"seeds {SEEDS[0]}-{SEEDS[-1]} vs {other[0]}-{other[-1]}",
        "layouts": len(names),
        "spearman_mean_throughput": round(_spearman(a, b), 3),
        "congestion_agreement_layout_majority": round(float(np.mean(ok_a == ok_b)), 3),
        "mean_abs_throughput_difference": round(float(np.mean(np.abs(a - b))), 3),
    }


def _planners() -> list[str]:
    return [p for p in os.environ.get("BENCH_SCREEN_PLANNERS", "pibt,windowed").split(",") if p]


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


def _spearman(x, y) -> float:
    from scipy.stats import spearmanr

    return float(spearmanr(x, y).statistic)


def fidelity() -> None:
    layouts = make_layouts()
    cache = os.environ.get("BENCH_SCREEN_RHCR_CACHE")
    if os.environ.get("BENCH_SCREEN_CACHED_ONLY") and cache and Path(cache).is_file():
        held = json.loads(Path(cache).read_text())
        layouts = [(n, r) for n, r in layouts if n in held]
        print(
            f"subset: the {len(layouts)} layouts with cached RHCR figures: {', '.join(n for n, _ in layouts)}"
        )
    print(
        f"== fidelity: {len(layouts)} layouts 33x36, {SCENARIO}, {AGENTS} agents, T={T}, {len(SEEDS)} seeds"
    )
    t0 = time.perf_counter()
    exact = rhcr_figures(layouts, cache)
    print(f"rhcr: {time.perf_counter() - t0:.0f} s wall")
    names = [n for n, _ in layouts]
    ex_thr = np.array([np.mean([r[0] for r in exact[n]]) for n in names])
    ex_ok = np.array([[r[1] for r in exact[n]] for n in names], bool)
    # What no screen can beat: its random streams are not RHCR's, so at best it knows each
    # layout's chance of congesting, and per run it agrees with RHCR's majority outcome only.
    k = ex_ok.sum(1)
    ceiling = 1.0 - float(np.minimum(k, len(SEEDS) - k).sum()) / ex_ok.size
    print(f"per-run congestion agreement ceiling (RHCR's own seed-to-seed spread): {ceiling:.3f}")
    print(json.dumps(split_half(layouts, exact, cache)))
    flow = {n: free_flow_throughput(build_scenario(r, SCENARIO, n_agents=AGENTS), AGENTS) for n, r in layouts}
    setups = [("pibt", c) for c in ("crowding", "moved") if "pibt" in _planners()]
    setups += [("windowed", "moved")] if "windowed" in _planners() else []
    for planner, congestion in setups:
        screen, wall = screen_figures(layouts, congestion, planner)
        print(
            f"screen planner={planner} congestion={congestion}: {wall:.1f} s wall for the batch "
            f"({len(layouts) * len(SEEDS)} runs, compilation included)"
        )
        sc_thr = np.array([np.mean([r[0] for r in screen[n]]) for n in names])
        sc_ok = np.array([[r[1] for r in screen[n]] for n in names], bool)
        if congestion == "crowding" or planner == "windowed":
            for n, a, b, ea, sb in zip(names, ex_thr, sc_thr, ex_ok, sc_ok):
                print(f"  {n:22s} rhcr {a:6.3f} ok {ea.sum()}/5   screen {b:6.3f} ok {sb.sum()}/5")
        if planner == "pibt" and congestion == "moved":  # every run to the horizon: crowding alone
            crowd = np.array([np.mean([r[2] for r in screen[n]]) for n in names])
            print(
                f"spearman of RHCR mean throughput and minus the screen's mean crowding "
                f"(full-horizon runs): {_spearman(ex_thr, -crowd):.3f}"
            )
        rho = _spearman(ex_thr, sc_thr)
        if planner == "pibt":
            est = rhcr_estimate(
                [[r[0] for r in screen[n]] for n in names],
                [[r[1] for r in screen[n]] for n in names],
                [[r[3] for r in screen[n]] for n in names],
                [flow[n] for n in names],
                EFFICIENCY,
            )
            print(
                f"spearman of RHCR mean throughput and the screen's free-flow estimate "
                f"(efficiency {EFFICIENCY}): {_spearman(ex_thr, est):.3f} (raw screen: {rho:.3f})"
            )
        maj = float(np.mean((ex_ok.mean(1) > 0.5) == (sc_ok.mean(1) > 0.5)))
        run = float(np.mean(ex_ok == sc_ok))
        print(
            json.dumps(
                {
                    "planner": planner,
                    "congestion": congestion,
                    "layouts": len(names),
                    "spearman_mean_throughput": round(rho, 3),
                    "congestion_agreement_layout_majority": round(maj, 3),
                    "congestion_agreement_per_run": round(run, 3),
                    "rhcr_success_rate": round(float(ex_ok.mean()), 3),
                    "screen_success_rate": round(float(sc_ok.mean()), 3),
                }
            )
        )


# The mixed fidelity set's search layouts: (domain, its search's memo, the first and last
# iteration drawn from). The first is the first whose layouts no calibration of the screen saw:
# uneven traffic's threshold came from iterations 1-28, manufacturing's from 1-7; the warehouse
# (even) threshold and congested share came from the synthetic seed-0 set. The last is where
# the running searches stood when the figures in docs/benchmarks.md were measured, so that the
# memos' later iterations do not change the draw.
MIXED_SOURCES = (
    ("warehouse_even", "results/warehouse_even_a5/eval_memo.npz", 1, 200),
    ("warehouse_uneven", "results/warehouse_uneven_a5/eval_memo.npz", 29, 95),
    ("manufacturing", "results/manufacturing_a5/eval_memo.npz", 8, 24),
)


def _memo_sample(path: Path, iterations: tuple[int, int], n: int, seed: int) -> list[tuple[str, list[str]]]:
    """``n`` distinct exactly-run repaired layouts of a search's memo from the ``iterations``
    (first, last), drawn at random: (name, rows), the name carrying the memo's domain and the
    layout's key."""
    from nca_qd.io import array_to_rows
    from nca_qd.layouts import get_layout
    from nca_qd.scoring.keys import layout_key

    memo = np.load(path)
    scenario = json.loads(str(memo["fingerprint"]))["domain"]
    by_key = {layout_key(lay): i for i, lay in enumerate(memo["repair_layouts"])}
    keys = sorted(
        {
            bytes(k)
            for k, it in zip(memo["exact_keys"], memo["exact_iteration"])
            if iterations[0] <= it <= iterations[1]
        }
        & set(by_key)
    )
    pick = np.random.default_rng(seed).choice(len(keys), min(n, len(keys)), replace=False)
    tiles = get_layout(scenario, "domain").tiles
    return [
        (f"{scenario}:{keys[i].hex()[:16]}", array_to_rows(memo["repair_layouts"][by_key[keys[i]]], tiles))
        for i in sorted(pick)
    ]


def fidelity_mixed() -> None:
    """Issue 20's fidelity set as it reads: the held-out synthetic warehouse layouts (seed 1)
    plus layouts of the three searches (warehouse even and uneven, manufacturing) that no
    calibration saw; each screened as its domain's configuration screens it (threshold,
    estimate), against exact RHCR at the search's node budget, with RHCR's split half beside."""
    from experiments.cli import compose_config
    from nca_qd.domains import make_domain
    from nca_qd.scoring.mapf import MapfScorer

    cache = os.environ.get("BENCH_SCREEN_RHCR_CACHE")
    n = int(os.environ.get("BENCH_SCREEN_MIXED_N", 14))
    groups = [("synthetic", "warehouse_even", make_layouts())]
    for scenario, memo, first, last in MIXED_SOURCES:
        if Path(memo).is_file():
            groups.append(
                (f"{scenario}_search", scenario, _memo_sample(Path(memo), (first, last), n, seed=3))
            )
        else:
            print(f"fidelity_mixed: no memo at {memo}; its group is left out")
    other = [s + len(SEEDS) for s in SEEDS]
    rows_out: dict[str, list[np.ndarray]] = {}
    t0 = time.perf_counter()
    for group, scenario, layouts in groups:
        names = [name for name, _ in layouts]
        first = rhcr_figures(layouts, cache, SEEDS, scenario)
        second = rhcr_figures(layouts, cache, other, scenario)
        cfg = compose_config("run", [f"domain={scenario}", "eval.workers=0"])
        scorer = MapfScorer(make_domain(cfg.domain), cfg)
        thr, ok, stop, flow = scorer.screen_runs([rows for _, rows in layouts], SEEDS)
        if scorer.cfg.screen_estimate == "free_flow":
            est = rhcr_estimate(thr, ok, stop, flow, scorer.efficiency, scorer.cfg.screen_congested)
        else:
            est = thr.mean(1) * scorer.cfg.screen_scale
        columns = [
            [np.mean([r[0] for r in first[m]]) for m in names],  # RHCR mean, seeds 0-4
            [np.mean([r[0] for r in second[m]]) for m in names],  # seeds 5-9
            [np.mean([r[1] for r in first[m]]) > 0.5 for m in names],
            [np.mean([r[1] for r in second[m]]) > 0.5 for m in names],
            est,
            thr.mean(1),
            ok.mean(1) > 0.5,
        ]
        for key, col in zip(("a", "b", "ok_a", "ok_b", "est", "raw", "ok_s"), columns):
            rows_out.setdefault(key, []).append(np.asarray(col))
        rows_out.setdefault("group", []).append(np.array([group] * len(names)))
        rows_out.setdefault("estimate", []).append(np.array([scorer.cfg.screen_estimate] * len(names)))
    print(f"fidelity_mixed: {time.perf_counter() - t0:.0f} s wall (RHCR cached or run, screen)")
    col = {k: np.concatenate(v) for k, v in rows_out.items()}

    def figures(sel: np.ndarray) -> dict:
        a, b, est = col["a"][sel], col["b"][sel], col["est"][sel]
        return {
            "layouts": int(sel.sum()),
            "rhcr_split_half_spearman": round(_spearman(a, b), 3),
            "rhcr_split_half_majority": round(float(np.mean(col["ok_a"][sel] == col["ok_b"][sel])), 3),
            "screen_spearman": round(_spearman(a, est), 3),
            "screen_spearman_raw": round(_spearman(a, col["raw"][sel]), 3),
            "screen_majority": round(float(np.mean(col["ok_a"][sel] == col["ok_s"][sel])), 3),
            "rhcr_flow_share": round(float(np.mean(col["ok_a"][sel])), 3),
        }

    print(
        f"== fidelity_mixed: {len(col['a'])} held-out 33x36 layouts, {AGENTS} agents, T={T}, "
        f"RHCR seeds {SEEDS[0]}-{SEEDS[-1]} (screen, split half against {other[0]}-{other[-1]}), "
        f"pbs_max_nodes={PBS_MAX_NODES}"
    )
    print(json.dumps({"all": figures(np.ones(len(col["a"]), bool))}))
    for group in dict.fromkeys(col["group"]):
        sel = col["group"] == group
        print(json.dumps({str(group): {**figures(sel), "estimate": str(col["estimate"][sel][0])}}))


def _elite_before(memo, config_path: Path, layouts: np.ndarray) -> np.ndarray:
    """Per exact entry of a search's memo (its repaired ``layouts``), the result archive's elite
    in the entry's cell just before the entry's iteration (-inf: the cell was empty). The
    result archive takes every exactly-run layout with its mean exact throughput, so that elite
    is the best mean of the entries of earlier iterations in the same cell."""
    from omegaconf import OmegaConf

    from nca_qd.domains import make_domain
    from nca_qd.qd.archive import grid_cell_indices

    cfg = OmegaConf.load(config_path)
    domain = make_domain(cfg.domain)
    meas = np.concatenate(
        [np.asarray(domain.measures(layouts[a : a + 256])) for a in range(0, len(layouts), 256)]
    )
    spec = cfg.domain.measures
    cells = np.asarray(grid_cell_indices(meas, list(spec.cells), [list(r) for r in spec.ranges]))
    mean, it = memo["exact_throughput"].mean(1), memo["exact_iteration"]
    out = np.full(len(mean), -np.inf)
    best: dict[int, float] = {}
    for t in np.unique(it):  # in iteration order: a batch's layouts see the archive before it
        now = np.flatnonzero(it == t)
        out[now] = [best.get(int(c), -np.inf) for c in cells[now]]
        for i in now:
            best[int(cells[i])] = max(best.get(int(cells[i]), -np.inf), float(mean[i]))
    return out


def search_layouts() -> None:
    """The screen on the search's own layouts: a random sample of a memo's exactly-run layouts."""
    from nca_qd.io import array_to_rows
    from nca_qd.layouts import get_layout
    from nca_qd.scoring.keys import layout_key
    from nca_qd.sim.screen import simulate_scenarios

    path = Path(os.environ.get("BENCH_SCREEN_MEMO", "results/warehouse_even_a5/eval_memo.npz"))
    if not path.is_file():
        print(f"search: no memo at {path} (set BENCH_SCREEN_MEMO)")
        return
    memo = np.load(path)
    if json.loads(str(memo["fingerprint"]))["domain"] != SCENARIO:
        print(f"search: {path} is not a {SCENARIO} memo")
        return
    by_key = {layout_key(lay): i for i, lay in enumerate(memo["repair_layouts"])}
    known = [(by_key[bytes(k)], tp) for k, tp in zip(memo["exact_keys"], memo["exact_throughput"])]
    config = path.parent / "config.yaml"
    elite_all = (
        _elite_before(memo, config, memo["repair_layouts"][[i for i, _ in known]])
        if config.is_file()
        else None
    )
    rng = np.random.default_rng(0)
    n = min(int(os.environ.get("BENCH_SCREEN_SEARCH_N", 300)), len(known))
    pick = rng.choice(len(known), n, replace=False)
    tiles = get_layout(SCENARIO, "domain").tiles
    scens = [
        build_scenario(array_to_rows(memo["repair_layouts"][known[i][0]], tiles), SCENARIO) for i in pick
    ]
    exact = np.array([known[i][1] for i in pick])  # [n, 5]
    flow = np.array([free_flow_throughput(s, AGENTS) for s in scens])
    print(f"== search layouts: {n} of the {len(known)} exactly-run layouts of {path}, 5 screen seeds")
    t0 = time.perf_counter()
    runs = [row for a in range(0, n, 64) for row in simulate_scenarios(scens[a : a + 64], AGENTS, T, SEEDS)]
    print(f"screen: {time.perf_counter() - t0:.0f} s wall")
    thr = np.array([[r.throughput for r in row] for row in runs])
    ok = np.array([[r.success for r in row] for row in runs])
    stop = np.array([[r.stop_time / T for r in row] for row in runs])
    fit, test = np.arange(n) < n // 2, np.arange(n) >= n // 2
    flows = fit & (exact / flow[:, None] > 0.85).all(1)  # all 5 RHCR runs flowed
    eff = float(np.mean(exact[flows] / flow[flows, None]))
    est = rhcr_estimate(thr, ok, stop, flow, eff)
    truth = exact.mean(1)
    top = max(1, test.sum() // 10)

    def top_overlap(pred):
        idx = np.flatnonzero(test)
        return len(set(idx[np.argsort(-pred[test])[:top]]) & set(idx[np.argsort(-truth[test])[:top]]))

    out = {
        "layouts_scored": int(test.sum()),
        "efficiency_fitted": round(eff, 4),
        "fit_layouts": int(flows.sum()),
    }
    for name, pred in (("screen", thr.mean(1)), ("free_flow_estimate", est), ("free_flow_alone", flow)):
        out[name] = {
            "spearman": round(_spearman(truth[test], pred[test]), 3),
            f"top_{top}": top_overlap(pred),
        }
    out["rhcr_share_below_6"] = round(float(np.mean(truth < 6.0)), 3)
    print(json.dumps(out))
    if elite_all is None:
        return
    # The search's decision replayed: with the result archive as it was when each layout came,
    # does a prediction x (1 + exact_margin) reach its cell's elite (an exact run follows)?
    # "improvers": the layouts whose exact mean beat that elite (they entered the archive).
    # The memo only holds layouts the search chose (scaled screen, or the random check share),
    # so these figures favour the scaled screen.
    elite = elite_all[pick]
    occ = test & np.isfinite(elite)
    better = truth > elite
    choice = {"layouts_in_occupied_cells": int(occ.sum()), "improvers": int((occ & better).sum())}
    for name, pred in (("screen_scaled", CONGESTED_SCALE * thr.mean(1)), ("free_flow_estimate", est)):
        err = pred[occ] - truth[occ]
        choice[name] = {"bias": round(float(err.mean()), 3), "mae": round(float(np.abs(err).mean()), 3)}
        for margin in (0.1, 0.05, 0.03, 0.0):  # eval.exact_margin (the search's: 0.1)
            chosen = pred * (1 + margin) >= elite
            choice[name][f"margin_{margin}"] = {
                "improvers_chosen": int((occ & better & chosen).sum()),
                "others_chosen": int((occ & ~better & chosen).sum()),
            }
    print(json.dumps(choice))


def _one_big_run(rows: list[str], n: int, steps: int, repeats: int = 1, planner: str = "pibt"):
    """One run with RHCR's congestion rule alone: (seconds to compile + 10 steps, seconds for
    ``steps`` steps in each of ``repeats`` calls (the first compiles the ``steps`` horizon),
    its result)."""
    from nca_qd.sim.screen import simulate_batch

    t0 = time.perf_counter()
    simulate_batch([rows], SCENARIO, n, 10, [0], congestion="moved", planner=planner)
    comp = time.perf_counter() - t0
    walls = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        r = simulate_batch([rows], SCENARIO, n, steps, [0], congestion="moved", planner=planner)[0][0]
        walls.append(time.perf_counter() - t0)
    return comp, walls, r


def speed() -> None:
    for planner in _planners():
        speed_one(planner)


def speed_one(planner: str) -> None:
    from nca_qd.sim.screen import simulate_batch

    layouts = make_layouts(50)[:50]
    rows = [r for _, r in layouts]
    print(
        f"== speed, planner={planner} (congestion='moved', so runs go the full horizon unless "
        f"congested): {len(rows)} layouts x {len(SEEDS)} seeds x {AGENTS} agents x {T} steps"
    )
    t0 = time.perf_counter()
    simulate_batch(rows, SCENARIO, AGENTS, T, SEEDS, congestion="moved", planner=planner)
    first = time.perf_counter() - t0
    walls, cpus = [], []
    for _ in range(REPEATS):
        t0, c0 = time.perf_counter(), time.process_time()
        res = simulate_batch(rows, SCENARIO, AGENTS, T, SEEDS, congestion="moved", planner=planner)
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    print(
        f"first call (with compilation) {first:.1f} s; after compilation, best of {REPEATS}: "
        f"{min(walls):.1f} s wall, {cpus[int(np.argmin(walls))]:.1f} s CPU (all: "
        f"{', '.join(f'{w:.1f}' for w in walls)} s); "
        f"mean throughput {np.mean([r.throughput for x in res for r in x]):.3f}, "
        f"success {np.mean([r.success for x in res for r in x]):.2f}"
    )
    big = _load("human_101x102.json")
    if big is None:
        print("human_101x102.json not found, skipped")
        return
    n, steps = 1400, int(os.environ.get("BENCH_SCREEN_BIG_T", 5000))
    comp, walls, r = _one_big_run(big, n, steps, max(2, REPEATS), planner)
    print(
        f"101x102, {n} agents x {steps} steps, planner={planner}: {min(walls[1:]):.1f} s wall after "
        f"compilation (best of {len(walls) - 1}; distance table included; the first call, which "
        f"compiles this horizon, {walls[0]:.1f} s; compile+10 steps {comp:.1f} s); "
        f"throughput {r.throughput:.3f}, "
        f"success {r.success}, stop_time {r.stop_time}"
    )


def tiled(rows: list[str], ty: int, tx: int) -> list[str]:
    """A layout repeated ``ty`` x ``tx`` times (a larger warehouse of the same pattern)."""
    return [r * tx for r in rows] * ty


def scale() -> None:
    """Beyond the paper's sizes: the human 101x102 warehouse tiled (BENCH_SCREEN_TILES, default
    2x2 -> 202x204) with BENCH_SCREEN_SCALE_AGENTS agents (default 5,600: the 101x102 density of
    1,400) for 5,000 steps, one run, RHCR's congestion rule alone; prints the wall time."""
    big = _load("human_101x102.json")
    if big is None:
        print("human_101x102.json not found, skipped")
        return
    ty, tx = (int(v) for v in os.environ.get("BENCH_SCREEN_TILES", "2x2").split("x"))
    n = int(os.environ.get("BENCH_SCREEN_SCALE_AGENTS", 1400 * ty * tx))
    steps = int(os.environ.get("BENCH_SCREEN_BIG_T", 5000))
    rows = tiled(big, ty, tx)
    comp, walls, r = _one_big_run(rows, n, steps)
    print(
        f"== scale: {len(rows)}x{len(rows[0])} ({ty}x{tx} human 101x102), {n} agents x {steps} "
        f"steps: {walls[0]:.1f} s wall (compiling this horizon included; compile+10 steps "
        f"{comp:.1f} s); "
        f"throughput {r.throughput:.3f}, success {r.success}, stop_time {r.stop_time}"
    )


def fidelity_large() -> None:
    """Screen against exact RHCR at a large size, run by run and layout by layout (majority
    verdicts; where both flow, the screen's throughput estimates against RHCR's)."""
    from omegaconf import OmegaConf

    from experiments.cli import compose_config
    from nca_qd.sim.rhcr import simulate_many
    from nca_qd.sim.screen import crowd_mean_for, simulate_scenarios

    folder = os.environ.get("BENCH_SCREEN_LAYOUTS")
    if not folder or not Path(folder).is_dir():
        print("fidelity_large: set BENCH_SCREEN_LAYOUTS to a directory of layout JSON files")
        return
    files = sorted(f for f in Path(folder).glob("*.json") if not f.stem.endswith("_unrepaired"))
    layouts = [(f.stem, load_map(f).rows) for f in files]
    shapes = {(len(r), len(r[0])) for _, r in layouts}
    if len(shapes) != 1:
        print(f"fidelity_large: the layouts must share one size, got {sorted(shapes)}")
        return
    domain = os.environ.get("BENCH_SCREEN_LARGE_DOMAIN", SCENARIO)
    crowd = crowd_mean_for(OmegaConf.to_container(compose_config("run", [f"domain={domain}"]).domain))
    agents = [int(a) for a in os.environ.get("BENCH_SCREEN_LARGE_AGENTS", "1000,1400").split(",")]
    seeds = [int(s) for s in os.environ.get("BENCH_SCREEN_LARGE_SEEDS", "0,1").split(",")]
    steps = 1000
    cache = os.environ.get("BENCH_SCREEN_RHCR_CACHE")
    done = json.loads(Path(cache).read_text()) if cache and Path(cache).is_file() else {}
    ((h, w),) = shapes
    print(
        f"== fidelity at {h}x{w} ({domain}, crowding threshold {crowd}): {len(layouts)} layouts x "
        f"{agents} agents x seeds {seeds}, T={steps}"
    )
    agree, majority, ratios = [], [], {"raw": [], "scaled": [], "free_flow": []}
    for n in agents:
        scens = [build_scenario(r, domain, n_agents=n, source=name) for name, r in layouts]
        screened = simulate_scenarios(scens, n, steps, seeds, crowd_mean=crowd)
        for (name, rows), scen, sc in zip(layouts, scens, screened):
            key = f"{name}|{h}x{w}|{n}|{steps}" + ("" if domain == SCENARIO else f"|{domain}")
            known = done.get(key, {})
            if isinstance(known, list):  # the older cache: a list for seeds 0, 1, ...
                known = {str(i): run for i, run in enumerate(known)}
            missing = [s for s in seeds if str(s) not in known]
            if missing:  # RHCR for the seeds not cached yet
                more = simulate_many(rows, domain, n, steps, missing)
                known.update({str(s): [r.throughput, r.success, r.stop_time] for s, r in zip(missing, more)})
                done[key] = known
                if cache:
                    Path(cache).write_text(json.dumps(done))
            exact = [known[str(s)] for s in seeds]
            for (tp, ok, stop), r in zip(exact, sc):
                agree.append(bool(ok) == bool(r.success))
                print(
                    f"  {name:28s} {n:5d} agents  rhcr {'ok ' if ok else 'CON'} stop {stop:5d} "
                    f"tp {tp:6.2f} | screen {'ok ' if r.success else 'CON'} stop "
                    f"{r.stop_time:5d} tp {r.throughput:6.2f}"
                )
            ex_ok = np.array([e[1] for e in exact], bool)
            sc_ok = np.array([r.success for r in sc], bool)
            majority.append((ex_ok.mean() > 0.5) == (sc_ok.mean() > 0.5))
            if ex_ok.mean() > 0.5 and sc_ok.mean() > 0.5:  # both flow: the estimates against RHCR
                rhcr_tp = float(np.mean([e[0] for e in exact if e[1]]))
                raw = float(np.mean([r.throughput for r in sc if r.success]))
                flow = free_flow_throughput(scen, n)
                estimates = {"raw": raw, "scaled": CONGESTED_SCALE * raw, "free_flow": EFFICIENCY * flow}
                for kind, value in estimates.items():
                    ratios[kind].append(value / rhcr_tp)
                shares = ", ".join(f"{kind} x{value / rhcr_tp:.3f}" for kind, value in estimates.items())
                print(f"    both flow: RHCR {rhcr_tp:.2f}, screen {raw:.2f}; {shares} (free flow {flow:.2f})")
    print(
        json.dumps(
            {
                "size": f"{h}x{w}",
                "domain": domain,
                "runs": len(agree),
                "congestion_agreement_per_run": round(float(np.mean(agree)), 3),
                "layout_cases": len(majority),
                "congestion_agreement_layout_majority": round(float(np.mean(majority)), 3),
                "both_flow": len(ratios["raw"]),
                **{
                    f"throughput_ratio_{k}": [round(float(np.min(v)), 3), round(float(np.max(v)), 3)]
                    for k, v in ratios.items()
                    if v
                },
            }
        )
    )


def fit_congested() -> None:
    """Refit :data:`nca_qd.sim.free_flow.CONGESTED_MODEL`: least squares of RHCR's share of
    free flow on the layouts of the generator's seed-0 set with a congested screened run, then
    the held-out Spearman on the seed-1 set (the fidelity part's layouts)."""
    from nca_qd.sim.free_flow import CONGESTED_MODEL

    def figures(seed: int, cache: str | None):
        layouts = make_layouts(seed=seed)
        names = [n for n, _ in layouts]
        exact = rhcr_figures(layouts, cache)
        screen, _ = screen_figures(layouts, "crowding")
        flow = np.array([free_flow_throughput(build_scenario(r, SCENARIO), AGENTS) for _, r in layouts])
        per_run = np.array([screen[n] for n in names])  # [n, seeds, 4]
        y = np.array([np.mean([r[0] for r in exact[n]]) for n in names])
        return per_run[..., 0], per_run[..., 1] > 0.5, per_run[..., 3], flow, y

    cache = os.environ.get("BENCH_SCREEN_RHCR_CACHE")
    fit_cache = os.environ.get("BENCH_SCREEN_RHCR_CACHE_SEED0")  # the seed-0 set's own cache
    thr, ok, stop, flow, y = figures(0, fit_cache)
    some = ~ok.all(1)
    design = np.column_stack([np.ones(some.sum()), thr[some].mean(1) / flow[some], stop[some].mean(1)])
    coef, *_ = np.linalg.lstsq(design, y[some] / flow[some], rcond=None)
    thr1, ok1, stop1, flow1, y1 = figures(1, cache)
    out = {
        "fit_layouts": int(some.sum()),
        "coefficients": [round(float(c), 3) for c in coef],
        "shipped": list(CONGESTED_MODEL),
        "held_out_spearman_refit": round(
            _spearman(y1, rhcr_estimate(thr1, ok1, stop1, flow1, EFFICIENCY, tuple(coef))), 3
        ),
        "held_out_spearman_shipped": round(
            _spearman(y1, rhcr_estimate(thr1, ok1, stop1, flow1, EFFICIENCY)), 3
        ),
    }
    print(json.dumps(out))


def _crowd_replay(crowd, tasks, stop0, ok0, threshold: float, replan: int = 5):
    """The crowding rule replayed on runs made under RHCR's rule alone (``crowd`` [n, S, checks],
    ``tasks`` [n, S, T], their stop times and verdicts): (success, throughput) per run had the
    screen used ``threshold``."""
    from nca_qd.sim.screen import CROWD_MIN_CHECKS

    n_checks = np.arange(1, crowd.shape[-1] + 1)
    made = n_checks * replan <= stop0[..., None]  # the checks each run reached
    hit = made & (n_checks >= CROWD_MIN_CHECKS) & (np.cumsum(crowd, -1) >= threshold * n_checks)
    first = np.where(hit.any(-1), hit.argmax(-1), -1)
    stop = np.where(first >= 0, replan * (first + 1), stop0)
    done = np.cumsum(tasks, -1)
    thr = np.take_along_axis(done, (stop - 1)[..., None], -1)[..., 0] / tasks.shape[-1]
    return ok0 & (first < 0), thr


def _replay_records(runs):
    """Screened runs made under RHCR's rule alone ([layout][seed]) as the arrays
    ``_crowd_replay`` reads: crowding per check, tasks per step, stop times, verdicts."""
    crowd = np.zeros((len(runs), len(SEEDS), T // 5))
    tasks = np.zeros((len(runs), len(SEEDS), T))
    for i, row in enumerate(runs):
        for s, r in enumerate(row):
            crowd[i, s, : len(r.crowding)] = r.crowding
            tasks[i, s] = r.tasks_per_step
    stop0 = np.array([[r.stop_time for r in row] for row in runs])
    ok0 = np.array([[r.success for r in row] for row in runs])
    return crowd, tasks, stop0, ok0


def _memo_exact_layouts(memo, lo: int, hi: int):
    """A search memo's exactly-run layouts of iterations ``lo``..``hi``: the domain, their
    indices among the memo's exact entries, and a function giving any entries' scenarios."""
    from nca_qd.io import array_to_rows
    from nca_qd.layouts import get_layout
    from nca_qd.scoring.keys import layout_key

    scenario = json.loads(str(memo["fingerprint"]))["domain"]
    tiles = get_layout(scenario, "domain").tiles
    by_key = {layout_key(lay): i for i, lay in enumerate(memo["repair_layouts"])}
    entries = [
        j
        for j, k in enumerate(memo["exact_keys"])
        if bytes(k) in by_key and lo <= memo["exact_iteration"][j] <= hi
    ]

    def scenarios(entries_):
        return [
            build_scenario(
                array_to_rows(memo["repair_layouts"][by_key[bytes(memo["exact_keys"][j])]], tiles), scenario
            )
            for j in entries_
        ]

    return scenario, entries, scenarios


def _screen_in_chunks(scens, congestion: str, threshold: float | None = None):
    """Screen scenarios 64 at a time (AGENTS, T, SEEDS): [scenario][seed] runs."""
    from nca_qd.sim.screen import CROWD_MEAN, simulate_scenarios

    crowd_mean = CROWD_MEAN if threshold is None else threshold
    return [
        row
        for a in range(0, len(scens), 64)
        for row in simulate_scenarios(
            scens[a : a + 64], AGENTS, T, SEEDS, congestion=congestion, crowd_mean=crowd_mean
        )
    ]


def crowd_drift() -> None:
    """Whether a crowding threshold calibrated on a search's first iterations still judges the
    layouts the search runs exactly later: each exactly-run layout of the memo's iterations
    ``BENCH_SCREEN_MEMO_FROM``..``BENCH_SCREEN_MEMO_UNTIL``, screened (200 agents, T=1,000, 5
    seeds) under RHCR's rule alone and the crowding rule replayed per threshold; majority
    verdicts against RHCR's, and the layouts each side alone calls congested."""
    path = Path(os.environ.get("BENCH_SCREEN_MEMO", "results/manufacturing_a5/eval_memo.npz"))
    if not path.is_file():
        print(f"crowd_drift: no memo at {path} (set BENCH_SCREEN_MEMO)")
        return
    lo = int(os.environ.get("BENCH_SCREEN_MEMO_FROM", 0))
    hi = int(os.environ.get("BENCH_SCREEN_MEMO_UNTIL", 10**9))
    memo = np.load(path)
    _, entries, scenarios = _memo_exact_layouts(memo, lo, hi)
    crowd, tasks, stop0, ok0 = _replay_records(_screen_in_chunks(scenarios(entries), "moved"))
    rhcr = memo["exact_success"][entries].astype(bool).mean(1) > 0.5
    print(
        json.dumps(
            {
                "memo": str(path),
                "iterations": [lo, min(hi, int(memo["exact_iteration"].max()))],
                "layouts": len(entries),
                "rhcr_flows": int(rhcr.sum()),
            }
        )
    )
    for x in np.arange(16.0, 30.01, 2.0):
        flows = _crowd_replay(crowd, tasks, stop0, ok0, float(x))[0].mean(1) > 0.5
        print(
            json.dumps(
                {
                    "threshold": float(x),
                    "majority_agreement": round(float(np.mean(flows == rhcr)), 3),
                    "rhcr_flows_screen_congests": int(np.sum(rhcr & ~flows)),
                    "rhcr_congests_screen_flows": int(np.sum(~rhcr & flows)),
                }
            )
        )


def crowd_threshold() -> None:
    """Calibrate a domain's crowding threshold on half a search's memo, check it on the rest."""
    from omegaconf import OmegaConf

    from experiments.cli import compose_config
    from nca_qd.sim.screen import CROWD_MEAN, crowd_mean_for

    path = Path(os.environ.get("BENCH_SCREEN_MEMO", "results/warehouse_uneven_a5/eval_memo.npz"))
    if not path.is_file():
        print(f"crowd_threshold: no memo at {path} (set BENCH_SCREEN_MEMO)")
        return
    until = int(os.environ.get("BENCH_SCREEN_MEMO_UNTIL", 28))
    memo = np.load(path)
    scenario, entries, scenarios = _memo_exact_layouts(memo, int(memo["exact_iteration"].min()), until)
    configured = crowd_mean_for(OmegaConf.to_container(compose_config("run", [f"domain={scenario}"]).domain))
    order = np.random.default_rng(2).permutation(entries)
    halves = {"calibration": np.sort(order[: len(order) // 2]), "check": np.sort(order[len(order) // 2 :])}

    def screen(entries_, congestion, threshold=CROWD_MEAN):
        return _screen_in_chunks(scenarios(entries_), congestion, threshold)

    def verdicts(entries_):
        ok = memo["exact_success"][entries_].astype(bool)
        return ok.mean(1) > 0.5, memo["exact_throughput"][entries_].mean(1)

    cal = halves["calibration"]
    print(
        f"== crowding threshold: {scenario}, {len(entries)} exactly-run layouts of {path} "
        f"(iterations <= {until}), {len(cal)} to calibrate on, {len(halves['check'])} to check"
    )
    crowd, tasks, stop0, ok0 = _replay_records(screen(cal, "moved"))
    rhcr_ok, _ = verdicts(cal)
    grid = np.arange(14.0, 30.01, 0.25)
    agree = [
        float(np.mean((_crowd_replay(crowd, tasks, stop0, ok0, x)[0].mean(1) > 0.5) == rhcr_ok)) for x in grid
    ]
    best = float(grid[int(np.argmax(agree))])
    print(json.dumps({"calibration_best_threshold": best, "calibration_agreement": round(max(agree), 3)}))

    # The free-flow estimate's efficiency (RHCR's share of free flow where it flows), fitted
    # as a search fits it: the mean share over the calibration half's flowing RHCR runs.
    def free_flows(entries_):
        return np.array([free_flow_throughput(scen, AGENTS) for scen in scenarios(entries_)])

    flowed = memo["exact_success"][cal].astype(bool)
    shares = (memo["exact_throughput"][cal] / free_flows(cal)[:, None])[flowed]
    efficiency = float(shares.mean())
    print(json.dumps({"free_flow_efficiency": round(efficiency, 4), "fitted_on_runs": int(flowed.sum())}))
    chk = halves["check"]
    rhcr_ok, rhcr_thr = verdicts(chk)
    flow_chk = free_flows(chk)
    for x in sorted({best, configured, CROWD_MEAN}):
        t0 = time.perf_counter()
        res = screen(chk, "crowding", x)
        ok = np.array([[r.success for r in row] for row in res])
        thr = np.array([[r.throughput for r in row] for row in res]).mean(1)
        err = CONGESTED_SCALE * thr - rhcr_thr
        stop = np.array([[r.stop_time / T for r in row] for row in res])
        run_thr = np.array([[r.throughput for r in row] for row in res])
        est = rhcr_estimate(run_thr, ok, stop, flow_chk, efficiency)
        print(
            json.dumps(
                {
                    "threshold": x,
                    "layouts": len(chk),
                    "screen_run_success": round(float(ok.mean()), 3),
                    "rhcr_run_success": round(float(memo["exact_success"][chk].mean()), 3),
                    "majority_agreement": round(float(np.mean((ok.mean(1) > 0.5) == rhcr_ok)), 3),
                    "spearman": round(_spearman(rhcr_thr, thr), 3),
                    "scaled_mae": round(float(np.abs(err).mean()), 3),
                    "scaled_bias": round(float(err.mean()), 3),
                    "free_flow_spearman": round(_spearman(rhcr_thr, est), 3),
                    "free_flow_mae": round(float(np.abs(est - rhcr_thr).mean()), 3),
                    "free_flow_bias": round(float((est - rhcr_thr).mean()), 3),
                    "wall_s": round(time.perf_counter() - t0),
                }
            )
        )


def main() -> None:
    parts = os.environ.get("BENCH_SCREEN_PARTS", "fidelity,speed").split(",")
    if "scale" in parts:
        scale()
    if "speed" in parts:
        speed()
    if "fidelity" in parts:
        fidelity()
    if "search" in parts:
        search_layouts()
    if "fidelity_large" in parts:
        fidelity_large()
    if "fit_congested" in parts:
        fit_congested()
    if "crowd_threshold" in parts:
        crowd_threshold()
    if "crowd_drift" in parts:
        crowd_drift()
    if "fidelity_mixed" in parts:
        fidelity_mixed()


if __name__ == "__main__":
    main()
