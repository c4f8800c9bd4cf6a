"""DSAGE's cost (``make bench``): what one outer iteration costs at a configuration, by stage.

Measures on this machine, for a domain at its size S (maze 16 x 16, warehouse 33 x 32, ...)
with the domain's archive and DSAGE settings:

* one surrogate training step (a minibatch of ``batch_size`` layouts, forward + backward + Adam);
* one inner MAP-Elites iteration on the surrogate (``emitters x batch_size`` predictions and the
  archive insertion);
* the real evaluation of one layout: the learned maze agent (50 episodes, in a batch of 256), or
  for the multi-agent domains repair + exact RHCR on every seed (``eval.exact=all``, as DSAGE
  runs it) on the local pool;

and extrapolates one outer iteration at full data (``sample_size`` rows, ``epochs`` epochs,
``inner.iterations``, as many real evaluations as the downsampled archive has cells), for the
paper's configuration (``algo/dsage.yaml``) and a reduced one, and the real evaluations of a
whole search (``qd.n_evals`` of them, whatever the number of outer iterations).

    python -m benchmarks.bench_dsage [--domain maze,warehouse_even] [--features 64] [--reduced-features 32]
    python -m benchmarks.bench_dsage --domain warehouse_even --layouts 4
    python -m benchmarks.bench_dsage --domain warehouse_even --real-seconds-per-layout 15.4  # GPU box
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


def _settings(domain: str, extra: list[str] | None = None):
    """The run config of ``algo=dsage`` on ``domain`` and the domain built from it."""
    cfg = compose_config("run", [f"domain={domain}", "algo=dsage", *(extra or [])])
    return cfg, make_domain(cfg.domain)


def stage_costs(domain: str, features: int, res_blocks: int = 2, repeats: int = 5) -> dict[str, float]:
    """Seconds per training step (64 layouts) and per inner iteration (5 x 30 predictions)."""
    run_cfg, dom = _settings(domain)
    shape, k = tuple(dom.gen_shape("train")), dom.n_tiles
    spec = run_cfg.domain.measures
    ranges = [tuple(float(v) for v in r) for r in spec.ranges]
    obj = [float(v) for v in (run_cfg.domain.dsage.get("objective_range") or run_cfg.domain.objective_range)]
    cfg = SurrogateConfig(features=features, res_blocks=res_blocks, epochs=1, sample_size=64 * repeats)
    model = Surrogate(shape, k, [obj[0], *(r[0] for r in ranges)], [obj[1], *(r[1] for r in ranges)], cfg)
    params, opt = model.init(jax.random.PRNGKey(0))
    rng = np.random.default_rng(0)
    n = 64 * repeats
    layouts = rng.integers(0, k, (n, *shape)).astype(np.int8)
    targets = rng.random((n, 1 + len(ranges))).astype(np.float32)
    anc = rng.random((n, *shape)).astype(np.float16)
    model.train(params, opt, layouts, targets, anc, seed=0)  # compile
    t = time.perf_counter()
    model.train(params, opt, layouts, targets, anc, seed=1)
    train_step = (time.perf_counter() - t) / repeats
    iters = 20
    inner = make_inner_loop(
        model.predict, shape, k, [int(c) for c in spec.cells], ranges, iters, 5, 30, 100, 10
    )
    jax.block_until_ready(inner(params, jax.random.PRNGKey(0)))
    t = time.perf_counter()
    jax.block_until_ready(inner(params, jax.random.PRNGKey(1)))
    return {"train_step": train_step, "inner_iteration": (time.perf_counter() - t) / iters}


def real_evaluation(domain: str, n_layouts: int) -> tuple[float, str]:
    """Wall seconds per layout of the real evaluation of ``n_layouts`` random layouts of size S
    (maze: in one jitted batch, after compiling; multi-agent: repair + every exact run on the
    local pool, the pool started beforehand), and what was measured."""
    from nca_qd.pipeline import make_generator, make_objective

    cfg, dom = _settings(domain)
    generator = make_generator(dom, "dsage")
    objective = make_objective(dom, generator, cfg)
    rng = np.random.default_rng(0)
    if domain == "maze":
        sols = jnp.asarray((rng.random((n_layouts, generator.n_params)) < 0.3).astype(np.float32))
        jax.block_until_ready(objective(sols, jax.random.PRNGKey(0)).objective)
        t = time.perf_counter()
        jax.block_until_ready(objective(sols, jax.random.PRNGKey(1)).objective)
        return (time.perf_counter() - t) / n_layouts, "learned agent, 50 episodes"
    try:
        # DSAGE's random layouts: each tile uniform over the region's tiles
        sols = rng.integers(0, dom.n_tiles, (n_layouts + 1, generator.n_params)).astype(np.float32)
        objective(sols[:1], jax.random.PRNGKey(0))  # compiles the screen, starts the pool
        t = time.perf_counter()
        ev = objective(sols[1:], jax.random.PRNGKey(1))
        sec = (time.perf_counter() - t) / n_layouts
        m = ev.extras.get("metrics", {})
        sim = cfg.domain.simulation
        what = (
            f"repair + exact RHCR on {sim.n_runs} seeds, {cfg.domain.n_agents.train} agents, "
            f"T={sim.T}; of the batch: repair {m.get('repair_seconds', float('nan')):.1f} s, "
            f"exact {m.get('exact_seconds', float('nan')):.1f} s"
        )
        return sec, what
    finally:
        objective.close()


def outer_iteration(
    costs: dict[str, float], per_maze: float, epochs: int, sample: int, inner: int, n_real: int
):
    train = epochs * math.ceil(sample / 64) * costs["train_step"]
    search = inner * costs["inner_iteration"]
    real = n_real * per_maze
    return train, search, real


def report(
    domain: str,
    layouts: int | None,
    features: int,
    reduced_features: int,
    real_seconds: float | None = None,
) -> None:
    """Print one domain's figures (see the module docstring); ``real_seconds`` replaces the
    measured real evaluation per layout (e.g. the CPU pool's figure on a GPU machine)."""
    cfg, dom = _settings(domain)
    if real_seconds is None:
        n_layouts = layouts or (256 if domain == "maze" else 4)
        per_layout, what = real_evaluation(domain, n_layouts)
    else:
        per_layout, what = real_seconds, "given with --real-seconds-per-layout, not measured"
    print(f"backend: {jax.default_backend()} ({jax.devices()[0].device_kind}), jax {jax.__version__}")
    coarse = [int(c) for c in (cfg.algo.downsample or cfg.domain.dsage.downsample)]
    n_real = math.prod(coarse)  # the most real evaluations one outer iteration can ask
    n_evals = int(cfg.qd.n_evals)
    n_outer = math.ceil(n_evals / n_real)
    shape = "x".join(map(str, dom.gen_shape("train")))
    print(f"{domain} at S ({shape}): real evaluation {per_layout * 1000:.2f} ms per layout ({what})")
    print(
        f"real evaluations of a whole search: {n_evals} x {per_layout * 1000:.2f} ms = "
        f"{n_evals * per_layout / 3600:.1f} h, in >= {n_outer} outer iterations of <= {n_real}"
    )
    for label, feats, epochs, sample, inner in (
        ("paper (algo/dsage.yaml)", features, 200, 20000, 10000),
        ("reduced", reduced_features, 20, 20000, 500),
    ):
        c = stage_costs(domain, feats)
        train, search, real = outer_iteration(c, per_layout, epochs, sample, inner, n_real)
        outer = train + search + real
        print(
            f"{label}: features {feats}: train step {c['train_step'] * 1000:.1f} ms, inner iteration "
            f"{c['inner_iteration'] * 1000:.1f} ms; one outer iteration at full data (epochs {epochs}, "
            f"{sample} rows, {inner} inner iterations, {n_real} real): train {train / 60:.1f} min + inner "
            f"{search / 60:.1f} min + real {real / 60:.1f} min = {outer / 3600:.2f} h; a whole search: "
            f"{n_outer} or more outer iterations, each at most this: ~{n_outer * outer / 3600:.1f} h"
        )


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--domain", default="maze,warehouse_even", help="comma-separated domains")
    ap.add_argument("--layouts", type=int, default=None, help="layouts evaluated for real (maze 256, else 4)")
    ap.add_argument("--features", type=int, default=64)
    ap.add_argument("--reduced-features", type=int, default=32)
    ap.add_argument(
        "--real-seconds-per-layout",
        type=float,
        default=None,
        help="use this real-evaluation cost per layout instead of measuring it (e.g. the CPU pool's "
        "figure from docs/benchmarks.md, on a GPU machine without the RHCR core)",
    )
    args = ap.parse_args(argv)
    if args.real_seconds_per_layout is not None and args.real_seconds_per_layout < 0:
        ap.error("--real-seconds-per-layout must be >= 0")
    for domain in args.domain.split(","):
        report(
            domain.strip(), args.layouts, args.features, args.reduced_features, args.real_seconds_per_layout
        )


if __name__ == "__main__":
    main()
