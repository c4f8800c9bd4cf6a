"""DSAGE's cost (``make bench``): what one outer iteration costs at a configuration, by stage.

Measures on this machine, for the maze at size S (16 x 16, 256 x 162 archive):

* one surrogate training step (a minibatch of ``batch_size`` layouts, forward + backward + Adam);
* one inner MAP-Elites iteration on the surrogate (``emitters x batch_size`` predictions and the
  archive insertion);
* the real evaluation of a downsampled batch (the learned maze agent, 50 episodes per maze);

and extrapolates one outer iteration at full data (``sample_size`` rows, ``epochs`` epochs,
``inner.iterations``), for the paper's configuration (``algo/dsage.yaml``) and a reduced one.

    python -m benchmarks.bench_dsage [--features 64] [--reduced-features 32]
"""

from __future__ import annotations

import argparse
import math
import time

import jax
import jax.numpy as jnp
import numpy as np

from experiments.cli import compose_config
from nca_qd.domains import make_domain
from nca_qd.qd.dsage.surrogate import Surrogate, SurrogateConfig
from nca_qd.qd.dsage.tiles import make_inner_loop


def _time(fn, repeats: int) -> float:
    fn()  # compile
    t = time.perf_counter()
    for _ in range(repeats):
        fn()
    return (time.perf_counter() - t) / repeats


def stage_costs(features: int, res_blocks: int = 2, repeats: int = 5) -> dict[str, float]:
    """Seconds per training step (64 layouts) and per inner iteration (150 predictions)."""
    cfg = SurrogateConfig(features=features, res_blocks=res_blocks, epochs=1, sample_size=64 * repeats)
    model = Surrogate((16, 16), 2, [0, 0, 0], [1, 256, 648], cfg)
    params, opt = model.init(jax.random.PRNGKey(0))
    rng = np.random.default_rng(0)
    n = 64 * repeats
    layouts = rng.integers(0, 2, (n, 16, 16)).astype(np.int8)
    targets = rng.random((n, 3)).astype(np.float32)
    anc = rng.random((n, 16, 16)).astype(np.float16)
    model.train(params, opt, layouts, targets, anc, seed=0)  # compile
    t = time.perf_counter()
    model.train(params, opt, layouts, targets, anc, seed=1)
    train_step = (time.perf_counter() - t) / repeats
    iters = 20
    inner = make_inner_loop(
        model.predict, (16, 16), 2, (256, 162), ((0, 256), (0, 648)), iters, 5, 30, 100, 10
    )
    jax.block_until_ready(inner(params, jax.random.PRNGKey(0)))
    t = time.perf_counter()
    jax.block_until_ready(inner(params, jax.random.PRNGKey(1)))
    return {"train_step": train_step, "inner_iteration": (time.perf_counter() - t) / iters}


def real_evaluation(batch: int = 256) -> float:
    """Seconds per maze of the learned agent's real evaluation (50 episodes), batch ``batch``."""
    cfg = compose_config("run", ["domain=maze", "algo=dsage"])
    evaluator = make_domain(cfg.domain).make_evaluator(cfg)
    regions = jnp.asarray((np.random.default_rng(0).random((batch, 16, 16)) < 0.3).astype(np.int32))
    jax.block_until_ready(evaluator(regions, jax.random.PRNGKey(0)).objective)
    t = time.perf_counter()
    jax.block_until_ready(evaluator(regions, jax.random.PRNGKey(1)).objective)
    return (time.perf_counter() - t) / batch


def outer_iteration(
    costs: dict[str, float], per_maze: float, epochs: int, sample: int, inner: int, n_real: int
):
    train = epochs * math.ceil(sample / 64) * costs["train_step"]
    search = inner * costs["inner_iteration"]
    real = n_real * per_maze
    return train, search, real


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--features", type=int, default=64)
    ap.add_argument("--reduced-features", type=int, default=32)
    args = ap.parse_args(argv)
    per_maze = real_evaluation()
    print(f"real evaluation (learned agent, 50 episodes): {per_maze * 1000:.1f} ms per maze")
    for label, feats, epochs, sample, inner in (
        ("paper (algo/dsage.yaml)", args.features, 200, 20000, 10000),
        ("reduced", args.reduced_features, 20, 20000, 500),
    ):
        c = stage_costs(feats)
        train, search, real = outer_iteration(c, per_maze, epochs, sample, inner, 864)
        print(
            f"{label}: features {feats}: train step {c['train_step'] * 1000:.0f} ms, inner iteration "
            f"{c['inner_iteration'] * 1000:.1f} ms; one outer iteration at full data (epochs {epochs}, "
            f"{sample} rows, {inner} inner iterations, 864 real): train {train / 60:.1f} min + inner "
            f"{search / 60:.1f} min + real {real / 60:.1f} min = {(train + search + real) / 3600:.2f} h"
        )


if __name__ == "__main__":
    main()
