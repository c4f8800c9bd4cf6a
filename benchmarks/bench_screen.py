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

The parts on the searches' own layouts (``search``, ``fidelity_mixed``) live in
:mod:`benchmarks.screen_search`, the one at a large size (``fidelity_large``) in
:mod:`benchmarks.screen_large`; what the parts share in :mod:`benchmarks.screen_common`.

The fits of constants the product uses (the congested-layout share of the free-flow estimate,
a domain's crowding threshold, a threshold's drift; formerly the parts ``fit_congested``,
``crowd_threshold``, ``crowd_drift`` here) are the product's: ``python -m experiments.calibrate``
(:mod:`nca_qd.calibration`). This benchmark draws its layouts from the same set.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np

from benchmarks.screen_common import (
    EFFICIENCY,
    _load,
    _planners,
    make_layouts,
    rhcr_figures,
)
from benchmarks.screen_large import fidelity_large
from benchmarks.screen_search import fidelity_mixed, search_layouts
from nca_qd.calibration.layout_set import AGENTS, SCENARIO, SEEDS, T, screen_figures, spearman
from nca_qd.sim.free_flow import free_flow_throughput, rhcr_estimate
from nca_qd.sim.scenario import build_scenario

# Timed calls per speed figure (the best is reported: this machine's run-to-run spread is
# about 15 %).
REPEATS = int(os.environ.get("BENCH_SCREEN_REPEATS", 3))


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
