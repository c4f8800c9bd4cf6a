"""PPO with a recurrent (LSTM) policy over vmapped maze environments, levels from ACCEL.

PureJaxRL style: the whole training state is one pytree (:class:`TrainState`) and one update is
one jitted call (:meth:`Trainer.update`) that

1. chooses a level for each of the ``n_envs`` environments (:func:`nca_qd.agent.levels.choose_levels`),
2. runs every environment for ``horizon`` steps in a ``lax.scan`` (vmapped over environments)
   with the minigrid dynamics of :mod:`nca_qd.sim.maze_agent` (``observe`` / ``step``); an
   episode ends on the goal (reward ``1 - 0.9 * t / horizon``, minigrid's) or after ``horizon``
   steps (reward 0, terminal), and the environment then restarts the same level at its start with
   a new random direction and a zero LSTM carry (auto-reset). Every rollout starts a fresh episode
   on a freshly chosen level, so each environment plays exactly one level per update and the
   first episode's time limit is the rollout's end; later episodes cut by the rollout's end are
   bootstrapped with the critic's value,
3. computes GAE advantages, then ``epochs`` x ``minibatches`` (minibatches split the
   environments; each replays its whole sequences through the LSTM, resetting the carry at
   episode starts) steps of Adam on the clipped PPO objective + value loss (clipped as in PPO2)
   - entropy bonus, global-norm clipped gradients,
4. scores each level by its positive value loss (mean of ``max(advantage, 0)`` over its first
   episode, :func:`level_scores`) and updates the level replay buffer.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax

from nca_qd.agent.levels import LevelBuffer, Levels, buffer_init, buffer_update, choose_levels
from nca_qd.agent.network import AgentNet, init_params, learned_policy, zero_carry
from nca_qd.sim import maze_agent as ma


class TrainState(NamedTuple):
    params: Any
    opt_state: Any
    buffer: LevelBuffer
    key: jax.Array
    update: jax.Array  # int32: updates done


class Transition(NamedTuple):
    view: jax.Array  # [T, E, 5, 5]
    dir: jax.Array  # [T, E]
    action: jax.Array
    logp: jax.Array
    value: jax.Array
    reward: jax.Array
    done: jax.Array
    reached: jax.Array


def _reset_carry(carry, reset):
    return jax.tree.map(lambda c: jnp.where(reset[:, None], 0.0, c), carry)


def gae(reward, value, done, last_value, gamma: float, lam: float):
    """Generalised advantage estimates and value targets, ``[T, E]`` each."""

    def body(carry, x):
        adv, next_value = carry
        r, v, d = x
        nd = 1.0 - d.astype(jnp.float32)
        delta = r + gamma * next_value * nd - v
        adv = delta + gamma * lam * nd * adv
        return (adv, v), adv

    _, adv = jax.lax.scan(body, (jnp.zeros_like(last_value), last_value), (reward, value, done), reverse=True)
    return adv, adv + value


def level_scores(adv: jax.Array, done: jax.Array) -> jax.Array:
    """Positive value loss of each environment's level ``[E]``: the mean of ``max(adv, 0)`` over
    the level's first episode of the rollout (ACCEL scores a level per episode; averaging over the
    whole rollout instead would favour easy levels, replayed many times, with one reward each)."""
    before = jnp.cumsum(done, axis=0) - done  # episodes finished before step t
    first = (before == 0).astype(jnp.float32)
    return jnp.sum(jnp.maximum(adv, 0.0) * first, axis=0) / jnp.maximum(first.sum(0), 1.0)


class Trainer:
    """Builds the jitted update from a config (see ``experiments/conf/train_agent.yaml``).

    ``cfg`` needs ``n_envs``, ``horizon``, ``interior`` ([h, w]), ``ppo`` (gamma, gae_lambda,
    clip, vf_coef, ent_coef, lr, max_grad_norm, epochs, minibatches) and ``levels`` (see
    :func:`~nca_qd.agent.levels.choose_levels`: method, buffer_size, ...).
    """

    def __init__(self, net: AgentNet, cfg, compiler_options: dict | None = None):
        self.net, self.cfg = net, cfg
        self.n_envs, self.horizon = int(cfg.n_envs), int(cfg.horizon)
        self.interior = tuple(int(v) for v in cfg.interior)
        p = cfg.ppo
        if self.n_envs % int(p.minibatches):
            from nca_qd.errors import NcaQdError

            raise NcaQdError(f"n_envs={self.n_envs} is not divisible by ppo.minibatches={int(p.minibatches)}")
        self.tx = optax.chain(
            optax.clip_by_global_norm(float(p.max_grad_norm)), optax.adam(float(p.lr), eps=1e-5)
        )
        # compiler_options: XLA options of the update (tests use a low optimisation level to
        # compile faster).
        self.update = jax.jit(self._update, compiler_options=compiler_options)
        self._init = jax.jit(self._init_state, compiler_options=compiler_options)

    @property
    def steps_per_update(self) -> int:
        return self.n_envs * self.horizon

    def init(self, key: jax.Array) -> TrainState:
        """Fresh parameters, optimiser state and an empty level buffer (one jitted call)."""
        return self._init(key)

    def _init_state(self, key: jax.Array) -> TrainState:
        k_net, k = jax.random.split(key)
        params = init_params(self.net, k_net)
        h, w = self.interior
        buf = buffer_init(int(self.cfg.levels.buffer_size), (h + 2, w + 2))
        return TrainState(params, self.tx.init(params), buf, k, jnp.array(0, jnp.int32))

    # --- rollout ---------------------------------------------------------------------------
    def rollout(self, params, levels: Levels, key: jax.Array):
        """``horizon`` steps of every environment on its level; returns transitions and the
        critic's value after the last step ``[E]``."""
        net, horizon, n = self.net, self.horizon, self.n_envs
        envs = jax.vmap(ma.make_env)(levels.layout, levels.goal)
        k0, k_scan = jax.random.split(key)
        dir0 = (jax.random.bits(k0, (n,), jnp.uint32) & 3).astype(jnp.int32)
        agent = ma.AgentState(levels.start, dir0)
        observe = jax.vmap(ma.observe)
        step = jax.vmap(ma.step)

        def body(c, k):
            agent, t, carry = c
            view = observe(envs, agent)
            carry, logits, value = net.apply(params, carry, view, agent.dir)
            k_a, k_d = jax.random.split(k)
            action = jax.random.categorical(k_a, logits).astype(jnp.int32)
            logp = jnp.take_along_axis(jax.nn.log_softmax(logits), action[:, None], 1)[:, 0]
            nxt = step(envs, agent, action)
            t1 = t + 1
            reached = jnp.all(nxt.pos == levels.goal, axis=-1)
            done = reached | (t1 >= horizon)
            reward = jnp.where(reached, 1.0 - 0.9 * t1 / horizon, 0.0).astype(jnp.float32)
            new_dir = (jax.random.bits(k_d, (n,), jnp.uint32) & 3).astype(jnp.int32)
            agent_next = ma.AgentState(
                jnp.where(done[:, None], levels.start, nxt.pos), jnp.where(done, new_dir, nxt.dir)
            )
            out = Transition(view, agent.dir, action, logp, value, reward, done, reached)
            return (agent_next, jnp.where(done, 0, t1), _reset_carry(carry, done)), out

        init = (agent, jnp.zeros((n,), jnp.int32), zero_carry(net, (n,)))
        (agent, _, carry), traj = jax.lax.scan(body, init, jax.random.split(k_scan, horizon))
        _, _, last_value = net.apply(params, carry, observe(envs, agent), agent.dir)
        return traj, last_value

    # --- loss ------------------------------------------------------------------------------
    def loss(self, params, traj: Transition, adv, target):
        """PPO loss on whole sequences ``[T, B]`` (carry reset at episode starts)."""
        p, net = self.cfg.ppo, self.net
        b = traj.dir.shape[1]
        resets = jnp.concatenate([jnp.ones((1, b), bool), traj.done[:-1]], axis=0)

        def body(carry, x):
            view, d, reset = x
            carry, logits, value = net.apply(params, _reset_carry(carry, reset), view, d)
            return carry, (logits, value)

        _, (logits, value) = jax.lax.scan(body, zero_carry(net, (b,)), (traj.view, traj.dir, resets))
        logp_all = jax.nn.log_softmax(logits)
        logp = jnp.take_along_axis(logp_all, traj.action[..., None], -1)[..., 0]
        ratio = jnp.exp(logp - traj.logp)
        a = (adv - adv.mean()) / (adv.std() + 1e-8)
        clip = float(p.clip)
        pg = -jnp.mean(jnp.minimum(ratio * a, jnp.clip(ratio, 1 - clip, 1 + clip) * a))
        v_clip = traj.value + jnp.clip(value - traj.value, -clip, clip)
        vf = 0.5 * jnp.mean(jnp.maximum((value - target) ** 2, (v_clip - target) ** 2))
        ent = -jnp.mean(jnp.sum(jnp.exp(logp_all) * logp_all, axis=-1))
        total = pg + float(p.vf_coef) * vf - float(p.ent_coef) * ent
        return total, (pg, vf, ent)

    def _ppo(self, params, opt_state, traj, adv, target, key):
        p = self.cfg.ppo
        n_mb = int(p.minibatches)
        mb = self.n_envs // n_mb
        grad_fn = jax.value_and_grad(self.loss, has_aux=True)

        def epoch(c, k):
            params, opt_state = c
            perm = jax.random.permutation(k, self.n_envs).reshape(n_mb, mb)

            def minibatch(c, idx):
                params, opt_state = c
                take = lambda x: x[:, idx]  # noqa: E731
                (total, aux), grads = grad_fn(params, jax.tree.map(take, traj), take(adv), take(target))
                updates, opt_state = self.tx.update(grads, opt_state, params)
                return (optax.apply_updates(params, updates), opt_state), (total,) + aux

            return jax.lax.scan(minibatch, (params, opt_state), perm)

        (params, opt_state), stats = jax.lax.scan(
            epoch, (params, opt_state), jax.random.split(key, int(p.epochs))
        )
        return params, opt_state, jax.tree.map(jnp.mean, stats)

    # --- one update ------------------------------------------------------------------------
    def _update(self, state: TrainState) -> tuple[TrainState, dict[str, jax.Array]]:
        key, k_lvl, k_roll, k_ppo = jax.random.split(state.key, 4)
        levels, src, kind = choose_levels(
            k_lvl, state.buffer, state.update, self.n_envs, self.interior, self.cfg.levels
        )
        traj, last_value = self.rollout(state.params, levels, k_roll)
        p = self.cfg.ppo
        adv, target = gae(traj.reward, traj.value, traj.done, last_value, float(p.gamma), float(p.gae_lambda))
        params, opt_state, (total, pg, vf, ent) = self._ppo(
            state.params, state.opt_state, traj, adv, target, k_ppo
        )
        scores = level_scores(adv, traj.done)
        buffer = buffer_update(state.buffer, levels, src, scores, state.update)
        episodes = jnp.sum(traj.done)
        metrics = {
            "loss": total,
            "policy_loss": pg,
            "value_loss": vf,
            "entropy": ent,
            "episodes": episodes,
            "mean_return": jnp.sum(traj.reward) / jnp.maximum(episodes, 1),
            "train_success": jnp.sum(traj.reached) / jnp.maximum(episodes, 1),
            "replayed": jnp.mean(kind == 0),
            "edited": jnp.mean(kind == 1),
            "nca": jnp.mean(kind == 3),
            "buffer_size": jnp.sum(buffer.valid),
            "buffer_score": jnp.sum(jnp.where(buffer.valid, buffer.score, 0.0))
            / jnp.maximum(jnp.sum(buffer.valid), 1),
            "level_score": jnp.mean(scores),
        }
        return TrainState(params, opt_state, buffer, key, state.update + 1), metrics


def make_heldout_eval(net: AgentNet, levels: Levels, episodes: int, horizon: int):
    """Jitted ``(params, key) -> (reached [M, episodes], lengths [M, episodes])`` of the sampled
    policy on fixed levels, through :func:`nca_qd.sim.maze_agent.rollout_batch`."""

    @jax.jit
    def evaluate(params, key):
        policy = learned_policy(net, params)
        keys = jax.random.split(key, levels.layout.shape[0])
        res = ma.rollout_batch(policy, levels.layout, levels.start, levels.goal, keys, episodes, horizon)
        return res.reached, res.lengths

    return evaluate
