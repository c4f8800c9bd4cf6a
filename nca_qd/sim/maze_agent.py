"""Single-agent maze simulation with minigrid dynamics, fully in JAX (jit + vmap, fixed shapes).

Layouts are ``int`` arrays ``[H, W]`` in the maze alphabet ``" X"``: 0 = empty, 1 = wall. The
agent lives in the *bordered* layout (the generated interior plus its ring of walls); anything
outside the array counts as wall.

Dynamics (as minigrid's, so that path lengths of rule-based and learned agents are comparable):

* State: position ``pos = (row, col)`` and direction ``dir`` in ``0..3``.
* Direction convention (minigrid's): ``0`` = east (col + 1), ``1`` = south (row + 1),
  ``2`` = west (col - 1), ``3`` = north (row - 1); rows grow downwards, so ``dir + 1`` is a
  clockwise (right) turn on screen. :data:`DIR_VEC` holds the ``(drow, dcol)`` of each.
* Actions: :data:`LEFT` = 0 (``dir - 1``), :data:`RIGHT` = 1 (``dir + 1``), :data:`FORWARD` = 2
  (one tile along ``dir``; a blocked forward is a no-op), :data:`STAY` = 3. Every action, turns
  included, takes one timestep.
* An episode starts at the start tile with a direction drawn uniformly at random by the
  environment (seeded per episode) and ends as soon as the agent stands on the goal; its length
  is the number of actions taken. An episode that has not reached the goal after ``horizon``
  actions counts ``horizon``.

Policies are pluggable: a :class:`Policy` is three pure functions,

* ``prepare(layout, goal) -> aux``: per-maze precomputation, run once per maze (the
  shortest-path agent's BFS distance field; ``None`` for most policies),
* ``init(key) -> memory``: per-episode memory (a pytree of fixed shapes),
* ``act(env, state, memory, key) -> (action, memory)``: one decision. ``env`` is a
  :class:`MazeEnv`; a learned policy would look only at :func:`observe` (the minigrid-style
  partial view) and its memory, rule-based ones may read the layout directly. ``key`` is a fresh
  per-step key (unused keys cost nothing once jitted).

The registry :data:`POLICIES` names every kind a config may choose (``domain.agent.kind``):
two rule-based policies, ``shortest_path`` and ``wall_follower`` (documented at their
constructors), ``learned``, the trained agent of :mod:`nca_qd.agent`, and ``paper_accel`` /
``paper_accel_search``, the paper's agent from its checkpoint (:mod:`nca_qd.agent.paper_accel`),
named by module path and imported only when chosen (so this module depends on no agent package;
the agent package depends on this one). :func:`register_policy` adds more at run time.
:func:`rollout` runs ``E`` episodes of one maze (vmapped over episodes, one
``lax.while_loop`` over time that stops when every episode is done); :func:`rollout_batch` runs
many mazes at once, in stages that shed the finished episodes.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from nca_qd.errors import NcaQdError

EMPTY, WALL = 0, 1
LEFT, RIGHT, FORWARD, STAY = 0, 1, 2, 3
EAST, SOUTH, WEST, NORTH = 0, 1, 2, 3
# (drow, dcol) of each direction: east, south, west, north.
DIR_VEC = jnp.array([[0, 1], [1, 0], [0, -1], [-1, 0]], dtype=jnp.int32)
N_ACTIONS = 4
VIEW_SIZE = 5
# Value of a tile in the distance field that the goal cannot reach.
UNREACHED = jnp.iinfo(jnp.int32).max // 2


class AgentState(NamedTuple):
    """Agent position ``[2]`` (row, col in the bordered layout) and direction ``[]`` (int32)."""

    pos: jax.Array
    dir: jax.Array


class MazeEnv(NamedTuple):
    """What a policy may look at in one maze.

    layout: ``[H, W]`` int (0 empty, 1 wall), bordered.
    free_dirs: ``[H, W]`` int32, bit ``d`` set when the neighbour in direction ``d`` is empty
        (a precomputed 4-neighbour mask: one gather per step answers every "is it free?").
    goal: ``[2]`` int32.
    aux: the policy's per-maze precomputation (``Policy.prepare``).
    """

    layout: jax.Array
    free_dirs: jax.Array
    goal: jax.Array
    aux: Any


class Policy(NamedTuple):
    """A maze policy: ``prepare`` per maze, ``init`` per episode, ``act`` per step (see module doc).

    ``deterministic``: ``act`` ignores its key, so (state, memory) fully determines the future;
    :func:`rollout_batch` then stops an episode as soon as it revisits a (state, memory) it was
    in before (a cycle that never reaches the goal: it would count the horizon anyway).

    ``rollout``: for a policy whose episodes are not independent (the paper's agent as its
    search played it: environments in lock step that share an input), its own
    ``(layouts, starts, goals, keys, episodes, horizon, active) -> Rollout`` replaces
    :func:`rollout_batch`'s loop; ``act`` then only serves single recorded episodes.
    """

    prepare: Callable[[jax.Array, jax.Array], Any]
    init: Callable[[jax.Array], Any]
    act: Callable[[MazeEnv, AgentState, Any, jax.Array], tuple[jax.Array, Any]]
    deterministic: bool = False
    rollout: Callable[..., Any] | None = None


# --------------------------------------------------------------------------- dynamics


def free_dirs_mask(layout: jax.Array) -> jax.Array:
    """``[H, W]`` int32: bit ``d`` set when the 4-neighbour in direction ``d`` is empty."""
    free = jnp.pad(layout == EMPTY, 1, constant_values=False)
    h, w = layout.shape
    mask = jnp.zeros((h, w), jnp.int32)
    for d, (dr, dc) in enumerate(((0, 1), (1, 0), (0, -1), (-1, 0))):
        nb = free[1 + dr : 1 + dr + h, 1 + dc : 1 + dc + w]
        mask = mask | (nb.astype(jnp.int32) << d)
    return mask


def make_env(layout: jax.Array, goal: jax.Array, aux: Any = None) -> MazeEnv:
    layout = jnp.asarray(layout, jnp.int32)
    return MazeEnv(layout, free_dirs_mask(layout), jnp.asarray(goal, jnp.int32), aux)


def dir_free(env: MazeEnv, state: AgentState, d: jax.Array) -> jax.Array:
    """Whether the neighbour of the agent's tile in (absolute) direction ``d`` is empty."""
    mask = env.free_dirs[state.pos[0], state.pos[1]]
    return ((mask >> (d % 4)) & 1).astype(bool)


