"""Staged maze rollouts (``make bench``): the agent's episodes of one search batch, staged as
the search runs them against one loop over every row (staging off), on batches like a search's.

Each batch: the 64 generators kept in a shipped run's ``elites.npz``, repeated to the search's
150 and perturbed with Gaussian noise of ``sigma`` (small: offspring of an archive, as CMA-MAE's;
large: a mix of solvable and unsolvable mazes, as MAP-Elites's early iterations), grown at
16x16 and scored by the maze evaluator itself (``MazeDomain.make_evaluator``: 50 episodes,
horizon 648). Prints the seconds per batch of both and whether their episode lengths, success
rates and (DSAGE's) visits are identical.

    python -m benchmarks.bench_maze_rollout [--repeats 2] [--runs <run>:<sigma>[:visits],...]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from experiments.cli import compose_config
from nca_qd.domains import make_domain
from nca_qd.pipeline import generate, make_generator
from nca_qd.sim import maze_agent as ma

RUNS = (
    "results/maze_qd/cma_mae_maze_s3:0.02,"
    "results/maze_qd/cma_mae_maze_s2:0.02:visits,"
    "results/maze_qd/map_elites_maze_entropy_s3:0.2"
)


def search_batch(domain, run: str, sigma: float, seed: int = 0) -> jax.Array:
    """150 interiors [150, 16, 16] grown from the run's kept generators plus noise."""
    kept = np.load(f"{run}/elites.npz")["kept_genotypes"]
    genomes = np.resize(kept, (150, kept.shape[1]))
    genomes = genomes + np.random.default_rng(seed).normal(0, sigma, genomes.shape).astype(np.float32)
    regions = generate(domain, make_generator(domain), genomes, shape=(16, 16), n_iters=50)
    return jnp.asarray(regions, jnp.int32)


def scorer(domain, staged: bool, visits: bool):
    """The maze evaluator's own jitted scorer (DSAGE's when ``visits``), its rollouts staged or
    as one loop over all rows: :data:`~nca_qd.sim.maze_agent.STAGE_FLOOR` is read when the
    function is traced, so each call of this builds a scorer of its own and traces it here."""
    evaluate = domain.make_evaluator({"algo": {"ancillary": visits}}).jitted
    floor = ma.STAGE_FLOOR if staged else 1

    def run(regions, key):
        saved, ma.STAGE_FLOOR = ma.STAGE_FLOOR, floor
        try:
            return jax.block_until_ready(evaluate(regions, key))
        finally:
            ma.STAGE_FLOOR = saved

    return run


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--runs", default=RUNS)
    args = ap.parse_args(argv)
    batches = []
    for item in args.runs.split(","):
        run, _, rest = item.partition(":")
        sigma, _, flag = rest.partition(":")
        try:
            sigma_value = float(sigma)
        except ValueError:
            sigma_value = -1.0
        if not Path(run, "elites.npz").is_file() or sigma_value < 0 or flag not in ("", "visits"):
            sys.exit(f"error: --runs takes <run>:<sigma>[:visits], the run with an elites.npz; got {item!r}")
        batches.append((run, sigma_value, flag == "visits"))
    domain = make_domain(compose_config("run", ["domain=maze", "qd.progress=false"]).domain)
    for run, sigma, visits in batches:
        regions = search_batch(domain, run, sigma)
        out, secs = {}, {}
        for staged in (False, True):
            score = scorer(domain, staged, visits)
            score(regions, jax.random.PRNGKey(0))  # compile
            times = []
            for rep in range(args.repeats):
                t0 = time.perf_counter()
                out[staged] = score(regions, jax.random.PRNGKey(1 + rep))
                times.append(time.perf_counter() - t0)
            secs[staged] = min(times)
        (_, _, a), (_, _, b) = out[False], out[True]
        compared = ("episode_lengths", "success_rate") + (("ancillary",) if visits else ())
        same = all(np.array_equal(a[name], b[name]) for name in compared)
        lengths = np.asarray(b["episode_lengths"])
        print(
            f"maze rollout, {run} sigma {sigma}{' with visits' if visits else ''}: one loop "
            f"{secs[False]:.2f} s, staged {secs[True]:.2f} s ({secs[False] / secs[True]:.1f}x); "
            f"identical: {same}; mean episode {lengths.mean():.0f} steps, "
            f"{(lengths == 648).mean():.0%} at the horizon",
            flush=True,
        )


if __name__ == "__main__":
    main()
