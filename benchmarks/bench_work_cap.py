"""What a bound on a planning call's A* expansions (``eval.plan_max_expansions``) changes.

Layouts a search already scored (its ``eval_memo.npz``: repaired layouts and their exact
throughput), jammed (memo mean < 2 tasks/step) and flowing, drawn at random; each run with exact
RHCR at the search's settings (200 agents, T = 1,000, ``pbs_max_nodes`` 2,000, 60 CPU-s per
call) without a cap and with each cap. Prints one JSON line per run, then per cap: runs with the
same verdict, runs identical, CPU without and with the cap, the largest change in throughput.

    python -m benchmarks.bench_work_cap --run-dir results/manufacturing_a5 --jammed 12 --flowing 6 \
        --caps 2000000,500000
"""

from __future__ import annotations

import argparse
import collections
import json

import numpy as np


def _layouts(run_dir: str, n_jammed: int, n_flowing: int, seed: int) -> list[tuple[np.ndarray, float]]:
    from nca_qd.scoring.keys import layout_key

    z = np.load(f"{run_dir}/eval_memo.npz")
    exact = {bytes(k): i for i, k in enumerate(z["exact_keys"])}
    jammed, flowing, seen = [], [], set()
    for lay in z["repair_layouts"][z["repair_found"]]:
        key = layout_key(lay)
        if key in seen or key not in exact:
            continue
        seen.add(key)
        thr = float(np.nanmean(z["exact_throughput"][exact[key]]))
        (jammed if thr < 2.0 else flowing).append((lay, thr))
    rng = np.random.default_rng(seed)
    pick = [jammed[i] for i in rng.choice(len(jammed), min(n_jammed, len(jammed)), replace=False)]
    pick += [flowing[i] for i in rng.choice(len(flowing), min(n_flowing, len(flowing)), replace=False)]
    print(
        f"# {len(jammed)} jammed and {len(flowing)} flowing distinct layouts in the memo; {len(pick)} drawn"
    )
    return pick


def main(argv: list[str] | None = None) -> None:
    from nca_qd.io import array_to_rows
    from nca_qd.repair import tiles_of
    from nca_qd.run_dir import load_run_config
    from nca_qd.sim.rhcr import simulate

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run-dir", default="results/manufacturing_a5")
    ap.add_argument("--jammed", type=int, default=12)
    ap.add_argument("--flowing", type=int, default=6)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--caps", default="2000000,500000")
    ap.add_argument("--draw-seed", type=int, default=0)
    args = ap.parse_args(argv)
    domain = str(load_run_config(args.run_dir)["domain"]["name"])
    tiles = tiles_of(domain)
    caps: list[int | None] = [None, *(int(c) for c in args.caps.split(","))]
    runs: dict[tuple[int, int], dict] = collections.defaultdict(dict)
    for j, (lay, memo) in enumerate(_layouts(args.run_dir, args.jammed, args.flowing, args.draw_seed)):
        rows = array_to_rows(lay, tiles)
        for cap in caps:
            for s in range(args.seeds):
                r = simulate(
                    rows,
                    domain,
                    200,
                    1000,
                    s,
                    pbs_max_nodes=2000,
                    plan_time_limit_s=60.0,
                    plan_max_expansions=cap,
                )
                line = {
                    "layout": j,
                    "memo": round(memo, 3),
                    "cap": cap,
                    "seed": s,
                    "throughput": r.throughput,
                    "success": r.success,
                    "stop": r.stop_time,
                    "failed_calls": r.pbs_failures,
                    "cpu": round(r.cpu_seconds, 3),
                }
                runs[(j, s)][cap] = line
                print(json.dumps(line), flush=True)
    for cap in caps[1:]:
        pairs = [(d[None], d[cap]) for d in runs.values()]
        same = sum(a["success"] == b["success"] for a, b in pairs)
        ident = sum((a["throughput"], a["stop"]) == (b["throughput"], b["stop"]) for a, b in pairs)
        cpu0, cpu1 = sum(a["cpu"] for a, _ in pairs), sum(b["cpu"] for _, b in pairs)
        jam = [(a, b) for a, b in pairs if not a["success"]]
        j0, j1 = sum(a["cpu"] for a, _ in jam), sum(b["cpu"] for _, b in jam)
        worst = max(abs(a["throughput"] - b["throughput"]) for a, b in pairs)
        print(
            f"cap {cap:,}: {same} of {len(pairs)} runs reach the same verdict, {ident} identical; CPU "
            f"{cpu0:.1f} -> {cpu1:.1f} s ({cpu0 / cpu1:.2f}x), on the {len(jam)} congesting runs "
            f"{j0:.1f} -> {j1:.1f} s ({j0 / max(j1, 1e-9):.2f}x); largest throughput change {worst:.3f}"
        )


if __name__ == "__main__":
    main()