def step(env: MazeEnv, state: AgentState, action: jax.Array) -> AgentState:
    """One minigrid transition. A forward move into a wall (or off the grid) is a no-op."""
    d = state.dir
    new_dir = jnp.where(action == LEFT, (d + 3) % 4, jnp.where(action == RIGHT, (d + 1) % 4, d))
    move = (action == FORWARD) & dir_free(env, state, d)
    new_pos = jnp.where(move, state.pos + DIR_VEC[d], state.pos)
    return AgentState(new_pos.astype(jnp.int32), new_dir.astype(jnp.int32))


def observe(env: MazeEnv, state: AgentState, view: int = VIEW_SIZE) -> jax.Array:
    """Minigrid-style egocentric partial view ``[view, view]`` int: 0 empty, 1 wall, 2 goal.

    The agent stands at the bottom row, middle column, facing up (row 0 is ``view - 1`` tiles
    ahead; column 0 is to its left). Tiles off the grid read as wall. No occlusion (minigrid's
    ``see_through_walls=True``). Meant for the learned agent; the rule-based ones do not use it.
    """
    f = (view - 1) - jnp.arange(view)[:, None]  # tiles ahead
    s = jnp.arange(view)[None, :] - view // 2  # tiles to the right
    fwd, right = DIR_VEC[state.dir], DIR_VEC[(state.dir + 1) % 4]
    r = state.pos[0] + f * fwd[0] + s * right[0]
    c = state.pos[1] + f * fwd[1] + s * right[1]
    h, w = env.layout.shape
    inside = (r >= 0) & (r < h) & (c >= 0) & (c < w)
    tiles = jnp.where(inside, env.layout[jnp.clip(r, 0, h - 1), jnp.clip(c, 0, w - 1)], WALL)
    return jnp.where((r == env.goal[0]) & (c == env.goal[1]), 2, tiles).astype(jnp.int32)


# --------------------------------------------------------------------------- policies


