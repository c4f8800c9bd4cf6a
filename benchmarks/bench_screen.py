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
``results/warehouse_even_qd/cma_mae_a5_s0/eval_memo.npz``), whose exact RHCR throughputs (5 seeds, T=1,000,
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

Fidelity at a large size (``BENCH_SCREEN_PARTS=fidelity_large``, not in the default set: about
2 CPU-hours at 101x102): every layout JSON of ``BENCH_SCREEN_LAYOUTS`` (a directory, e.g. an
evaluation's ``layouts/``; ``*_unrepaired.json`` skipped) with ``BENCH_SCREEN_LARGE_AGENTS``
agents (default 1000,1400), seeds ``BENCH_SCREEN_LARGE_SEEDS`` (default 0,1), T=1,000, in the
domain ``BENCH_SCREEN_LARGE_DOMAIN`` (default warehouse_even; the screen uses that domain's
crowding threshold): exact RHCR (threads: all CPUs; cached in ``BENCH_SCREEN_RHCR_CACHE`` if
set) against the screen, run by run and by each layout's majority verdict; where both flow,
the screen's throughput (raw, scaled by 1.3 and the free-flow estimate) against RHCR's.

The fits of constants the product uses (the congested-layout share of the free-flow estimate,
a domain's crowding threshold, a threshold's drift; formerly the parts ``fit_congested``,
``crowd_threshold``, ``crowd_drift`` here) are the product's: ``python -m experiments.calibrate``
(:mod:`nca_qd.calibration`). This benchmark draws its layouts from the same set.

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

from nca_qd.calibration import layout_set
from nca_qd.calibration.layout_set import AGENTS, SCENARIO, SEEDS, T, screen_figures, spearman
from nca_qd.io import load_map
from nca_qd.sim.free_flow import free_flow_throughput, rhcr_estimate
from nca_qd.sim.scenario import build_scenario

MAPS = Path("/work/shared/reference/maps/warehouse")
# Timed calls per speed figure (the best is reported: this machine's run-to-run spread is
# about 15 %).
REPEATS = int(os.environ.get("BENCH_SCREEN_REPEATS", 3))
_NODES = os.environ.get("BENCH_SCREEN_PBS_MAX_NODES", "auto")
PBS_MAX_NODES: int | str = int(_NODES) if _NODES.isdigit() else _NODES
# RHCR's share of free-flow throughput where it flows (warehouse even, 33x36, 200 agents),
# measured on the warehouse search's memo; the screen's scale for congested runs.
EFFICIENCY = float(os.environ.get("BENCH_SCREEN_EFFICIENCY", 0.932))
CONGESTED_SCALE = 1.3  # the scaled screen's (eval.screen_scale)


def _maps() -> Path | None:
    """The folder of the paper's 33x36 warehouse maps (``NCA_QD_MAPS``/warehouse, else the
    shared reference copy), or None."""
    env = os.environ.get("NCA_QD_MAPS")
    for d in ([Path(env) / "warehouse"] if env else []) + [MAPS]:
        if (d / "human_33x36.json").is_file():
            return d
    return None


def _load(name: str) -> list[str] | None:
    maps = _maps()
    return None if maps is None else layout_set._load(maps, name)


def make_layouts(n_min: int = 40, seed: int = 1) -> list[tuple[str, list[str]]]:
    return layout_set.make_layouts(_maps(), n_min, seed)


def rhcr_figures(layouts, cache: str | None, seeds: list[int] = SEEDS, scenario: str = SCENARIO) -> dict:
    return layout_set.rhcr_figures(layouts, cache, seeds, scenario, PBS_MAX_NODES)


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
        "spearman_mean_throughput": round(spearman(a, b), 3),
        "congestion_agreement_layout_majority": round(float(np.mean(ok_a == ok_b)), 3),
        "mean_abs_throughput_difference": round(float(np.mean(np.abs(a - b))), 3),
    }


def _planners() -> list[str]:
    return [p for p in os.environ.get("BENCH_SCREEN_PLANNERS", "pibt,windowed").split(",") if p]


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
                f"(full-horizon runs): {spearman(ex_thr, -crowd):.3f}"
            )
        rho = spearman(ex_thr, sc_thr)
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
                f"(efficiency {EFFICIENCY}): {spearman(ex_thr, est):.3f} (raw screen: {rho:.3f})"
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
# memos' later iterations do not change the draw. (The figures of 2026-11-27 drew their even
# layouts from results/warehouse_even_a5, which left the tree on 2026-11-29 for the comparison's
# arm: `git checkout ee3c4c2 -- results/warehouse_even_a5` brings it back.)
MIXED_SOURCES = (
    ("warehouse_even", "results/warehouse_even_qd/cma_mae_a5_s0/eval_memo.npz", 1, 200),
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
    """The fits of constants the product uses (the congested-layout share of the free-flow estimate,
    a domain's crowding threshold, a threshold's drift; formerly the parts ``fit_congested``,
    ``crowd_threshold``, ``crowd_drift`` here) are the product's: ``python -m experiments.calibrate``
    (:mod:`nca_qd.calibration`). This benchmark draws its layouts from the same set.

    Issue 20's fidelity set as it reads: the held-out synthetic warehouse layouts (seed 1)
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
            "rhcr_split_half_spearman": round(spearman(a, b), 3),
            "rhcr_split_half_majority": round(float(np.mean(col["ok_a"][sel] == col["ok_b"][sel])), 3),
            "screen_spearman": round(spearman(a, est), 3),
            "screen_spearman_raw": round(spearman(a, col["raw"][sel]), 3),
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

    path = Path(os.environ.get("BENCH_SCREEN_MEMO", "results/warehouse_even_qd/cma_mae_a5_s0/eval_memo.npz"))
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
            "spearman": round(spearman(truth[test], pred[test]), 3),
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
    moved = {"fit_congested": "congested", "crowd_threshold": "crowd_threshold", "crowd_drift": "crowd_drift"}
    for part in parts:
        if part in moved:  # fits of constants the product uses are the product's (nca_qd.calibration)
            print(f"{part}: now python -m experiments.calibrate fit={moved[part]} (nca_qd/calibration)")
    if "fidelity_mixed" in parts:
        fidelity_mixed()


if __name__ == "__main__":
    main()
