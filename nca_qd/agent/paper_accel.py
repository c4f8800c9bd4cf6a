"""The paper's maze agent as policy kinds: ``paper_accel`` and ``paper_accel_search``.

The paper measured its maze archives (the path-length measure) and its transfer table with the
ACCEL agent of its public repository (``lunjohnzhang/warehouse_env_gen_nca_public``,
``env_search/maze/agents/saved_models/accel_seed_1/model_20000.tar``). That checkpoint is not
shipped here (it is the paper's): give its path as the kind's weights,
``domain.agent.weights=<model_20000.tar>`` (or ``maze_transfer agent_weights=...``). It is read
with numpy (no PyTorch) and the network runs in this repository's maze dynamics
(:mod:`nca_qd.sim.maze_agent`, minigrid's), so a search or a transfer run can use the paper's
measuring instrument instead of ours:

* the network: a 3x3 convolution (16 filters, valid) over the 5x5 view encoded as minigrid does
  (object type, colour, state; divided by 10), the direction one-hot through a dense layer of 5
  (no activation), an LSTM of 256, an actor of dense 32 + tanh + 7 logits; actions are sampled
  and 3-6 (pickup, drop, toggle, done) change nothing, as in an empty maze, so they map to
  :data:`~nca_qd.sim.maze_agent.STAY`.
* ``paper_accel``: each episode on its own with its own direction, as the paper's transfer runs
  (``run_single_rl_agent``, 1 environment) play it. An ordinary per-episode :class:`Policy`.
* ``paper_accel_search``: as the paper's QD search plays it (``RLAgent.eval_and_track`` with
  ``RLAgentConfig.n_envs`` 10): 10 environments of one maze in lock step, episodes back to back,
  the first ``episodes`` to end kept (in step, then environment order), which favours short
  episodes; and the direction input as the paper's ``one_hot`` builds it: its batch index sets,
  in every row, the columns of all 10 environments' directions, so each agent sees their union
  (an agent alone, as in recorded pictures, sees its own). The episodes are coupled, so the
  kind brings its own batched rollout (:attr:`Policy.rollout`); it cannot count visits (DSAGE's
  ancillary target).
"""

from __future__ import annotations

import collections
import logging
import pickle
import zipfile
from functools import lru_cache, partial
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from nca_qd.errors import NcaQdError
from nca_qd.sim import maze_agent as ma

log = logging.getLogger(__name__)

N_ENVS = 10  # the paper's RLAgentConfig.n_envs
N_ACTIONS = 7  # minigrid's actions; 3..6 act on objects the maze has none of
HIDDEN = 256
# minigrid's encoding of our view classes (empty, wall, goal): OBJECT_TO_IDX and COLOR_TO_IDX
ENC_TYPE = np.array([1.0, 2.0, 8.0], np.float32) / 10
ENC_COLOR = np.array([0.0, 5.0, 1.0], np.float32) / 10
_STORAGE = {"FloatStorage": np.float32, "DoubleStorage": np.float64, "LongStorage": np.int64}
# the checkpoint's tensors: short name -> (state dict name, shape)
PARAMS = {
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


def read_state_dict(path: str | Path) -> dict[str, np.ndarray]:
    """A PyTorch zip checkpoint of float tensors as ``{name: array}``, read without PyTorch
    (only the globals a state dict of tensors names are allowed)."""
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
    out = {}
    for short, (name, shape) in PARAMS.items():
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


def to_action(logits: jax.Array, key: jax.Array) -> jax.Array:
    """A sampled minigrid action as ours: 3..6 do nothing in a maze (STAY)."""
    action = jax.random.categorical(key, logits)
    return jnp.where(action >= 3, ma.STAY, action).astype(jnp.int32)


def play_lockstep(
    p,
    layout,
    start,
    goal,
    key,
    n_episodes: int = 50,
    horizon: int = 648,
    n_envs: int = N_ENVS,
    active: jax.Array | bool = True,
):
    """``(lengths [n_episodes], reached [n_episodes])`` of the first episodes to end among
    ``n_envs`` environments playing one bordered maze back to back, with the union of their
    directions as input (module docstring; ``n_envs`` 1 is the transfer protocol). An inactive
    maze (no start-goal path) plays nothing: every episode counts the horizon."""
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
        "lengths": jnp.full(n_episodes, horizon, jnp.int32),
        "reached": jnp.zeros(n_episodes, bool),
        "n": jnp.where(active, 0, n_episodes).astype(jnp.int32),
        "step": jnp.int32(0),
        "key": key,
    }

    def body(s):
        key, k_act, k_dir = jax.random.split(s["key"], 3)
        agents = ma.AgentState(s["pos"], s["dir"])
        views = jax.vmap(lambda a: ma.observe(env, a))(agents)
        union = jnp.any(jax.nn.one_hot(s["dir"], 4) > 0, axis=0).astype(jnp.float32)
        logits, h, c = jax.vmap(forward, in_axes=(None, 0, None, 0, 0))(p, views, union, s["h"], s["c"])
        action = to_action(logits, k_act)
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
def play_lockstep_batch(
    p,
    layouts,
    starts,
    goals,
    keys,
    n_episodes: int = 50,
    horizon: int = 648,
    n_envs: int = N_ENVS,
    active=None,
):
    """:func:`play_lockstep` over a batch of bordered mazes of one shape."""
    active = jnp.ones(layouts.shape[0], bool) if active is None else jnp.asarray(active, bool)
    return jax.vmap(lambda lay, s, g, k, a: play_lockstep(p, lay, s, g, k, n_episodes, horizon, n_envs, a))(
        layouts, starts, goals, keys, active
    )