def distance_field(layout: jax.Array, goal: jax.Array) -> jax.Array:
    """BFS distance (4-connected, through empty tiles) of every tile to ``goal`` ``[H, W]`` int32.

    Walls and tiles the goal cannot reach hold :data:`UNREACHED`. A ``lax.while_loop`` of
    min-plus relaxations that stops when nothing changes (longest distance + 1 iterations).
    """
    layout = jnp.asarray(layout)
    h, w = layout.shape
    free = layout == EMPTY
    rows, cols = jnp.arange(h)[:, None], jnp.arange(w)[None, :]
    dist0 = jnp.where(free & (rows == goal[0]) & (cols == goal[1]), 0, UNREACHED).astype(jnp.int32)

    def relax(dist):
        p = jnp.pad(dist, 1, constant_values=UNREACHED)
        nb = jnp.minimum(jnp.minimum(p[:-2, 1:-1], p[2:, 1:-1]), jnp.minimum(p[1:-1, :-2], p[1:-1, 2:]))
        return jnp.where(free, jnp.minimum(dist, nb + 1), UNREACHED)

    def body(carry):
        dist, _ = carry
        new = relax(dist)
        return new, jnp.any(new != dist)

    dist, _ = jax.lax.while_loop(lambda c: c[1], body, (dist0, jnp.array(True)))
    return dist


def shortest_path_policy() -> Policy:
    """Turns toward and moves along a shortest path to the goal.

    Per maze it computes the BFS distance field from the goal (:func:`distance_field`). Each
    step it picks a neighbour one closer to the goal, preferring (to save turns) the one ahead,
    then right, then left, then behind; if that is ahead it moves forward, otherwise it turns
    toward it (right for the one behind). The episode length is the BFS distance plus the turns,
    so it is at least the BFS distance. Deterministic; the key and memory are unused.
    """

    def prepare(layout, goal):
        return distance_field(layout, goal)

    def init(key):
        return jnp.zeros((), jnp.int32)

    def act(env, state, memory, key):
        dist = env.aux
        here = dist[state.pos[0], state.pos[1]]
        # Candidate directions in order of preference: ahead, right, left, behind.
        order = (state.dir + jnp.array([0, 1, 3, 2], jnp.int32)) % 4
        nb = state.pos[None, :] + DIR_VEC[order]
        h, w = dist.shape
        nb_dist = dist[jnp.clip(nb[:, 0], 0, h - 1), jnp.clip(nb[:, 1], 0, w - 1)]
        good = (nb_dist == here - 1) & (here < UNREACHED) & (here > 0)
        choice = jnp.argmax(good)  # first good candidate (0 if none)
        action = jnp.array([FORWARD, RIGHT, LEFT, RIGHT], jnp.int32)[choice]
        action = jnp.where(jnp.any(good), action, STAY)
        return action, memory

    return Policy(prepare, init, act, deterministic=True)


class WallFollowerMemory(NamedTuple):
    right_hand: jax.Array  # bool: right-hand rule (else left-hand)
    following: jax.Array  # bool: has hit a wall and is following it
    just_turned: jax.Array  # bool: turned toward its hand last step, must now step forward


def wall_follower_policy() -> Policy:
    """Walks straight until a wall is in front, then follows that wall with a hand rule.

    Per episode it draws (from the episode key) a right- or left-hand rule with probability 1/2.
    Phase 1, walking: forward while the tile ahead is empty. At the first wall ahead it turns
    away from its hand (left for the right-hand rule) so that the wall is on its hand side, and
    starts following. Phase 2, following, each step:

    1. if it turned toward its hand on the previous step, it moves forward (into the tile it
       found empty; without this rule it would spin on the spot in open space);
    2. else if the tile on its hand side is empty, it turns toward its hand;
    3. else if the tile ahead is empty, it moves forward;
    4. else it turns away from its hand.

    With every action taking one timestep, this is the classic hand-on-the-wall rule. It reaches
    the goal in simply-connected mazes, but it can circle forever around a wall island or the
    outer wall of a room that does not touch the goal; then the episode counts the full horizon.
    """

    def prepare(layout, goal):
        return None

    def init(key):
        right_hand = (jax.random.bits(key, (), jnp.uint32) & 1) == 1
        return WallFollowerMemory(right_hand, jnp.array(False), jnp.array(False))

    def act(env, state, memory, key):
        right_hand = memory.right_hand
        d = state.dir
        mask = env.free_dirs[state.pos[0], state.pos[1]]
        front_free = ((mask >> d) & 1) == 1
        hand_dir = jnp.where(right_hand, (d + 1) % 4, (d + 3) % 4)
        hand_free = ((mask >> hand_dir) & 1) == 1
        toward = jnp.where(right_hand, RIGHT, LEFT)
        away = jnp.where(right_hand, LEFT, RIGHT)

        # Phase 1 (walking straight).
        walk_action = jnp.where(front_free, FORWARD, away)
        # Phase 2 (following).
        follow_action = jnp.where(
            memory.just_turned,
            FORWARD,
            jnp.where(hand_free, toward, jnp.where(front_free, FORWARD, away)),
        )
        following = memory.following
        action = jnp.where(following, follow_action, walk_action).astype(jnp.int32)
        new_memory = WallFollowerMemory(
            right_hand=right_hand,
            following=following | ~front_free,
            just_turned=following & ~memory.just_turned & hand_free,
        )
        return action, new_memory

    return Policy(prepare, init, act, deterministic=True)


