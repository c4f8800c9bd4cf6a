"""The learned maze agent's network and its :class:`~nca_qd.sim.maze_agent.Policy`.

Architecture (as the paper's ACCEL agent, Dennis et al. / Parker-Holder et al. minigrid model):

* the egocentric 5x5 view (:func:`nca_qd.sim.maze_agent.observe`: 0 empty, 1 wall, 2 goal) as a
  one-hot ``[5, 5, 3]`` image through one 3x3 convolution with 16 filters (VALID padding, ReLU)
  -> 3x3x16 = 144 features. The convolution is written as a patch matmul (the nine 3x3 patches
  gathered, one ``[27, 16]`` kernel): the same function as ``nn.Conv`` but a plain matmul under
  vmap on XLA's CPU backend;
* the direction one-hot (4) through a dense layer of 5 units (ReLU);
* an LSTM over the concatenation (``hidden`` units);
* an actor head (dense ``head_hidden``, tanh, dense 4 logits) and a critic head (dense
  ``head_hidden``, tanh, dense 1).

Hidden size: the paper's agent uses an LSTM of 256. Here the default is 64 (see
``experiments/conf/train_agent.yaml``): the project runs on a 2-core CPU, and the QD maze search
steps 150 mazes x 50 episodes = 7,500 agents for up to 648 steps per iteration through this
network. The LSTM's cost is ~4 x hidden x (inputs + hidden) multiply-adds per agent-step, 7x less
at 64 than at 256 (55 K vs. 415 K), and a 64-unit LSTM already holds the short memory that the
5x5-view maze task needs (the trained agent's held-out success is in ``maze_agent.json``).

The agent's policy samples its action from the logits with the per-step key; its per-episode
memory is the LSTM carry ``(c, h)``, zeros at the start of an episode.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

from nca_qd.sim import maze_agent as ma

N_VIEW_CLASSES = 3  # empty, wall, goal
Carry = tuple[jax.Array, jax.Array]


class AgentNet(nn.Module):
    """Recurrent actor-critic: ``(carry, view [..., 5, 5], dir [...]) -> (carry, logits [..., 4],
    value [...])``. Any leading batch shape (the carry's leading shape must match)."""

    hidden: int = 64
    conv_features: int = 16
    dir_features: int = 5
    head_hidden: int = 32

    @nn.compact
    def __call__(self, carry: Carry, view: jax.Array, direction: jax.Array):
        x = jax.nn.one_hot(view, N_VIEW_CLASSES)  # [..., 5, 5, 3]
        v = view.shape[-1]
        k = v - 2  # VALID 3x3 output size
        patches = jnp.stack(
            [
                x[..., i : i + 3, j : j + 3, :].reshape(x.shape[:-3] + (9 * N_VIEW_CLASSES,))
                for i in range(k)
                for j in range(k)
            ],
            axis=-2,
        )  # [..., 9, 27]
        x = nn.relu(nn.Dense(self.conv_features, name="conv")(patches))
        x = x.reshape(x.shape[:-2] + (k * k * self.conv_features,))
        d = nn.relu(nn.Dense(self.dir_features, name="dir")(jax.nn.one_hot(direction, 4)))
        z = jnp.concatenate([x, d], axis=-1)
        carry, h = nn.OptimizedLSTMCell(self.hidden, name="lstm")(carry, z)
        a = nn.Dense(ma.N_ACTIONS, name="actor_out")(
            nn.tanh(nn.Dense(self.head_hidden, name="actor_hidden")(h))
        )
        c = nn.Dense(1, name="critic_out")(nn.tanh(nn.Dense(self.head_hidden, name="critic_hidden")(h)))
        return carry, a, c[..., 0]


def make_net(net_cfg: Mapping[str, Any]) -> AgentNet:
    """The network described by a config block (``hidden``, ``conv_features``, ...)."""
    keys = ("hidden", "conv_features", "dir_features", "head_hidden")
    return AgentNet(**{k: int(net_cfg[k]) for k in keys if k in net_cfg})


def zero_carry(net: AgentNet, batch: tuple[int, ...] = ()) -> Carry:
    """An all-zero LSTM carry ``(c, h)`` of shape ``batch + (hidden,)``."""
    z = jnp.zeros(batch + (net.hidden,), jnp.float32)
    return z, z


def init_params(net: AgentNet, key: jax.Array) -> Any:
    """Fresh parameters (one unbatched call traces every layer)."""
    view = jnp.zeros((ma.VIEW_SIZE, ma.VIEW_SIZE), jnp.int32)
    return net.init(key, zero_carry(net), view, jnp.zeros((), jnp.int32))


def n_params(params: Any) -> int:
    return int(sum(x.size for x in jax.tree.leaves(params)))


def learned_policy(net: AgentNet, params: Any, greedy: bool = False) -> ma.Policy:
    """A :class:`~nca_qd.sim.maze_agent.Policy` that runs ``net`` with ``params``.

    ``params`` may be concrete (the shipped agent) or traced (evaluation inside a jitted training
    step). Actions are sampled from the logits (``greedy``: argmax, for diagnostics only).
    """

    def prepare(layout, goal):
        return None

    def init(key):
        return zero_carry(net)

    def act(env, state, memory, key):
        view = ma.observe(env, state)
        carry, logits, _ = net.apply(params, memory, view, state.dir)
        if greedy:
            action = jnp.argmax(logits)
        else:
            action = jax.random.categorical(key, logits)
        return action.astype(jnp.int32), carry

    return ma.Policy(prepare, init, act, deterministic=greedy)
