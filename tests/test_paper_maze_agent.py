"""benchmarks.paper_maze_agent: the checkpoint reader, the network step, the paper's episode protocol."""

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

from benchmarks.paper_maze_agent import (
    ENC_COLOR,
    ENC_TYPE,
    HIDDEN,
    agent_params,
    evaluate_maze,
    forward,
    main,
    read_state_dict,
)
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
    lengths, reached = evaluate_maze(p, layout, start, goal, key, n_episodes=100, horizon=30)
    lengths, reached = np.asarray(lengths), np.asarray(reached)
    assert set(lengths.tolist()) <= {5, 30}
    np.testing.assert_array_equal(reached, lengths == 5)
    assert 0.1 < reached.mean() < 0.45


def test_bad_checkpoint_is_one_line_and_exit_2(tmp_path, capsys):
    (tmp_path / "x.tar").write_text("not a zip")
    assert main(["--checkpoint", str(tmp_path / "x.tar")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a PyTorch zip checkpoint" in err[0]