class Memory(NamedTuple):
    h: jax.Array  # [HIDDEN]
    c: jax.Array  # [HIDDEN]


def _episode_policy(p, rollout=None) -> ma.Policy:
    """The network as a per-episode policy (its own direction as input)."""

    def prepare(layout, goal):
        return None

    def init(key):
        return Memory(jnp.zeros(HIDDEN), jnp.zeros(HIDDEN))

    def act(env, state, memory, key):
        view = ma.observe(env, state)
        logits, h, c = forward(p, view, jax.nn.one_hot(state.dir, 4), memory.h, memory.c)
        return to_action(logits, key), Memory(h, c)

    return ma.Policy(prepare, init, act, deterministic=False, rollout=rollout)


# SHA-256 of ``accel_seed_1/model_20000.tar`` in the paper's repository (the file every shipped
# result with these kinds was measured by): a run's log says whether its weights are that file.
PAPER_CHECKPOINT_SHA256 = "5ad0ce09ce1f1763f4b2c16f2ec08da1abb6a0564b0cf715e9be4c0ac7a634ae"


def checkpoint_sha256(path: str | Path) -> str:
    import hashlib

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


@lru_cache(maxsize=4)
def load_params(path: str) -> dict[str, jax.Array]:
    """The paper's checkpoint at ``path``, checked (cached per path). Another file with the
    same network (another seed's, or a later step's) loads too, with a warning naming it: a
    result measured by it is not measured by the paper's agent."""
    params = agent_params(read_state_dict(path))  # a missing or broken file: one clear error
    digest = checkpoint_sha256(path)
    if digest != PAPER_CHECKPOINT_SHA256:
        log.warning("%s is not the paper's accel_seed_1/model_20000.tar (SHA-256 %s)", path, digest)
    return params


def _params(weights: str | Path | None, kind: str) -> dict[str, jax.Array]:
    if weights is None:
        raise NcaQdError(
            f"maze agent {kind!r} needs the paper's checkpoint as its weights (not shipped here): "
            "weights=<accel_seed_1/model_20000.tar of lunjohnzhang/warehouse_env_gen_nca_public>"
        )
    return load_params(str(Path(weights)))


def transfer_policy(weights: str | Path | None = None) -> ma.Policy:
    """``paper_accel``: the paper's agent, one episode at a time (its transfer runs' protocol)."""
    return _episode_policy(_params(weights, "paper_accel"))


def search_policy(weights: str | Path | None = None, n_envs: int = N_ENVS) -> ma.Policy:
    """``paper_accel_search``: the paper's agent as its QD search played it (10 environments in
    lock step, first episodes to end kept, union of directions). ``act`` alone (a recorded
    picture) plays one episode with the agent's own direction."""
    p = _params(weights, "paper_accel_search")

    def rollout(layouts, starts, goals, keys, episodes, horizon, active):
        lengths, reached = play_lockstep_batch(
            p, layouts, starts, goals, keys, episodes, horizon, n_envs, active
        )
        return ma.Rollout(lengths, reached)

    return _episode_policy(p, rollout)
