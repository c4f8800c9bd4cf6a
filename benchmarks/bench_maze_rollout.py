"""Staged maze rollouts (``make bench``): the agent's episodes of one search batch, staged as
the search runs them against one loop over every row (staging off), on batches like a search's.

Each batch: the 64 generators kept in a shipped run's ``elites.npz``, repeated to the search's
150 and perturbed with Gaussian noise of ``sigma`` (small: offspring of an archive, as CMA-MAE's;
large: a mix of solvable and unsolvable mazes, as MAP-Elites's early iterations), grown at
16x16, scored as the maze evaluator does (50 episodes, horizon 648). Prints the seconds per
batch of both and whether their episode lengths, goals and (DSAGE's) visits are identical.

    python -m benchmarks.bench_maze_rollout [--repeats 2] [--runs <run>:<sigma>[:visits],...]
"""

from __future__ import annotations

import argparse
import sys
import time
from functools import partial
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from experiments.cli import compose_config
from nca_qd.domains import make_domain
from nca_qd.domains.maze import EMPTY, WALL, longest_shortest_path, maze_key
from nca_qd.pipeline import generate, make_generator
from nca_qd.sim import maze_agent as ma

RUNS = (
    "results/maze_qd/cma_mae_maze_s3:0.02,"
    "results/maze_qd/cma_mae_maze_s2:0.02:visits,"
    "results/maze_qd/map_elites_maze_entropy_s3:0.2"
)


def search_batch(run: str, sigma: float, seed: int = 0) -> jax.Array:
    """150 interiors [150, 16, 16] grown from the run's kept generators plus noise."""
    cfg = compose_config("run", ["domain=maze", "qd.progress=false"])
    domain = make_domain(cfg.domain)
    kept = np.load(f"{run}/elites.npz")["kept_genotypes"]
    genomes = np.resize(kept, (150, kept.shape[1]))
    genomes = genomes + np.random.default_rng(seed).normal(0, sigma, genomes.shape).astype(np.float32)
    regions = generate(domain, make_generator(domain), genomes, shape=(16, 16), n_iters=50)
    return jnp.asarray(regions, jnp.int32)


def scorer(staged: bool, visits: bool):
    """The evaluator's rollout of a batch of interiors, staged or as one loop over all rows."""
    policy = ma.get_policy("learned")
    floor = ma.STAGE_FLOOR if staged else 1

    @jax.jit
    def score(regions, key):
        layouts = jnp.pad(regions, ((0, 0), (1, 1), (1, 1)), constant_values=WALL)
        length, start, goal = longest_shortest_path(regions == EMPTY)
        start, goal = jnp.where(start >= 0, start + 1, start), jnp.where(goal >= 0, goal + 1, goal)
        keys = jax.vmap(partial(maze_key, key))(jnp.arange(regions.shape[0]))
        return ma.rollout_batch(policy, layouts, start, goal, keys, 50, 648, length > 0, count_visits=visits)

    def run(regions, key):
        saved, ma.STAGE_FLOOR = ma.STAGE_FLOOR, floor  # read when the function is traced
        try:
            return jax.block_until_ready(score(regions, key))
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
        batches.append((run, sigma, flag == "visits"))
    for run, sigma, visits in batches:
        regions = search_batch(run, float(sigma))
        out, secs = {}, {}
        for staged in (False, True):
            score = scorer(staged, visits)
            score(regions, jax.random.PRNGKey(0))  # compile
            times = []
            for rep in range(args.repeats):
                t0 = time.perf_counter()
                out[staged] = score(regions, jax.random.PRNGKey(1 + rep))
                times.append(time.perf_counter() - t0)
            secs[staged] = min(times)
        a, b = out[False], out[True]
        same = np.array_equal(a.lengths, b.lengths) and np.array_equal(a.reached, b.reached)
        if visits:
            same = same and np.array_equal(a.visits, b.visits)
        lengths = np.asarray(b.lengths)
        print(
            f"maze rollout, {run} sigma {sigma}{' with visits' if visits else ''}: one loop "
            f"{secs[False]:.2f} s, staged {secs[True]:.2f} s ({secs[False] / secs[True]:.1f}x); "
            f"identical: {same}; mean episode {lengths.mean():.0f} steps, "
            f"{(lengths == 648).mean():.0%} at the horizon",
            flush=True,
        )


if __name__ == "__main__":
    main()
