"""The paper's maze agent, side by side with ours, on the mazes of a maze run's archive.

    python -m benchmarks.paper_maze_agent --checkpoint <model_20000.tar> \
        --run results/maze_qd/cma_mae_maze_entropy_s0

The maze archive's path-length measure is the learned agent's mean episode length, so the agent
decides which cells a search can fill. The paper measured with the ACCEL agent of its public
repository (``lunjohnzhang/warehouse_env_gen_nca_public``,
``env_search/maze/agents/saved_models/accel_seed_1/model_20000.tar``, a PyTorch checkpoint that
is not shipped here: fetch it and give its path). This tool reads that checkpoint with numpy
(no PyTorch), runs the network in this repository's maze dynamics (:mod:`nca_qd.sim.maze_agent`,
minigrid's) and evaluates it the way the paper's ``RLAgent.eval_and_track`` does:

* the network: a 3x3 convolution (16 filters, valid) over the 5x5 view encoded as minigrid does
  (object type, colour, state; divided by 10), the direction one-hot through a dense layer of 5
  (no activation), an LSTM of 256, an actor of dense 32 + tanh + 7 logits, actions sampled;
  actions 3-6 (pickup, drop, toggle, done) change nothing, as in an empty maze;
* 10 environments in lock step, episodes back to back, the first 50 episodes to end kept (in
  step, then environment order) — which favours short episodes;
* the direction input as the paper's ``one_hot`` builds it: its batch index sets, in every row,
  the columns of all 10 environments' directions, so each agent sees their union.

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
import collections
import csv
import pickle
import sys
import zipfile
from functools import partial
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from nca_qd.errors import NcaQdError
from nca_qd.sim import maze_agent as ma

N_ENVS = 10  # the paper's RLAgentConfig.n_envs
N_ACTIONS = 7  # minigrid's actions; 3..6 act on objects the maze has none of
HIDDEN = 256
# minigrid's encoding of our view classes (empty, wall, goal): OBJECT_TO_IDX and COLOR_TO_IDX
ENC_TYPE = np.array([1.0, 2.0, 8.0], np.float32) / 10
ENC_COLOR = np.array([0.0, 5.0, 1.0], np.float32) / 10
SAMPLE_NAME, CSV_NAME = "paper_agent_sample.npz", "paper_agent_paths.csv"
BANDS = (0.0, 0.1, 0.2, 0.3, 0.45, 0.6, 0.8, 1.0)
_STORAGE = {"FloatStorage": np.float32, "DoubleStorage": np.float64, "LongStorage": np.int64}


def read_state_dict(path: str | Path) -> dict[str, np.ndarray]:
    """A PyTorch zip checkpoint of float tensors as ``{name: array}``, read without PyTorch."""
    try:
        z = zipfile.ZipFile(path)
    except (OSError, zipfile.BadZipFile) as exc:
        raise NcaQdError(f"{path}: not a PyTorch zip checkpoint ({exc})") from None
    prefix = z.namelist()[0].split("/")[0]

    def rebuild(storage, offset, size, stride, *_):
        n = storage.itemsize
        return np.lib.stride_tricks.as_strided(
            storage[offset:], shape=tuple(size), strides=[s * n for s in stride]
        ).copy()

    class Reader(pickle.Unpickler):
        def find_class(self, module, name):
            if (module, name) == ("torch._utils", "_rebuild_tensor_v2"):
                return rebuild
            if module == "torch" and name in _STORAGE:
                return name
            if (module, name) == ("collections", "OrderedDict"):
                return collections.OrderedDict  # (a plain dict cannot take its _metadata)
            raise pickle.UnpicklingError(f"unexpected {module}.{name} in {path}")

        def persistent_load(self, pid):
            _, storage_type, key, _location, _numel = pid
            return np.frombuffer(z.read(f"{prefix}/data/{key}"), _STORAGE[storage_type])

    try:
        state = Reader(z.open(f"{prefix}/data.pkl")).load()
    except (KeyError, pickle.UnpicklingError, ValueError) as exc:
        raise NcaQdError(f"{path}: not a state dict of tensors ({exc})") from None
    return {k: np.asarray(v) for k, v in state.items()}


def agent_params(state: dict[str, np.ndarray]) -> dict[str, jax.Array]:
    """The network's parameters under short names, checked against the expected shapes."""
    names = {
        "conv_w": ("image_conv.0.weight", (16, 3, 3, 3)),
        "conv_b": ("image_conv.0.bias", (16,)),
        "dir_w": ("scalar_embed.weight", (5, 4)),
        "dir_b": ("scalar_embed.bias", (5,)),
        "w_ih": ("rnn.rnn.weight_ih_l0", (4 * HIDDEN, 149)),
        "w_hh": ("rnn.rnn.weight_hh_l0", (4 * HIDDEN, HIDDEN)),
        "b_ih": ("rnn.rnn.bias_ih_l0", (4 * HIDDEN,)),
        "b_hh": ("rnn.rnn.bias_hh_l0", (4 * HIDDEN,)),
        "actor_w": ("actor.0.0.weight", (32, HIDDEN)),
        "actor_b": ("actor.0.0.bias", (32,)),
        "logits_w": ("actor.1.linear.weight", (N_ACTIONS, 32)),
        "logits_b": ("actor.1.linear.bias", (N_ACTIONS,)),
    }
    out = {}
    for short, (name, shape) in names.items():
        if name not in state or tuple(state[name].shape) != shape:
            got = tuple(state[name].shape) if name in state else "missing"
            raise NcaQdError(f"checkpoint: {name} should be {shape}, is {got}")
        out[short] = jnp.asarray(state[name], jnp.float32)
    return out


