"""RHCR simulator speed and validation figures (part of `make bench`).

Prints, per layout: CPU-seconds per simulation, throughput (mean ± standard error over the
seeds), success rate. Reference: the original C++ RHCR needs about 26-28 CPU-seconds for 200
agents x 1,000 steps on the paper's 33x36 generated warehouse and 40-50 on manufacturing.
The 101x102 warehouse with 1,000 agents runs under a wall-clock budget and reports how far it
got. Layouts come from :func:`nca_qd.io.reference_maps_dir` ($NCA_QD_MAPS or the shared
reference folder); missing ones are reported and skipped.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from nca_qd.io import load_map
from nca_qd.sim.rhcr import simulate_many
from nca_qd.sim.scenario import tiles_for
from nca_qd.io import reference_maps_dir

SEEDS = [0, 1, 2]
CASES = [  # (layout, scenario, agents, T, time budget per run in s)
    ("warehouse/paper_cma-mae_a5_even_33x36.json", "warehouse_even", 200, 1000, None),
    ("warehouse/human_33x36.json", "warehouse_even", 200, 1000, None),
    ("manufacturing/human_33x36.json", "manufacturing", 200, 1000, None),
    ("warehouse/human_101x102.json", "warehouse_even", 1000, 1000, 120.0),
]


def _find(rel: str) -> Path | None:
    path = reference_maps_dir() / rel
    return path if path.is_file() else None


def main() -> None:
    print("== RHCR (windowed PBS + space-time A*, w=10, h=5); reference C++ RHCR: 26-28 CPU-s "
          "(paper layout), 40-50 (manufacturing) per 200 agents x 1,000 steps")
    for rel, scenario, agents, T, budget in CASES:
        path = _find(rel)
        if path is None:
            print(f"{rel}: not found (set NCA_QD_MAPS), skipped")
            continue
        rows = load_map(path, tiles=tiles_for(scenario)).rows
        seeds = SEEDS if budget is None else SEEDS[:1]
        runs = simulate_many(rows, scenario, agents, T, seeds, time_limit_s=budget)
        thr = np.array([r.throughput for r in runs])
        se = thr.std(ddof=1) / math.sqrt(len(thr)) if len(thr) > 1 else 0.0
        cpu = np.mean([r.cpu_seconds for r in runs])
        stops = ",".join(str(r.stop_time) for r in runs)
        flags = " TIMED OUT" if any(r.timed_out for r in runs) else ""
        print(f"{rel} {scenario} agents={agents} T={T} seeds={len(runs)}: "
              f"cpu_s/run={cpu:.2f} throughput={thr.mean():.3f}±{se:.3f} "
              f"success={np.mean([r.success for r in runs]):.0%} stop_time=[{stops}]"
              f" pbs_failures={sum(r.pbs_failures for r in runs)}{flags}", flush=True)


if __name__ == "__main__":
    main()
