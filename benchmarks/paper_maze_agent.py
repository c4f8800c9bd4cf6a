"""The paper's maze agent, side by side with ours, on the mazes of a maze run's archive.

    python -m benchmarks.paper_maze_agent --checkpoint <model_20000.tar> \
        --run results/maze_qd/cma_mae_maze_entropy_s0

The maze archive's path-length measure is the learned agent's mean episode length, so the agent
decides which cells a search can fill. The paper measured with the ACCEL agent of its public
repository (``lunjohnzhang/warehouse_env_gen_nca_public``,
``env_search/maze/agents/saved_models/accel_seed_1/model_20000.tar``, a PyTorch checkpoint that
is not shipped here: fetch it and give its path). The agent, its checkpoint reader and both
of the paper's protocols live in :mod:`nca_qd.agent.paper_accel` (the maze kinds
``paper_accel`` and ``paper_accel_search``); this tool compares it with ours.

The paper's search measures with 10 environments (``RLAgentConfig.n_envs``), its transfer runs
(``run_single_rl_agent``) with 1, where the direction input is the agent's own. The tool first
plays the paper's NCA maze (``--paper-maze 16``: 18 x 18 with its border; ``64``: 66 x 66; 100
episodes, horizon 2 x tiles) with the paper's agent both ways and with ours, then a seeded
sample of the run's elites per band of the first measure (``--per-band``, default 30; the
sample's layouts go to ``paper_agent_sample.npz`` in the run directory, so the comparison can be
re-run where the archive is not shipped) with the search's protocol, and prints, per band, both
agents' median path length and shares at 200 and 400 steps or more; per-maze figures go to
``paper_agent_paths.csv`` beside it. Bad input: one line on stderr, exit status 2.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.cli import guarded
from nca_qd.agent.paper_accel import N_ENVS, agent_params, play_lockstep_batch, read_state_dict
from nca_qd.errors import NcaQdError
from nca_qd.sim import maze_agent as ma

SAMPLE_NAME, CSV_NAME = "paper_agent_sample.npz", "paper_agent_paths.csv"
BANDS = (0.0, 0.1, 0.2, 0.3, 0.45, 0.6, 0.8, 1.0)


def make_sample(run_dir: Path, per_band: int, seed: int = 0) -> dict[str, np.ndarray]:
    """A seeded sample of the run's solvable elites per band (from its ``maze_paths.csv``),
    grown at the training size: bordered layouts, start, goal, cell, first measure, our path."""
    from benchmarks.maze_paths import CSV_NAME as PATHS_CSV
    from benchmarks.maze_paths import read_rows
    from nca_qd.domains import make_domain
    from nca_qd.domains.maze import longest_shortest_path
    from nca_qd.pipeline import generate, make_generator
    from nca_qd.run_dir import load_archive, load_run_config

    if not (run_dir / PATHS_CSV).is_file():
        raise NcaQdError(f"{run_dir}: no {PATHS_CSV} (run python -m benchmarks.maze_paths {run_dir})")
    rows = read_rows(run_dir / PATHS_CSV)
    m0 = np.array([r["m0"] for r in rows])
    solvable = np.array([r["objective"] > 0 for r in rows])
    rng = np.random.default_rng(seed)
    pick = []
    for lo, hi in zip(BANDS[:-1], BANDS[1:]):
        idx = np.flatnonzero((m0 >= lo) & ((m0 < hi) | (hi == BANDS[-1])) & solvable)
        pick.append(rng.choice(idx, min(per_band, len(idx)), replace=False))
    chosen = np.sort(np.concatenate(pick))
    cfg = load_run_config(run_dir)
    archive = load_archive(run_dir, "result")
    domain = make_domain(cfg.domain)
    cells = np.array([rows[i]["cell"] for i in chosen], np.int64)
    genotypes = np.stack([np.asarray(archive["genotypes"][c], np.float32) for c in cells])
    regions = np.asarray(generate(domain, make_generator(domain), genotypes), np.int8)
    _, start, goal = longest_shortest_path(jnp.asarray(regions == 0))
    return {
        "layouts": np.pad(regions, ((0, 0), (1, 1), (1, 1)), constant_values=ma.WALL),
        "start": np.asarray(start) + 1,
        "goal": np.asarray(goal) + 1,
        "cell": cells,
        "m0": m0[chosen],
        "our_path_length": np.array([rows[i]["path_length"] for i in chosen]),
    }


def paper_maze(p, key, interior: int = 16) -> dict[str, dict]:
    """The paper's NCA maze (``interior`` 16 or 64, with its border), 100 episodes: the paper's
    agent as its transfer runs play it (1 environment: its own direction) and as its search
    does (10 environments: the union of their directions), and our shipped agent."""
    from nca_qd.domains.maze import run_agent, solve_start_goal
    from nca_qd.io import load_map, reference_maps_dir

    rows = load_map(reference_maps_dir() / "maze" / f"paper_nca_{interior}x{interior}.json").rows
    layout = np.pad(np.array([[ch == "X" for ch in r] for r in rows], np.int32), 1, constant_values=ma.WALL)
    start, goal, _ = solve_start_goal(layout)
    horizon = 2 * layout.size
    out = {}
    for name, n_envs in (("paper's agent, 1 environment", 1), ("paper's agent, 10 environments", N_ENVS)):
        lengths, reached = play_lockstep_batch(
            p,
            layout[None],
            start[None],
            goal[None],
            key[None],
            n_episodes=100,
            horizon=horizon,
            n_envs=n_envs,
        )
        out[name] = {"success": float(np.mean(reached)), "mean_length": float(np.mean(lengths))}
    ours = run_agent(layout, start, goal, key, kind="learned", episodes=100, horizon=horizon)
    out["our agent"] = {"success": float(ours.reached.mean()), "mean_length": float(ours.lengths.mean())}
    return out


def band_lines(m0: np.ndarray, ours: np.ndarray, paper: np.ndarray, success: np.ndarray) -> list[str]:
    lines = [
        "| band | mazes | path p50, ours | paper's | >= 200 steps, ours | paper's | >= 400, ours | "
        "paper's | paper's agent success |",
        "|" + "---|" * 9,
    ]
    for lo, hi in zip(BANDS[:-1], BANDS[1:]):
        m = (m0 >= lo) & ((m0 < hi) | (hi == BANDS[-1]))
        if not m.any():
            continue
        o, q = ours[m], paper[m]
        lines.append(
            f"| {lo:g}-{hi:g} | {int(m.sum())} | {np.median(o):.0f} | {np.median(q):.0f} | "
            f"{np.mean(o >= 200):.2f} | {np.mean(q >= 200):.2f} | {np.mean(o >= 400):.2f} | "
            f"{np.mean(q >= 400):.2f} | {success[m].mean():.2f} |"
        )
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks.paper_maze_agent", description=__doc__.split("\n")[0]
    )
    ap.add_argument("--checkpoint", required=True, help="the paper's accel_seed_1/model_20000.tar")
    ap.add_argument("--run", default="results/maze_qd/cma_mae_maze_entropy_s0")
    ap.add_argument("--per-band", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--paper-maze", type=int, choices=(16, 64), default=16, help="the paper's NCA maze's interior"
    )
    args = ap.parse_args(argv)
    return guarded(lambda: _side_by_side(args))


def _side_by_side(args: argparse.Namespace) -> None:
    p = agent_params(read_state_dict(args.checkpoint))
    run_dir = Path(args.run)
    if not (run_dir / "config.yaml").is_file():
        raise NcaQdError(f"{run_dir}: not a run directory (no config.yaml)")
    sample_path = run_dir / SAMPLE_NAME
    if sample_path.is_file():
        with np.load(sample_path) as f:
            sample = {k: f[k] for k in f.files}
    else:
        sample = make_sample(run_dir, args.per_band, args.seed)
        np.savez_compressed(sample_path, **sample)
    key = jax.random.PRNGKey(args.seed)
    k_paper, k_sample = jax.random.split(key)
    size = args.paper_maze + 2
    for name, res in paper_maze(p, k_paper, args.paper_maze).items():
        print(
            f"paper_nca_{size}x{size}, 100 episodes, {name}: success {res['success']:.2f}, "
            f"mean episode length {res['mean_length']:.0f}"
        )
    n = len(sample["cell"])
    lengths, reached = play_lockstep_batch(
        p,
        jnp.asarray(sample["layouts"], jnp.int32),
        jnp.asarray(sample["start"]),
        jnp.asarray(sample["goal"]),
        jax.random.split(k_sample, n),
    )
    paper_path = np.asarray(lengths).mean(axis=1)
    success = np.asarray(reached).mean(axis=1)
    with open(run_dir / CSV_NAME, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["cell", "m0", "our_path_length", "paper_path_length", "paper_success"])
        for row in zip(sample["cell"], sample["m0"], sample["our_path_length"], paper_path, success):
            w.writerow([int(row[0]), f"{row[1]:.5f}", f"{row[2]:.2f}", f"{row[3]:.2f}", f"{row[4]:.2f}"])
    print(f"{run_dir}: {n} elites ({sample_path.name}), per maze in {run_dir / CSV_NAME}")
    print("\n".join(band_lines(sample["m0"], sample["our_path_length"], paper_path, success)))


if __name__ == "__main__":
    sys.exit(main())