def forward(p, view, dir_input, h, c):
    """One agent step: ``view [5, 5]`` (row 0 farthest ahead, column 0 to the left), the
    direction input ``[4]``, LSTM state -> (logits [7], h, c)."""
    img = jnp.stack([jnp.asarray(ENC_TYPE)[view].T, jnp.asarray(ENC_COLOR)[view].T, jnp.zeros((5, 5))])
    patches = jnp.stack([img[:, i : i + 3, j : j + 3] for i in range(3) for j in range(3)])
    conv = jnp.einsum("ocab,pcab->op", p["conv_w"], patches) + p["conv_b"][:, None]  # [16, 9]
    x = jnp.concatenate([jax.nn.relu(conv.reshape(-1)), p["dir_w"] @ dir_input + p["dir_b"]])
    g = p["w_ih"] @ x + p["b_ih"] + p["w_hh"] @ h + p["b_hh"]
    i, f, gg, o = jnp.split(g, 4)  # PyTorch's gate order
    c = jax.nn.sigmoid(f) * c + jax.nn.sigmoid(i) * jnp.tanh(gg)
    h = jax.nn.sigmoid(o) * jnp.tanh(c)
    logits = p["logits_w"] @ jnp.tanh(p["actor_w"] @ h + p["actor_b"]) + p["logits_b"]
    return logits, h, c


def evaluate_maze(
    p, layout, start, goal, key, n_episodes: int = 50, horizon: int = 648, n_envs: int = N_ENVS
):
    """``(lengths [n_episodes], reached [n_episodes])`` of the first episodes to end among
    ``n_envs`` environments playing one bordered maze back to back (module docstring; the
    paper's search used 10, its transfer runs 1, where the direction input is the agent's own)."""
    env = ma.make_env(layout, goal)
    start = jnp.asarray(start, jnp.int32)
    cap = n_episodes * horizon // n_envs + horizon + 1
    k0, key = jax.random.split(key)
    s0 = {
        "pos": jnp.tile(start, (n_envs, 1)),
        "dir": jax.random.randint(k0, (n_envs,), 0, 4, jnp.int32),
        "h": jnp.zeros((n_envs, HIDDEN)),
        "c": jnp.zeros((n_envs, HIDDEN)),
        "t": jnp.zeros(n_envs, jnp.int32),
        "lengths": jnp.zeros(n_episodes, jnp.int32),
        "reached": jnp.zeros(n_episodes, bool),
        "n": jnp.int32(0),
        "step": jnp.int32(0),
        "key": key,
    }

    def body(s):
        key, k_act, k_dir = jax.random.split(s["key"], 3)
        agents = ma.AgentState(s["pos"], s["dir"])
        views = jax.vmap(lambda a: ma.observe(env, a))(agents)
        union = jnp.any(jax.nn.one_hot(s["dir"], 4) > 0, axis=0).astype(jnp.float32)
        logits, h, c = jax.vmap(forward, in_axes=(None, 0, None, 0, 0))(p, views, union, s["h"], s["c"])
        action = jax.random.categorical(k_act, logits)
        action = jnp.where(action >= 3, ma.STAY, action).astype(jnp.int32)
        moved = jax.vmap(lambda a, u: ma.step(env, a, u))(agents, action)
        t = s["t"] + 1
        reached = jnp.all(moved.pos == env.goal, axis=-1)
        done = reached | (t >= horizon)
        slot = jnp.where(done, s["n"] + jnp.cumsum(done) - 1, n_episodes)  # env order within a step
        fresh = jax.random.randint(k_dir, (n_envs,), 0, 4, jnp.int32)
        return {
            "pos": jnp.where(done[:, None], start, moved.pos),
            "dir": jnp.where(done, fresh, moved.dir),
            "h": jnp.where(done[:, None], 0.0, h),
            "c": jnp.where(done[:, None], 0.0, c),
            "t": jnp.where(done, 0, t),
            "lengths": s["lengths"].at[slot].set(t, mode="drop"),
            "reached": s["reached"].at[slot].set(reached, mode="drop"),
            "n": s["n"] + jnp.sum(done, dtype=jnp.int32),
            "step": s["step"] + 1,
            "key": key,
        }

    s = jax.lax.while_loop(lambda s: (s["n"] < n_episodes) & (s["step"] < cap), body, s0)
    return s["lengths"], s["reached"]


@partial(jax.jit, static_argnames=("n_episodes", "horizon", "n_envs"))
def evaluate_batch(
    p, layouts, starts, goals, keys, n_episodes: int = 50, horizon: int = 648, n_envs: int = N_ENVS
):
    """:func:`evaluate_maze` over a batch of bordered mazes of one shape."""
    return jax.vmap(lambda lay, s, g, k: evaluate_maze(p, lay, s, g, k, n_episodes, horizon, n_envs))(
        layouts, starts, goals, keys
    )


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
        lengths, reached = evaluate_batch(
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
    try:
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
    except NcaQdError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    key = jax.random.PRNGKey(args.seed)
    k_paper, k_sample = jax.random.split(key)
    size = args.paper_maze + 2
    for name, res in paper_maze(p, k_paper, args.paper_maze).items():
        print(
            f"paper_nca_{size}x{size}, 100 episodes, {name}: success {res['success']:.2f}, "
            f"mean episode length {res['mean_length']:.0f}"
        )
    n = len(sample["cell"])
    lengths, reached = evaluate_batch(
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
    return 0


if __name__ == "__main__":
    sys.exit(main())