# kind -> policy factory, or "module:function" of one, imported when the kind is first used
POLICIES: dict[str, Callable[[], Policy] | str] = {
    "shortest_path": shortest_path_policy,
    "wall_follower": wall_follower_policy,
    "learned": "nca_qd.agent.shipped:shipped_policy",
    # the paper's agent from its public checkpoint (weights=<its model_20000.tar>; not shipped)
    "paper_accel": "nca_qd.agent.paper_accel:transfer_policy",
    "paper_accel_search": "nca_qd.agent.paper_accel:search_policy",
}


def register_policy(kind: str, factory: Callable[[], Policy] | str) -> None:
    """Make ``factory()`` available as ``domain.agent.kind=<kind>`` (``factory`` may be a
    ``"module:function"`` string, imported on first use)."""
    POLICIES[kind] = factory


# kinds whose factory takes ``weights`` (learned: a directory of trained parameters, None: the
# shipped ones; paper_accel*: the paper's checkpoint file, required)
WEIGHTED_KINDS = {"learned", "paper_accel", "paper_accel_search"}


def get_policy(kind: str, weights: str | None = None) -> Policy:
    """The policy of agent ``kind``; ``weights`` picks the parameters of a learned kind."""
    if kind not in POLICIES:
        raise NcaQdError(f"unknown maze agent kind {kind!r} (known: {', '.join(sorted(POLICIES))})")
    if weights is not None and kind not in WEIGHTED_KINDS:
        raise NcaQdError(
            f"agent weights apply to the kinds {', '.join(sorted(WEIGHTED_KINDS))} only, not to {kind!r}"
        )
    factory = POLICIES[kind]
    if isinstance(factory, str):
        import importlib

        module, name = factory.split(":")
        factory = getattr(importlib.import_module(module), name)
    return factory() if weights is None else factory(weights=weights)


# --------------------------------------------------------------------------- rollouts


class Rollout(NamedTuple):
    lengths: jax.Array  # [E] int32 actions until the goal, horizon where missed
    reached: jax.Array  # [E] bool
    # [H, W] (or [B, H, W]) float32: visits per tile summed over episodes (start and every
    # position until the goal or the horizon), only with ``count_visits``
    visits: jax.Array | None = None


def _episode_init(policy: Policy, key: jax.Array, start: jax.Array):
    k_dir, k_mem, k_steps = jax.random.split(key, 3)
    # Uniform over the 4 directions (2**32 is a multiple of 4); jax.random.bits compiles much
    # faster than randint.
    direction = (jax.random.bits(k_dir, (), jnp.uint32) & 3).astype(jnp.int32)
    state = AgentState(jnp.asarray(start, jnp.int32), direction)
    return state, policy.init(k_mem), k_steps


def _episode_step(policy: Policy, env: MazeEnv, state, memory, k_steps, t):
    action, memory = policy.act(env, state, memory, jax.random.fold_in(k_steps, t))
    state = step(env, state, action)
    return state, memory


def rollout(
    policy: Policy,
    layout: jax.Array,
    start: jax.Array,
    goal: jax.Array,
    key: jax.Array,
    episodes: int,
    horizon: int,
    active: jax.Array | bool = True,
    detect_cycles: bool = True,
) -> Rollout:
    """Run ``episodes`` episodes of one maze (jit-able). See :func:`rollout_batch` for many mazes.

    Episode ``i`` uses ``jax.random.split(key, episodes)[i]``. With ``active`` False nothing is
    simulated and every episode counts the horizon (mazes without a start-goal path).
    """
    res = rollout_batch(
        policy,
        layout[None],
        jnp.asarray(start)[None],
        jnp.asarray(goal)[None],
        key[None],
        episodes,
        horizon,
        jnp.asarray(active)[None],
        detect_cycles,
    )
    return Rollout(res.lengths[0], res.reached[0])


