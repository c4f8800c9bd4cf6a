"""Cost of one warehouse / manufacturing QD iteration at the paper's settings (``make bench``).

Runs a few CMA-MAE iterations (5 emitters x 10 NCA generators at 33x36, 200 agents, T=1,000,
N_e=5) in a temporary directory and prints the mean per-iteration wall time, its split
(generate / repair / screen / exact RHCR), the exact runs made, the screen's error on them, and
the projected wall time of the paper's 10,000-evaluation search (target: <= 24 h on 2 cores;
the paper's cluster runs cost hundreds of CPU-hours).

    python -m benchmarks.bench_search [--domain warehouse_even] [--iters 4]
    python -m benchmarks.bench_search --run-dir /path/to/run     # summarise a run's metrics.csv
    python -m benchmarks.bench_search --run-dir /path/to/run --iterations 12-40
    python -m benchmarks.bench_search --replay-early-stop results/warehouse_even_qd/cma_mae_a5_s0  # replayed
    python -m benchmarks.bench_search --exact-floor results/warehouse_even_qd/cma_mae_a5_s0

The first iteration includes JAX compilation (NCA, screen) and the worker pool's start and is
reported apart. Early iterations send most layouts to exact RHCR (the result archive is empty);
later ones fewer, so a projection from early iterations is pessimistic.
"""

from __future__ import annotations

import argparse
import csv
import statistics
import tempfile
from pathlib import Path

STAGES = ("generate_seconds", "repair_seconds", "screen_seconds", "exact_seconds")


def summarise(rows: list[dict[str, str]], n_evals: int = 10_000) -> None:
    if not rows:
        print("no iterations recorded")
        return
    first, rest = rows[0], rows[1:] or rows[:1]

    def mean(key: str, rs=rest) -> float:
        vals = [float(r[key]) for r in rs if r.get(key) not in (None, "", "nan")]
        return statistics.fmean(vals) if vals else float("nan")

    batch = int(rows[0]["evaluations"]) // int(rows[0]["iteration"])
    step = mean("step_seconds")
    ids = [int(r["iteration"]) for r in rows]
    print(
        f"iterations: {len(rows)} (batch {batch}); iteration {ids[0]} {float(first['step_seconds']):.1f} s "
        f"(reported apart: a run's first includes compilation and the pool's start)"
    )
    print(
        f"per iteration (iterations {ids[1] if len(ids) > 1 else ids[0]}..{ids[-1]}): {step:.1f} s wall = "
        + ", ".join(f"{k.split('_')[0]} {mean(k):.1f} s" for k in STAGES)
    )
    runs = mean("exact_runs")
    print(
        f"exact RHCR: {mean('n_exact'):.1f} of {batch} layouts per iteration "
        f"({runs:.0f} runs, {mean('exact_seconds') / runs if runs else float('nan'):.2f} s wall "
        f"per run made); screen x scale minus exact: bias {mean('screen_bias'):+.3f}, "
        f"mean |error| {mean('screen_mae'):.3f} (throughput)"
    )
    if rows[0].get("exact_reused") not in (None, ""):  # runs with the evaluation memo
        print(
            f"reused (memo or a copy in the batch): repair {mean('repair_reused'):.1f}, "
            f"exact {mean('exact_reused'):.1f} of {batch} layouts per iteration"
        )
    iters = n_evals / batch
    print(
        f"projected {n_evals:,} evaluations: {iters:.0f} iterations x {step:.1f} s = "
        f"{iters * step / 3600:.1f} h (target <= 24 h)"
    )
    last = rows[-1]
    print(
        f"archive after {last['evaluations']} evaluations: QD-score {float(last['qd_score']):.1f}, "
        f"coverage {float(last['coverage']):.4f}, best f_res {float(last['best_objective']):.3f}"
    )


