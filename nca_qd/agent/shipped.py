"""The shipped maze agent: weights in ``nca_qd/agent/weights/`` and the ``learned`` policy kind.

``maze_agent.msgpack`` holds the network parameters (Flax msgpack serialisation) and
``maze_agent.json`` how they were trained: the network block needed to rebuild
:class:`~nca_qd.agent.network.AgentNet`, the training configuration, environment steps, wall
time, held-out success and date. Both are package data, found with :mod:`importlib.resources`
(so an editable install and a wheel behave the same).
"""

from __future__ import annotations

import importlib.resources
import json
from functools import lru_cache
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from nca_qd.agent.network import AgentNet, init_params, learned_policy, make_net
from nca_qd.errors import NcaQdError
from nca_qd.sim import maze_agent as ma

WEIGHTS_FILE, META_FILE = "maze_agent.msgpack", "maze_agent.json"


def weights_dir() -> Path:
    """Directory of the shipped weights inside the installed package."""
    return Path(str(importlib.resources.files("nca_qd.agent") / "weights"))


def load_agent(directory: str | Path | None = None) -> tuple[AgentNet, Any, dict[str, Any]]:
    """``(net, params, meta)`` of the agent stored in ``directory`` (default: the shipped one)."""
    from flax import serialization

    d = Path(directory) if directory is not None else weights_dir()
    w, m = d / WEIGHTS_FILE, d / META_FILE
    if not w.is_file() or not m.is_file():
        raise NcaQdError(
            f"learned maze agent not found in {d} ({WEIGHTS_FILE} and {META_FILE}); "
            "train one with python -m experiments.train_agent ship=true"
        )
    meta = json.loads(m.read_text())
    net = make_net(meta["network"])
    # The expected structure from an abstract trace (no compilation, unlike a real init).
    template = jax.eval_shape(lambda: init_params(net, jax.random.PRNGKey(0)))
    try:
        raw = serialization.msgpack_restore(w.read_bytes())
        params = serialization.from_state_dict(template, raw)
        bad = [
            path
            for (path, t), p in zip(jax.tree_util.tree_leaves_with_path(template), jax.tree.leaves(params))
            if tuple(t.shape) != tuple(np.shape(p))
        ]
    except (ValueError, KeyError, TypeError) as exc:
        raise NcaQdError(f"{w}: weights do not match the network in {m} ({exc})") from None
    if bad:
        raise NcaQdError(
            f"{w}: weights do not match the network in {m} (shape of {jax.tree_util.keystr(bad[0])})"
        )
    params = jax.tree.map(lambda a, t: jnp.asarray(a, t.dtype), params, template)
    return net, params, meta


def save_agent(params: Any, meta: dict[str, Any], directory: str | Path | None = None) -> Path:
    """Write weights and metadata (atomically) to ``directory`` (default: the shipped place)."""
    from flax import serialization

    from nca_qd.io import atomic_write_bytes, atomic_write_text

    d = Path(directory) if directory is not None else weights_dir()
    atomic_write_bytes(d / WEIGHTS_FILE, serialization.to_bytes(jax.device_get(params)))
    atomic_write_text(d / META_FILE, json.dumps(meta, indent=2, sort_keys=True) + "\n")
    for name in (WEIGHTS_FILE, META_FILE):
        (d / name).chmod(0o644)  # package data: readable by everyone (mkstemp makes 0600)
    _loaded.cache_clear()
    return d


@lru_cache(maxsize=4)
def _loaded(directory: str | None) -> tuple[AgentNet, Any]:
    net, params, _ = load_agent(directory)
    return net, params


def shipped_policy(weights: str | Path | None = None) -> ma.Policy:
    """The ``learned`` kind: the shipped network (or the one stored in ``weights``, a directory
    holding ``maze_agent.msgpack`` and ``maze_agent.json`` as ``experiments.train_agent
    ship_dir=...`` writes them), sampled actions, LSTM carry as memory."""
    net, params = _loaded(None if weights is None else str(Path(weights)))
    return learned_policy(net, params)