def rollout_batch(
    policy: Policy,
    layouts: jax.Array,
    starts: jax.Array,
    goals: jax.Array,
    keys: jax.Array,
    episodes: int,
    horizon: int,
    active: jax.Array | None = None,
    detect_cycles: bool = True,
    count_visits: bool = False,
) -> Rollout:
    """:func:`rollout` of ``B`` mazes at once: ``layouts [B, H, W]``, ``starts``/``goals`` ``[B, 2]``,
    ``keys [B]``, ``active [B]`` -> lengths and reached ``[B, episodes]``.

    The ``B x episodes`` agents step together (one row each, vmapped), each with its own maze,
    key and the shared clock, until every episode is done or the horizon. A step costs every row
    whether its agent still walks or not, and a search's batch has a long tail (most episodes end
    early, a few run to the horizon), so the rows are staged: whenever the agents still walking
    fit in half the rows, they are gathered there and the loop goes on at half the size (see
    :data:`STAGE_FLOOR`). An agent's steps do not depend on the rows beside it, so the results
    are those of one loop over the whole batch, bit for bit (tests/test_maze.py), in about half
    the time on a search's batch (docs/benchmarks.md).

    With a ``deterministic`` policy and ``detect_cycles``, Brent-style cycle detection (the
    (state, memory) of every episode is saved at t = 1, 2, 4, 8, ...; meeting it again means a
    cycle without the goal) ends hopeless episodes early. The result is exactly the same, only
    the loop stops sooner (a wall follower circling an island no longer costs the full horizon).

    ``count_visits`` also returns ``visits [B, H, W]``: how often the agents of all episodes
    stood on each tile before an action (the start included, the goal reached not; an inactive
    maze has none). DSAGE's surrogate learns it as its ancillary target (agent occupancy). Cycle
    detection must be off for it: a cut-short episode would count fewer visits than it makes.
    """
    b = layouts.shape[0]
    active = jnp.ones((b,), bool) if active is None else jnp.asarray(active, bool)
    if policy.rollout is not None:
        if count_visits:
            raise NcaQdError("this maze agent plays coupled episodes: it cannot count visits (DSAGE)")
        return policy.rollout(layouts, starts, goals, keys, episodes, horizon, active)
    envs = jax.vmap(make_env)(layouts, goals)
    envs = envs._replace(aux=jax.vmap(policy.prepare)(envs.layout, envs.goal))
    n = b * episodes
    maze = jnp.repeat(jnp.arange(b, dtype=jnp.int32), episodes)  # agent i plays maze i // E
    ep_keys = jax.vmap(lambda k: jax.random.split(k, episodes))(keys).reshape((n,) + keys.shape[1:])
    state, memory, k_steps = jax.vmap(lambda k, s: _episode_init(policy, k, s))(ep_keys, starts[maze])
    at_goal = jnp.all(state.pos == envs.goal[maze], axis=-1) & active[maze]
    detect = bool(detect_cycles and policy.deterministic and not count_visits)
    agents = _Agents(
        jnp.arange(n, dtype=jnp.int32),
        jax.tree.map(lambda a: a[maze], envs),
        state,
        memory,
        k_steps,
        at_goal | ~active[maze],
        at_goal,
        jnp.where(at_goal, 0, horizon).astype(jnp.int32),
        (state, memory) if detect else None,
    )
    h, w = layouts.shape[1:]
    visits = jnp.zeros((b, h, w), jnp.float32) if count_visits else None
    lengths, hit = jnp.full((n,), horizon, jnp.int32), jnp.zeros((n,), bool)
    t = jnp.array(0, jnp.int32)
    sizes = _stage_sizes(n)
    for k, size in enumerate(sizes):
        if size < agents.index.shape[0]:  # the live agents first (stable), then keep ``size``
            order = jnp.argsort(agents.done, stable=True)[:size]
            agents = jax.tree.map(lambda a, o=order: a[o], agents)
        below = sizes[k + 1] if k + 1 < len(sizes) else 0
        t, agents, visits = _run_stage(policy, agents, visits, t, horizon, below, detect, episodes)
        lengths = lengths.at[agents.index].set(agents.lengths)
        hit = hit.at[agents.index].set(agents.hit)
    return Rollout(lengths.reshape(b, episodes), hit.reshape(b, episodes), visits)