def run(domain: str, iters: int) -> list[dict[str, str]]:
    from experiments.cli import compose_config
    from nca_qd.experiment import Experiment

    with tempfile.TemporaryDirectory() as tmp:
        cfg = compose_config(
            "run",
            [f"domain={domain}", f"qd.n_evals={50 * iters}", "qd.progress=false", "output.pictures=false"],
        )
        Experiment(cfg, Path(tmp)).run()
        with open(Path(tmp) / "metrics.csv") as fh:
            return list(csv.DictReader(fh))


def replay_early_stop(run_dirs: str, deltas=(0.02, 0.05, 0.1)) -> None:
    """What stopping a layout's exact runs after its first would have saved in a finished search,
    and what it would have lost: from its memo (every exactly-run layout, its 5 runs) and the
    result archive's elite each layout met (rebuilt from the memo). A layout in an occupied
    cell stops when even its best case cannot beat that elite: the other runs at (1 + delta) x
    its first where the first flows (above 0.8 of the search's median throughput), at the
    search's best run anywhere where it congests. Lost: stopped layouts whose 5-run mean beat
    the elite (they would have entered the result archive)."""
    import numpy as np

    from benchmarks.screen_search import _elite_before
    from nca_qd.scoring.keys import layout_key

    for run in run_dirs.split(","):
        memo = np.load(Path(run) / "eval_memo.npz")
        by_key = {layout_key(lay): i for i, lay in enumerate(memo["repair_layouts"])}
        layouts = memo["repair_layouts"][[by_key[bytes(k)] for k in memo["exact_keys"]]]
        elite = _elite_before(memo, Path(run) / "config.yaml", layouts)
        thr = memo["exact_throughput"]
        mean, first, n_runs = thr.mean(1), thr[:, 0], thr.shape[1]
        occupied = np.isfinite(elite)
        better = occupied & (mean > elite)
        flows = first > 0.8 * np.median(mean)
        print(
            f"{run}: {len(mean)} exactly-run layouts, {occupied.sum()} came to an occupied cell, "
            f"{better.sum()} beat its elite"
        )
        for delta in deltas:
            rest = np.where(flows, first * (1 + delta), np.nanmax(thr))
            stop = occupied & ((first + (n_runs - 1) * rest) / n_runs < elite)
            lost = stop & better
            print(
                f"  delta {delta}: stopped {stop.sum()} ({stop.sum() / max(occupied.sum(), 1):.1%} of "
                f"those), lost {lost.sum()} of {better.sum()} improvers; runs saved "
                f"{(n_runs - 1) * stop.sum()} of {thr.size} ({(n_runs - 1) * stop.sum() / thr.size:.1%})"
            )


