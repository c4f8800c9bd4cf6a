"""RHCR simulator speed and fidelity figures (part of `make bench`).

Prints, per layout: CPU-seconds per simulation and per planning call (median / 95th
percentile / max), throughput (mean ± standard error over the seeds), success rate, PBS
failures, beside the paper's figure. Peers: the reference C++ RHCR (the paper's fork) needs
about 21.5 CPU-seconds for 200 agents x 1,000 steps on the paper's 33x36 generated warehouse
(a build with the Boost 1.71 heap its code release names; 26-28 with the earlier build, which
also gave 40-50 on manufacturing); at 101x102 with 1,400 agents it spends 6-50 s per planning call
(hours per run). Layouts come from :func:`nca_qd.io.reference_maps_dir` ($NCA_QD_MAPS or the
shared reference folder); missing ones are reported and skipped.

    python -m benchmarks.bench_rhcr                 # all cases (about 10 minutes on 2 cores)
    python -m benchmarks.bench_rhcr --seeds 20      # the paper's 101x102 check (about 40 minutes)
    python -m benchmarks.bench_rhcr --only 33x36    # the 33x36 cases alone

``--seeds`` (or ``BENCH_RHCR_SEEDS``) sets the seeds of the 101x102 cases.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

import numpy as np

from nca_qd.io import load_map, reference_maps_dir
from nca_qd.sim.rhcr import simulate_many
from nca_qd.sim.scenario import tiles_for

SMALL_SEEDS = [0, 1, 2, 3]
CASES = [  # (layout, scenario, agents, T, seeds (None: --seeds), paper's success and throughput at T=5,000)
    ("warehouse/paper_cma-mae_a5_even_33x36.json", "warehouse_even", 200, 1000, SMALL_SEEDS, "100 %, 6.74"),
    ("warehouse/human_33x36.json", "warehouse_even", 200, 1000, SMALL_SEEDS, "0 %"),
    ("manufacturing/human_33x36.json", "manufacturing", 200, 1000, SMALL_SEEDS, "100 %, 5.92"),
    ("warehouse/paper_cma-mae_a5_even_101x102.json", "warehouse_even", 1400, 5000, None, "90 %, 16.01"),
    ("warehouse/human_101x102.json", "warehouse_even", 1400, 5000, [0], "0 %"),
]


def _find(rel: str) -> Path | None:
    path = reference_maps_dir() / rel
    return path if path.is_file() else None


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=int(os.environ.get("BENCH_RHCR_SEEDS", "2")))
    ap.add_argument("--only", default="", help="run only the cases whose layout path contains this")
    args = ap.parse_args([] if argv is None else argv)
    if args.seeds < 1:
        ap.error(f"--seeds must be >= 1, got {args.seeds}")
    print(
        "== RHCR (windowed PBS + space-time A*, w=10, h=5); reference C++ RHCR: 21.5 CPU-s "
        "(paper layout; an earlier build 26-28), 40-50 (manufacturing, earlier build) per "
        "200 agents x 1,000 steps; 6-50 s per planning call at 101x102 with 1,400 agents"
    )
    for rel, scenario, agents, T, case_seeds, paper in CASES:
        if args.only not in rel:
            continue
        seeds = list(range(args.seeds)) if case_seeds is None else case_seeds
        path = _find(rel)
        if path is None:
            print(f"{rel}: not found (set NCA_QD_MAPS), skipped")
            continue
        rows = load_map(path, tiles=tiles_for(scenario)).rows
        runs = simulate_many(rows, scenario, agents, T, seeds)
        thr = np.array([r.throughput for r in runs])
        se = thr.std(ddof=1) / math.sqrt(len(thr)) if len(thr) > 1 else 0.0
        cpu = np.array([r.cpu_seconds for r in runs])
        calls = np.concatenate([r.call_cpu_seconds for r in runs])
        stops = ",".join(str(r.stop_time) for r in runs)
        ok = [r.throughput for r in runs if r.success]
        flowing = f"{np.mean(ok):.3f}" if ok else "-"
        print(
            f"{rel} {scenario} agents={agents} T={T} seeds={len(runs)}: "
            f"cpu_s/run={cpu.mean():.2f} (max {cpu.max():.1f}) cpu_s/call median={np.median(calls):.3f} "
            f"p95={np.percentile(calls, 95):.3f} max={calls.max():.2f} "
            f"throughput={thr.mean():.3f}±{se:.3f} (successful runs {flowing}) "
            f"success={np.mean([r.success for r in runs]):.0%} stop_time=[{stops}] "
            f"pbs_failures={sum(r.pbs_failures for r in runs)}/{sum(r.replans for r in runs)} "
            f"| paper: {paper}",
            flush=True,
        )


if __name__ == "__main__":
    main(sys.argv[1:])
