"""The paper's maze agent (nca_qd.agent.paper_accel and benchmarks.paper_maze_agent): the checkpoint
reader, the network step, the paper's two episode protocols, the maze kinds that use them."""

from __future__ import annotations

import collections
import io
import pickle
import sys
import types
import zipfile

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from benchmarks.paper_maze_agent import main
from nca_qd.agent.paper_accel import (
    ENC_COLOR,
    ENC_TYPE,
    HIDDEN,
    agent_params,
    forward,
    play_lockstep,
    read_state_dict,
)
from nca_qd.errors import NcaQdError
from nca_qd.sim import maze_agent as ma

SHAPES = {
    "image_conv.0.weight": (16, 3, 3, 3),
    "image_conv.0.bias": (16,),
    "scalar_embed.weight": (5, 4),
    "scalar_embed.bias": (5,),
    "rnn.rnn.weight_ih_l0": (4 * HIDDEN, 149),
    "rnn.rnn.weight_hh_l0": (4 * HIDDEN, HIDDEN),
    "rnn.rnn.bias_ih_l0": (4 * HIDDEN,),
    "rnn.rnn.bias_hh_l0": (4 * HIDDEN,),
    "actor.0.0.weight": (32, HIDDEN),
    "actor.0.0.bias": (32,),
    "actor.1.linear.weight": (7, 32),
    "actor.1.linear.bias": (7,),
}


class _Storage:
    def __init__(self, key, data):
        self.key, self.data = key, data


class _Tensor:
    def __init__(self, storage, size, stride):
        self.storage, self.size, self.stride = storage, size, stride

    def __reduce__(self):
        rebuild = sys.modules["torch._utils"]._rebuild_tensor_v2
        return (rebuild, (self.storage, 0, self.size, self.stride, False))


def write_checkpoint(path, tensors: dict[str, tuple[np.ndarray, tuple, tuple]], monkeypatch):
    """A zip in PyTorch's layout (archive/data.pkl + archive/data/<key>), written without PyTorch:
    a fake ``torch`` module provides the globals the pickle names."""
    torch = types.ModuleType("torch")
    utils = types.ModuleType("torch._utils")

    class FloatStorage:
        pass

    FloatStorage.__module__, FloatStorage.__qualname__ = "torch", "FloatStorage"
    torch.FloatStorage = FloatStorage

    def _rebuild_tensor_v2(*args):
        raise AssertionError("only pickled here")

    _rebuild_tensor_v2.__module__ = "torch._utils"
    _rebuild_tensor_v2.__qualname__ = "_rebuild_tensor_v2"
    utils._rebuild_tensor_v2 = _rebuild_tensor_v2
    monkeypatch.setitem(sys.modules, "torch", torch)
    monkeypatch.setitem(sys.modules, "torch._utils", utils)

    class P(pickle.Pickler):
        def persistent_id(self, obj):
            if isinstance(obj, _Storage):
                return ("storage", FloatStorage, obj.key, "cpu", obj.data.size)
            return None

    state, blobs = collections.OrderedDict(), {}
    for i, (name, (flat, size, stride)) in enumerate(tensors.items()):
        storage = _Storage(str(i), np.asarray(flat, np.float32))
        blobs[str(i)] = storage.data.tobytes()
        state[name] = _Tensor(storage, size, stride)
    buf = io.BytesIO()
    state._metadata = collections.OrderedDict()  # as PyTorch's state dicts carry
    P(buf, protocol=2).dump(state)
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("archive/data.pkl", buf.getvalue())
        for k, b in blobs.items():
            z.writestr(f"archive/data/{k}", b)


def test_reader_rebuilds_tensors_with_their_strides(tmp_path, monkeypatch):
    flat = np.arange(6, dtype=np.float32)
    write_checkpoint(
        tmp_path / "m.tar",
        {"a": (flat, (2, 3), (3, 1)), "a_t": (flat, (3, 2), (1, 3)), "v": (flat[:4], (4,), (1,))},
        monkeypatch,
    )
    state = read_state_dict(tmp_path / "m.tar")
    np.testing.assert_array_equal(state["a"], flat.reshape(2, 3))
    np.testing.assert_array_equal(state["a_t"], flat.reshape(2, 3).T)
    np.testing.assert_array_equal(state["v"], flat[:4])
    with pytest.raises(Exception, match="should be"):
        agent_params(state)