def exact_floor(run_dir: str, per_bucket: int = 6, buckets: int = 8, seed: int = 0) -> None:
    """The exact stage's CPU over a finished search, and the least wall time it needs on k cores.

    Draws ``per_bucket`` of the memo's exactly-scored layouts from each of ``buckets`` equal
    spans of iterations, runs each once more single-threaded at the search's exact settings
    (``eval.*``: node budget, T, agents; a seed from its key, since a batch's seeds are not
    stored) and reads the planner's thread CPU seconds, which a busy machine barely changes.
    Each span's mean CPU per run times the exact runs the search made in it (``metrics.csv``)
    is the protocol's exact CPU; divided by the cores, the wall time no scheduling can beat
    while every layout that is not skipped gets N_e exact runs."""
    import numpy as np
    from omegaconf import OmegaConf

    from nca_qd.io import array_to_rows
    from nca_qd.layouts import get_layout
    from nca_qd.run_dir import load_run_config
    from nca_qd.scoring.jobs import ExactSettings, exact_job
    from nca_qd.scoring.keys import layout_key
    from nca_qd.scoring.settings import ScoringConfig
    from nca_qd.sim.rhcr import REPLAN, WINDOW

    run = Path(run_dir)
    cfg = load_run_config(run)
    memo = np.load(run / "eval_memo.npz")
    scoring = ScoringConfig.from_cfg(OmegaConf.to_container(cfg.get("eval", {}), resolve=True))
    sim = cfg.domain.simulation
    T, n_agents = int(sim.T), int(cfg.domain.n_agents.train)
    settings = ExactSettings(T, None, WINDOW, REPLAN, dict(scoring.planner or {}))
    tiles = get_layout(cfg.domain.name, "domain").tiles
    by_key = {layout_key(lay): i for i, lay in enumerate(memo["repair_layouts"])}
    with open(run / "metrics.csv") as fh:
        metrics = list(csv.DictReader(fh))
    last = int(metrics[-1]["iteration"])
    edges = np.linspace(0, last, buckets + 1).round().astype(int)
    its = memo["exact_iteration"]
    rng = np.random.default_rng(seed)
    total_cpu, total_runs = 0.0, 0
    print(f"== exact-stage floor of {run_dir}: {T} steps, {n_agents} agents, {dict(settings.planner)}")
    print("iterations | sampled runs | CPU-s per run (mean, max) | runs made | exact CPU-h")
    for lo, hi in zip(edges[:-1], edges[1:]):
        pool = np.flatnonzero((its > lo) & (its <= hi))
        picks = rng.choice(pool, size=min(per_bucket, len(pool)), replace=False)
        cpu = []
        for j in picks:
            key = bytes(memo["exact_keys"][j])
            rows = array_to_rows(memo["repair_layouts"][by_key[key]], tiles)
            out = exact_job(rows, cfg.domain.name, n_agents, int.from_bytes(key[:4], "big") % 2**31, settings)
            cpu.append(out.cpu_seconds)
        made = sum(int(r["exact_runs"]) for r in metrics if lo < int(r["iteration"]) <= hi)
        span_cpu = float(np.mean(cpu)) * made
        total_cpu, total_runs = total_cpu + span_cpu, total_runs + made
        per_run = f"{np.mean(cpu):.2f}, {np.max(cpu):.2f}"
        print(f"{lo + 1}-{hi} | {len(cpu)} | {per_run} | {made} | {span_cpu / 3600:.2f}")
    print(f"whole search: {total_runs} exact runs, {total_cpu / 3600:.2f} CPU-h of exact RHCR")
    for cores in (2, 4, 8, 16):
        print(f"  on {cores} cores at best: {total_cpu / cores / 3600:.2f} h for the exact stage alone")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--domain", default="warehouse_even")
    ap.add_argument("--iters", type=int, default=4)
    ap.add_argument("--run-dir", default=None)
    ap.add_argument(
        "--iterations",
        default=None,
        metavar="A-B",
        help="with --run-dir: only iterations A..B (e.g. the ones that ran on an "
        "otherwise idle machine); the first of them is reported apart",
    )
    ap.add_argument(
        "--replay-early-stop",
        default=None,
        metavar="RUN[,RUN]",
        help="finished searches: what stopping exact runs after the first would save and lose",
    )
    ap.add_argument(
        "--exact-floor",
        default=None,
        metavar="RUN",
        help="a finished search: its exact stage's CPU-hours, re-measured on a sample of its layouts",
    )
    args = ap.parse_args(argv if argv is not None else [])
    if args.exact_floor:
        exact_floor(args.exact_floor)
        return
    if args.replay_early_stop:
        replay_early_stop(args.replay_early_stop)
        return
    if args.run_dir:
        with open(Path(args.run_dir) / "metrics.csv") as fh:
            rows = list(csv.DictReader(fh))
        if args.iterations:
            lo, _, hi = args.iterations.partition("-")
            rows = [r for r in rows if int(lo) <= int(r["iteration"]) <= int(hi or lo)]
        print(
            f"== search cost of {args.run_dir}"
            + (f", iterations {args.iterations}" if args.iterations else "")
        )
    else:
        print(f"== search cost: {args.domain}, {args.iters} CMA-MAE iterations at the paper's settings")
        rows = run(args.domain, args.iters)
    summarise(rows)


if __name__ == "__main__":
    import sys

    main(sys.argv[1:])
