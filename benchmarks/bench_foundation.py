"""Foundation benchmark: sphere (CMA-MAE paper), NCA generation speed, maze QD iteration cost.

    python -m benchmarks.bench_foundation [--sphere-iters 10000] [--maze-iters 20]

Figures are printed after compilation; peers: the CMA-MAE paper's sphere result (QD-score 64.86,
coverage 83 %), the NCA paper's 60 ms per environment (PyTorch, one at a time, 16 cores) and the
target of <= 1 ms per environment at 18x18 and <= 1 h for the 100,000-evaluation maze run.
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import numpy as np


def _timed(fn, repeats: int) -> list[float]:
    jax.block_until_ready(fn())  # compile
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return times


def bench_sphere(iters: int) -> None:
    from nca_qd.qd.benchmarks import normalised_qd_score, sphere_batch_objective, sphere_spec
    from nca_qd.qd.emitters import ESEmitters
    from nca_qd.qd.loop import QDLoop

    loop = QDLoop(ESEmitters(15, 36, 100, 0.5), sphere_batch_objective(), 100, sphere_spec())
    state = loop.init(jax.random.PRNGKey(0))
    state, m, _ = loop.step(state)  # compile
    t0 = time.perf_counter()
    for _ in range(iters - 1):
        state, m, _ = loop.step(state)
    wall = time.perf_counter() - t0
    qd = normalised_qd_score(m["qd_score"], 100 * 100)
    print(
        f"sphere n=100, CMA-MAE 15x36, {iters} iterations: QD-score {qd:.2f} "
        f"(paper 64.86), coverage {100 * m['coverage']:.1f} % (paper 83 %), "
        f"wall {wall:.0f} s ({1000 * wall / max(iters - 1, 1):.1f} ms/iteration)"
    )


def bench_generation() -> None:
    from nca_qd.nca import NCAGenerator

    gen = NCAGenerator(2)
    params = 0.2 * jax.random.normal(jax.random.PRNGKey(0), (150, gen.n_params))
    for shape, iters, label in (((16, 16), 50, "18x18, C=50"), ((64, 64), 200, "66x66, C_eval=200")):
        seed = np.zeros(shape, np.int32)
        seed[shape[0] // 2 - 1 : shape[0] // 2 + 1, shape[1] // 2 - 1 : shape[1] // 2 + 1] = 1
        times = _timed(lambda s=seed, c=iters: gen.generate(params, s, c), 5 if iters == 50 else 2)
        med = statistics.median(times)
        print(
            f"NCA generation b=150 maze {label}: {1000 * med / 150:.3f} ms/environment "
            f"(median of {len(times)}; paper 60 ms/env at S, 130 ms at S_eval, 16 cores)"
        )


UNTRAINED = "untrained_lstm"


def register_untrained(kind: str) -> None:
    """``untrained_lstm<N>``: the learned agent's network with an N-unit LSTM and random
    weights, as a maze agent kind. It rarely reaches a goal, so its episodes run to the horizon:
    an upper bound on any trained agent of that width, and the cost ratio between widths (the
    paper's LSTM-256 against the shipped 64) with no trained weights needed."""
    from nca_qd.agent.network import AgentNet, init_params, learned_policy
    from nca_qd.sim.maze_agent import register_policy

    net = AgentNet(hidden=int(kind[len(UNTRAINED) :]))
    register_policy(kind, lambda: learned_policy(net, init_params(net, jax.random.PRNGKey(0))))


def bench_maze_iteration(iters: int, agent: str) -> None:
    """Wall time of one maze CMA-MAE iteration with the path-length measure from ``agent``."""
    from experiments.cli import compose_config
    from nca_qd.experiment import Experiment

    if agent.startswith(UNTRAINED):
        register_untrained(agent)
        iters = min(iters, 5)  # every episode runs to the horizon

    cfg = compose_config("run", ["domain=maze", "qd.progress=false", f"domain.agent.kind={agent}"])
    exp = Experiment(cfg, run_dir="/tmp/nca_qd_bench_unused")
    state = exp.initial_state()
    state, _, _ = exp.loop.step(state)  # compile
    times = []
    for _ in range(iters):
        state, m, _ = exp.loop.step(state)
        times.append(m["step_seconds"])
    med, mean = statistics.median(times), statistics.mean(times)
    total = mean * exp.n_iterations
    print(
        f"maze CMA-MAE iteration (b=150, {agent} agent, 50 episodes): median "
        f"{med:.3f} s, mean {mean:.3f} s, max {max(times):.3f} s (eigenbasis refresh) over "
        f"{iters}; the default {cfg.qd.n_evals:,}-evaluation run = {exp.n_iterations} "
        f"iterations -> {total / 60:.1f} min at the mean (target <= 60 min)"
    )


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sphere-iters", type=int, default=10_000)
    ap.add_argument("--maze-iters", type=int, default=30)
    ap.add_argument(
        "--maze-agents",
        default="learned,wall_follower,untrained_lstm64,untrained_lstm256",
        help="agents behind the path-length measure (the first is the default; untrained_lstm<N>: "
        "random weights, N LSTM units, episodes to the horizon)",
    )
    args = ap.parse_args([] if argv is None else argv)
    print("== foundation ==")
    bench_generation()
    for agent in args.maze_agents.split(","):
        bench_maze_iteration(args.maze_iters, agent)
    bench_sphere(args.sphere_iters)


if __name__ == "__main__":
    import sys

    main(sys.argv[1:])
