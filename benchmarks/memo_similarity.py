"""How near the repair leaves a search's best layouts: Δ against f_res over a run's memo.

    python -m benchmarks.memo_similarity results/warehouse_even_qd/cma_mae_a0_s0 \
        results/warehouse_even_qd/cma_mae_a5_s0

Table 3 of the paper gives Δ (the share of cells the repair leaves as the NCA drew them) of one
generator per arm, the best. Where ours differs, the question is whether that one generator is
typical of its arm. A search's memo (``eval_memo.npz``) holds every repair it made (keyed by the
generated layout, with its similarity) and every exact score (keyed by the repaired layout), so
each repaired layout's Δ can be paired with its f_res: this prints, per run, Δ over the layouts
with the highest f_res, and the share of the good layouts (f_res at or above ``--good``) whose Δ
reaches ``--delta``. Reads only; no simulation.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def pairs(run_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    """(Δ, f_res) of every repaired layout of the run's memo that was also scored exactly."""
    from nca_qd.scoring.keys import layout_key

    with np.load(run_dir / "eval_memo.npz") as z:  # one read of each array (an NpzFile re-reads)
        m = {
            k: z[k]
            for k in ("exact_keys", "exact_throughput", "repair_found", "repair_layouts", "repair_similarity")
        }
    row = {bytes(k): i for i, k in enumerate(m["exact_keys"])}
    f_res = m["exact_throughput"].mean(axis=1)
    delta, score = [], []
    for i in np.flatnonzero(m["repair_found"]):
        j = row.get(layout_key(m["repair_layouts"][i]))
        if j is not None:
            delta.append(m["repair_similarity"][i])
            score.append(f_res[j])
    return np.asarray(delta), np.asarray(score)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("runs", nargs="+", help="run directories holding eval_memo.npz")
    p.add_argument("--top", default="10,50,200", help="sizes of the best-f_res groups")
    p.add_argument("--good", type=float, default=6.5, help="f_res of a good layout")
    p.add_argument("--delta", type=float, default=0.94, help="the Δ to reach (the paper's α = 0 row)")
    args = p.parse_args(argv)
    try:
        tops = [int(t) for t in args.top.split(",")]
    except ValueError:
        print(f"error: --top {args.top!r}: expected e.g. 10,50,200", file=sys.stderr)
        return 2
    for run in map(Path, args.runs):
        if not (run / "eval_memo.npz").is_file():
            print(f"error: {run}: no eval_memo.npz", file=sys.stderr)
            return 2
        delta, score = pairs(run)
        order = np.argsort(-score)
        print(
            f"{run}: {len(score):,} repaired layouts scored exactly; median Δ of all {np.median(delta):.3f}"
        )
        for t in tops:
            d = delta[order[:t]]
            print(
                f"  best {t} by f_res ({score[order[min(t, len(order)) - 1]]:.2f}–{score[order[0]]:.2f}): "
                f"Δ median {np.median(d):.3f}, range {d.min():.3f}–{d.max():.3f}"
            )
        good = score >= args.good
        print(
            f"  f_res ≥ {args.good}: {good.sum():,} layouts, {np.mean(delta[good] >= args.delta):.1%} "
            f"of them with Δ ≥ {args.delta}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