class _Agents(NamedTuple):
    """The agents a rollout stage steps, one row each (a stage keeps a prefix of the rows)."""

    index: jax.Array  # [n] int32: agent i = maze i // E, episode i % E
    env: MazeEnv  # [n, ...]: its maze
    state: AgentState
    memory: Any
    k_steps: jax.Array
    done: jax.Array  # [n] bool: at the goal, out of time, in a cycle, or an inactive maze
    hit: jax.Array  # [n] bool: reached the goal
    lengths: jax.Array  # [n] int32
    saved: Any  # (state, memory) saved for cycle detection, or None


# Stages of a rollout: the agents still walking are gathered into half as many rows whenever
# they fit, down to a sixteenth of the batch (at least 64 rows): each stage is one more loop
# to compile, and the last few slow episodes no longer cost a step of the whole batch.
STAGE_FLOOR, STAGE_MIN = 16, 64


def _stage_sizes(n: int) -> list[int]:
    sizes = [n]
    while -(-sizes[-1] // 2) >= max(STAGE_MIN, -(-n // STAGE_FLOOR)):
        sizes.append(-(-sizes[-1] // 2))
    return sizes


def _run_stage(policy, agents: _Agents, visits, t, horizon: int, below: int, detect: bool, episodes: int):
    """Step ``agents`` until the horizon, until all are done, or until at most ``below`` walk.

    Per agent the same steps as one episode alone: its key, its maze, its clock ``t``."""
    step_all = jax.vmap(partial(_episode_step, policy), in_axes=(0, 0, 0, 0, None))

    def cond(c):
        t, a, _ = c
        return (t < horizon) & (jnp.sum(~a.done) > below)

    def body(c):
        t, a, visits = c
        if visits is not None:  # where each live agent stands before it acts (as DSAGE counts)
            live = (~a.done).astype(jnp.float32)
            visits = visits.at[a.index // episodes, a.state.pos[:, 0], a.state.pos[:, 1]].add(live)
        state, memory = step_all(a.env, a.state, a.memory, a.k_steps, t)
        reached = jnp.all(state.pos == a.env.goal, axis=-1) & ~a.done
        lengths = jnp.where(reached, t + 1, a.lengths)
        done, hit = a.done | reached, a.hit | reached
        saved = a.saved
        if detect:
            same = [
                jnp.all((x == y).reshape(x.shape[:1] + (-1,)), axis=-1)
                for x, y in zip(jax.tree.leaves((state, memory)), jax.tree.leaves(saved))
            ]
            done = done | jnp.all(jnp.stack(same), axis=0)  # a cycle: never reaches the goal
            t1 = t + 1
            checkpoint = (t1 & (t1 - 1)) == 0  # t + 1 is a power of two
            saved = jax.tree.map(lambda new, old: jnp.where(checkpoint, new, old), (state, memory), saved)
        a = a._replace(state=state, memory=memory, done=done, hit=hit, lengths=lengths, saved=saved)
        return t + 1, a, visits

    return jax.lax.while_loop(cond, body, (t, agents, visits))


def record_episode(
    policy: Policy,
    layout: jax.Array,
    start: jax.Array,
    goal: jax.Array,
    key: jax.Array,
    episodes: int,
    horizon: int,
):
    """Positions ``[horizon + 1, 2]`` and directions ``[horizon + 1]`` of episode 0 of
    :func:`rollout` (same key derivation); after the goal the agent stays on it. Also returns
    the episode length."""
    env = make_env(layout, goal)
    env = env._replace(aux=policy.prepare(env.layout, env.goal))
    state, memory, k_steps = _episode_init(policy, jax.random.split(key, episodes)[0], start)
    at_goal = jnp.all(state.pos == env.goal)

    def body(c, t):
        state, memory, done, length = c
        new_state, new_memory = _episode_step(policy, env, state, memory, k_steps, t)
        state = jax.tree.map(lambda a, b: jnp.where(done, a, b), state, new_state)
        memory = jax.tree.map(lambda a, b: jnp.where(done, a, b), memory, new_memory)
        reached = jnp.all(state.pos == env.goal) & ~done
        length = jnp.where(reached, t + 1, length)
        return (state, memory, done | reached, length), (state.pos, state.dir)

    init = (state, memory, at_goal, jnp.where(at_goal, 0, horizon).astype(jnp.int32))
    (_, _, _, length), (pos, dirs) = jax.lax.scan(body, init, jnp.arange(horizon, dtype=jnp.int32))
    pos = jnp.concatenate([state.pos[None], pos], 0)
    dirs = jnp.concatenate([state.dir[None], dirs], 0)
    return pos, dirs, length