def random_params(seed=0, scale=0.3):
    rng = np.random.default_rng(seed)
    state = {k: rng.normal(0, scale, s).astype(np.float32) for k, s in SHAPES.items()}
    return state, agent_params(state)


def test_forward_matches_a_loop_over_the_spec():
    state, p = random_params()
    rng = np.random.default_rng(1)
    view = rng.integers(0, 3, (5, 5))
    d = np.array([1.0, 0.0, 1.0, 0.0], np.float32)
    h = rng.normal(0, 1, HIDDEN).astype(np.float32)
    c = rng.normal(0, 1, HIDDEN).astype(np.float32)
    # image[channel, x, y] of minigrid's encoding, x to the right, y = view row (0 farthest ahead)
    img = np.zeros((3, 5, 5), np.float32)
    for y in range(5):
        for x in range(5):
            img[0, x, y], img[1, x, y] = ENC_TYPE[view[y, x]], ENC_COLOR[view[y, x]]
    w, b = state["image_conv.0.weight"], state["image_conv.0.bias"]
    conv = np.zeros((16, 3, 3), np.float32)
    for o in range(16):
        for i in range(3):
            for j in range(3):
                conv[o, i, j] = b[o] + np.sum(w[o] * img[:, i : i + 3, j : j + 3])
    x = np.concatenate(
        [np.maximum(conv.reshape(-1), 0), state["scalar_embed.weight"] @ d + state["scalar_embed.bias"]]
    )
    g = (
        state["rnn.rnn.weight_ih_l0"] @ x
        + state["rnn.rnn.bias_ih_l0"]
        + state["rnn.rnn.weight_hh_l0"] @ h
        + state["rnn.rnn.bias_hh_l0"]
    )
    sig = lambda z: 1 / (1 + np.exp(-z))  # noqa: E731
    gi, gf, gg, go = g[:HIDDEN], g[HIDDEN : 2 * HIDDEN], g[2 * HIDDEN : 3 * HIDDEN], g[3 * HIDDEN :]
    c2 = sig(gf) * c + sig(gi) * np.tanh(gg)
    h2 = sig(go) * np.tanh(c2)
    a = np.tanh(state["actor.0.0.weight"] @ h2 + state["actor.0.0.bias"])
    logits = state["actor.1.linear.weight"] @ a + state["actor.1.linear.bias"]
    got_logits, got_h, got_c = forward(p, jnp.asarray(view), jnp.asarray(d), jnp.asarray(h), jnp.asarray(c))
    np.testing.assert_allclose(np.asarray(got_c), c2, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(np.asarray(got_h), h2, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(np.asarray(got_logits), logits, rtol=1e-4, atol=1e-4)


def test_the_first_episodes_to_end_are_kept():
    """An agent that only walks forward, in a straight corridor: an episode that starts facing
    the goal (1 in 4 random directions) ends after the corridor's length, any other at the
    horizon. Ten environments play back to back until 100 episodes have ended: every slot is
    filled with one of the two lengths, and about a quarter are short."""
    state = {k: np.zeros(s, np.float32) for k, s in SHAPES.items()}
    state["actor.1.linear.bias"][2] = 50.0  # FORWARD
    p = agent_params(state)
    layout = np.ones((3, 8), np.int32)
    layout[1, 1:7] = ma.EMPTY
    start, goal = np.array([1, 1]), np.array([1, 6])
    key = jax.random.PRNGKey(3)
    lengths, reached = play_lockstep(p, layout, start, goal, key, n_episodes=100, horizon=30)
    lengths, reached = np.asarray(lengths), np.asarray(reached)
    assert set(lengths.tolist()) <= {5, 30}
    np.testing.assert_array_equal(reached, lengths == 5)
    assert 0.1 < reached.mean() < 0.45


def test_bad_checkpoint_is_one_line_and_exit_2(tmp_path, capsys):
    (tmp_path / "x.tar").write_text("not a zip")
    assert main(["--checkpoint", str(tmp_path / "x.tar")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a PyTorch zip checkpoint" in err[0]


# --------------------------------------------------------------------------- the maze kinds

CORRIDOR = np.ones((3, 8), np.int32)
CORRIDOR[1, 1:7] = ma.EMPTY
C_START, C_GOAL = np.array([1, 1]), np.array([1, 6])


def compass_checkpoint(path, monkeypatch):
    """An agent that goes forward when its direction input reads "east" alone and turns right
    otherwise: the direction embedding's unit 0 is 2 x east - 3 x (any other), passed through
    an LSTM unit with its input and output gates open and its forget gate shut, then to the
    forward (+) and right (-) logits. Played with its own direction it faces east within three
    turns and walks the corridor (5-8 steps); fed the union of ten agents' directions it keeps
    turning."""
    state = {k: np.zeros(s, np.float32) for k, s in SHAPES.items()}
    state["scalar_embed.weight"][0] = [2.0, -3.0, -3.0, -3.0]  # east, south, west, north
    b = state["rnn.rnn.bias_ih_l0"]
    b[:HIDDEN], b[HIDDEN : 2 * HIDDEN], b[3 * HIDDEN :] = 20.0, -20.0, 20.0  # gates i, f, o
    state["rnn.rnn.weight_ih_l0"][2 * HIDDEN, 144] = 1.0  # cell input of unit 0 <- embedding 0
    state["actor.0.0.weight"][0, 0] = 10.0
    state["actor.1.linear.weight"][2, 0], state["actor.1.linear.weight"][1, 0] = 20.0, -20.0
    tensors = {k: (v.reshape(-1), v.shape, _strides(v.shape)) for k, v in state.items()}
    write_checkpoint(path, tensors, monkeypatch)
    return agent_params(state)


def _strides(shape):
    return tuple(int(np.prod(shape[i + 1 :])) for i in range(len(shape)))


def test_transfer_kind_plays_each_episode_with_its_own_direction(tmp_path, monkeypatch):
    compass_checkpoint(tmp_path / "m.tar", monkeypatch)
    policy = ma.get_policy("paper_accel", str(tmp_path / "m.tar"))
    res = ma.rollout(policy, jnp.asarray(CORRIDOR), C_START, C_GOAL, jax.random.PRNGKey(0), 40, 30)
    lengths = np.asarray(res.lengths)
    assert np.asarray(res.reached).all() and set(lengths.tolist()) <= {5, 6, 7, 8}
    assert len(set(lengths.tolist())) > 1  # random first directions


def test_search_kind_plays_the_papers_lockstep_protocol(tmp_path, monkeypatch):
    """``paper_accel_search`` through the domain's rollout is exactly the lock-step protocol,
    maze by maze with the evaluator's keys: the union input keeps the compass agent turning
    (where its own direction got it home every time); a maze without a path plays nothing."""
    from nca_qd.domains.maze import maze_key

    p = compass_checkpoint(tmp_path / "m.tar", monkeypatch)
    policy = ma.get_policy("paper_accel_search", str(tmp_path / "m.tar"))
    layouts = jnp.asarray(np.stack([CORRIDOR, CORRIDOR]))
    starts, goals = jnp.asarray(np.stack([C_START, C_START])), jnp.asarray(np.stack([C_GOAL, C_GOAL]))
    key = jax.random.PRNGKey(7)
    keys = jax.vmap(lambda i: maze_key(key, i))(jnp.arange(2))
    active = jnp.array([True, False])
    res = ma.rollout_batch(policy, layouts, starts, goals, keys, 20, 30, active)
    want, want_reached = play_lockstep(p, layouts[0], starts[0], goals[0], keys[0], 20, 30)
    np.testing.assert_array_equal(np.asarray(res.lengths[0]), np.asarray(want))
    np.testing.assert_array_equal(np.asarray(res.reached[0]), np.asarray(want_reached))
    assert np.asarray(res.reached[0]).mean() < 0.2
    assert (np.asarray(res.lengths[1]) == 30).all() and not np.asarray(res.reached[1]).any()
    with pytest.raises(NcaQdError, match="cannot count visits"):
        ma.rollout_batch(policy, layouts, starts, goals, keys, 20, 30, active, count_visits=True)


def test_maze_domain_scores_with_the_papers_agent(tmp_path, monkeypatch):
    """``domain.agent.kind=paper_accel_search`` with the checkpoint as weights: the evaluator's
    episode lengths are the lock-step protocol's for each maze's key; no weights, or a file that
    is no checkpoint: one clear error."""
    from nca_qd.domains import make_domain
    from nca_qd.domains.maze import longest_shortest_path, maze_key

    p = compass_checkpoint(tmp_path / "m.tar", monkeypatch)
    cfg = {
        "name": "maze",
        "size": {"train": [6, 6], "eval": [8, 8]},
        "nca_iters": {"train": 5, "eval": 5},
        "measures": {"names": ["n_walls", "path_length"], "ranges": [[0, 36], [0, 128]], "cells": [4, 4]},
        "agent": {"kind": "paper_accel_search", "weights": str(tmp_path / "m.tar"), "episodes": 10},
    }
    domain = make_domain(cfg)
    regions = np.zeros((2, 6, 6), np.int32)
    regions[0, 1:, 2] = ma.WALL
    regions[1, 2, :] = ma.WALL  # cut in two: the longest path stays within one half
    key = jax.random.PRNGKey(3)
    batch = domain.make_evaluator()(regions, key)
    layouts = np.pad(regions, ((0, 0), (1, 1), (1, 1)), constant_values=ma.WALL)
    _, start, goal = longest_shortest_path(jnp.asarray(regions == ma.EMPTY))
    for i in range(2):
        want, _ = play_lockstep(p, layouts[i], start[i] + 1, goal[i] + 1, maze_key(key, i), 10, 128)
        np.testing.assert_array_equal(np.asarray(batch.extras["episode_lengths"][i]), np.asarray(want))
    lengths = np.asarray(batch.extras["episode_lengths"])
    np.testing.assert_allclose(np.asarray(batch.measures[:, 1]), lengths.mean(1))
    for agent, match in (
        ({"kind": "paper_accel"}, "needs the paper's checkpoint"),
        ({"kind": "paper_accel_search", "weights": str(tmp_path / "none.tar")}, "not a PyTorch zip"),
    ):
        with pytest.raises(NcaQdError, match=match):
            make_domain({**cfg, "agent": agent})


def test_a_checkpoint_that_is_not_the_papers_says_so(tmp_path, monkeypatch, caplog):
    """Another file with the paper's network loads (another seed's agent is a fair thing to
    try), but the log names it as not the paper's model_20000.tar, by its own SHA-256; the
    paper's own file is recognised by its digest (checked here against an independent hash)."""
    import hashlib

    from nca_qd.agent import paper_accel

    compass_checkpoint(tmp_path / "m.tar", monkeypatch)
    digest = hashlib.sha256((tmp_path / "m.tar").read_bytes()).hexdigest()
    with caplog.at_level("WARNING", logger="nca_qd.agent.paper_accel"):
        paper_accel.load_params(str(tmp_path / "m.tar"))
    assert f"is not the paper's accel_seed_1/model_20000.tar (SHA-256 {digest})" in caplog.text
    caplog.clear()
    monkeypatch.setattr(paper_accel, "PAPER_CHECKPOINT_SHA256", digest)
    paper_accel.load_params.cache_clear()
    with caplog.at_level("WARNING", logger="nca_qd.agent.paper_accel"):
        paper_accel.load_params(str(tmp_path / "m.tar"))
    assert "is not the paper's" not in caplog.text
