"""Maze domain (paper §4, appendices B.3, D), fully in JAX.

The NCA generates an ``h x w`` interior (16x16 at training size, 64x64 at evaluation size) over
the alphabet ``" X"`` (0 = empty, 1 = wall); :meth:`MazeDomain.assemble` surrounds it with walls
(18x18, 66x66). Scoring of one layout:

* start and goal: the two ends of the longest shortest path over all pairs of empty tiles
  (4-connected). Ties: the start is the end with the smallest row-major index among all longest
  pairs, the goal the smallest-index tile at that distance from it. Computed exactly by a
  bit-parallel BFS from every tile at once (:func:`longest_shortest_path`).
* objective: 1 if there is such a path of length >= 1 (at least two connected empty tiles),
  else 0 (then start = goal = the first empty tile, or (-1, -1) when there is none).
* measures, in the order of ``cfg["measures"]["names"]``: ``n_walls`` (walls of the interior,
  [0, h*w]), ``entropy`` (:func:`nca_qd.measures.entropy`, K=2, of the interior) and
  ``path_length``: the mean episode length of the agent over ``cfg["agent"]["episodes"]`` episodes
  (a miss counts the horizon = ``horizon_factor`` x tiles of the bordered layout; 648 at 18x18;
  an unsolvable maze is not simulated and counts the horizon). The agent
  (``cfg["agent"]["kind"]``, default ``learned``: :mod:`nca_qd.agent`) is one of
  :data:`nca_qd.sim.maze_agent.POLICIES`; ``cfg["agent"]["weights"]`` (a directory) gives a
  learned agent other parameters than the shipped ones (the measure depends on the agent).
"""

from __future__ import annotations

from collections.abc import Mapping
from functools import cache, partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from nca_qd.domains.base import Domain, EvalBatch, Evaluator, wants_ancillary
from nca_qd.errors import NcaQdError
from nca_qd.measures import batch_entropy, tile_count
from nca_qd.sim import maze_agent

EMPTY, WALL = maze_agent.EMPTY, maze_agent.WALL
MEASURES = ("n_walls", "entropy", "path_length")
# The learned agent (nca_qd/agent: the paper's ACCEL-trained LSTM policy, shipped weights) is
# the default; the rule-based kinds stay available through cfg["agent"]["kind"].
DEFAULT_AGENT = {"kind": "learned", "episodes": 50, "horizon_factor": 2, "weights": None}


# --------------------------------------------------------------------------- start and goal


def _lowest_bit(x: jax.Array) -> jax.Array:
    """Index of the lowest set bit of a uint32 (32 for 0)."""
    return jax.lax.population_count((x & (~x + jnp.uint32(1))) - jnp.uint32(1)).astype(jnp.int32)


def longest_shortest_path(free: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Exact longest shortest path of grid(s) ``free [..., H, W]`` (bool, True = empty; 4-connected).

    Returns ``(length [...], start [..., 2], goal [..., 2])`` (int32; row, col in ``free``'s
    coordinates). With no two connected empty tiles, length is 0 and start = goal = the first
    empty tile (row-major), or (-1, -1) with no empty tile. Tie-break: see the module docstring.

    Bit-parallel BFS from all sources at once: each tile holds a bitmask over sources (tile ``i``
    is bit ``i % 32`` of word ``i // 32``), initially its own bit if empty. Each step ORs in the
    4 neighbours' masks and ANDs with the free mask, until nothing changes; the last step that
    added bits is the longest shortest distance, and the bits it added are the longest pairs.
    Cost per step ~ H*W*ceil(H*W/32) words per grid (16x16: 2 K words; 66x66: 600 K words).
    Batch dimensions share one ``lax.while_loop`` (no vmap: that would add selects per step).
    """
    free = jnp.asarray(free, bool)
    batch = free.shape[:-2]
    h, w = free.shape[-2:]
    free = free.reshape((-1, h, w))
    nb_ = free.shape[0]
    n = h * w
    nw = (n + 31) // 32
    idx = jnp.arange(n, dtype=jnp.int32)
    bits = jnp.left_shift(jnp.uint32(1), (idx % 32).astype(jnp.uint32))
    eye = jnp.where(idx[:, None] // 32 == jnp.arange(nw)[None, :], bits[:, None], jnp.uint32(0))
    keep = jnp.where(free, jnp.uint32(0xFFFFFFFF), jnp.uint32(0))[..., None]  # [B, H, W, 1]
    reach0 = eye.reshape(1, h, w, nw) & keep

    def body(c):
        reach, last, t, length, _ = c
        p = jnp.pad(reach, ((0, 0), (1, 1), (1, 1), (0, 0)))
        new = (reach | p[:, :-2, 1:-1] | p[:, 2:, 1:-1] | p[:, 1:-1, :-2] | p[:, 1:-1, 2:]) & keep
        frontier = new & ~reach
        changed = jnp.any(frontier != 0, axis=(1, 2, 3))  # [B]
        last = jnp.where(changed[:, None, None, None], frontier, last)
        length = jnp.where(changed, t + 1, length)
        return new, last, t + 1, length, jnp.any(changed)

    init = (
        reach0,
        jnp.zeros_like(reach0),
        jnp.array(0, jnp.int32),
        jnp.zeros((nb_,), jnp.int32),
        jnp.array(True),
    )
    _, last, _, length, _ = jax.lax.while_loop(lambda c: c[4], body, init)

    def ends(last, length, free):
        last = last.reshape(n, nw)
        col = jax.lax.reduce(last, jnp.uint32(0), jax.lax.bitwise_or, (0,))  # sources at distance L
        w0 = jnp.argmax(col != 0)
        b0 = _lowest_bit(col[w0])
        s = w0 * 32 + b0
        t = jnp.argmax(((last[:, w0] >> b0.astype(jnp.uint32)) & 1) == 1)
        flat_free = free.reshape(n)
        first = jnp.where(jnp.any(flat_free), jnp.argmax(flat_free), -1)
        s = jnp.where(length > 0, s, first)
        t = jnp.where(length > 0, t, first)

        def rc(i):
            return jnp.where(i >= 0, jnp.stack([i // w, i % w]), jnp.array([-1, -1])).astype(jnp.int32)

        return rc(s), rc(t)

    start, goal = jax.vmap(ends)(last, length, free)
    return length.reshape(batch), start.reshape(batch + (2,)), goal.reshape(batch + (2,))


def _bfs_distances(free: jax.Array, source: jax.Array) -> jax.Array:
    """Shortest 4-connected distances ``[B, H, W]`` (int32, -1 = unreached) from one flat
    ``source [B]`` per grid of ``free [B, H, W]``; a source on a wall (or -1) reaches nothing.
    One ``lax.while_loop`` for the batch, one dilation of the reached set per step."""
    b, h, w = free.shape
    flat = jnp.arange(h * w, dtype=jnp.int32).reshape(1, h, w)
    reach0 = (flat == source[:, None, None]) & free
    dist0 = jnp.where(reach0, 0, -1).astype(jnp.int32)

    def body(c):
        reach, dist, t, _ = c
        p = jnp.pad(reach, ((0, 0), (1, 1), (1, 1)))
        new = (reach | p[:, :-2, 1:-1] | p[:, 2:, 1:-1] | p[:, 1:-1, :-2] | p[:, 1:-1, 2:]) & free
        frontier = new & ~reach
        return new, jnp.where(frontier, t + 1, dist), t + 1, jnp.any(frontier)

    _, dist, _, _ = jax.lax.while_loop(lambda c: c[3], body, (reach0, dist0, jnp.int32(0), jnp.array(True)))
    return dist


def double_sweep_path(
    free: jax.Array, key: jax.Array | None = None, sources: int = 4
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """A long shortest path of grid(s) ``free [..., H, W]`` by a double BFS sweep: from
    ``sources`` free tiles (random with ``key``, else the first ones, row-major) to the
    farthest tile ``a`` of the one that reaches farthest, then from ``a`` to the farthest tile
    ``b``. Same returns as :func:`longest_shortest_path` (``length`` = the distance from ``a``
    to ``b``; 0 and ``a == b`` when ``a`` is isolated). Several first sources keep a walled-in
    tile from standing for the whole maze.

    Exact on mazes without cycles (a tree's diameter), a lower bound elsewhere. Its cost grows
    like the map's area times the path's length (about 2 MB of scratch for 16 levels at 66x66,
    against 194 MB for the exact all-pairs search): it places start and goal on large training
    levels, not in the domain's objective, which stays exact.
    """
    free = jnp.asarray(free, bool)
    batch = free.shape[:-2]
    h, w = free.shape[-2:]
    free = free.reshape((-1, h, w))
    nb = free.shape[0]
    flat = free.reshape(nb, -1)
    any_free = jnp.any(flat, axis=1)
    if key is None:  # the first free tiles, row-major
        score = jnp.where(flat, -jnp.arange(h * w, dtype=jnp.float32), -jnp.inf)
    else:  # uniformly random free tiles
        score = jnp.where(flat, jax.random.uniform(key, flat.shape), -1.0)
    k = min(int(sources), h * w)
    _, firsts = jax.lax.top_k(score, k)  # [B, k]
    firsts = jnp.where(jnp.take_along_axis(flat, firsts, 1), firsts, -1).astype(jnp.int32)
    d1 = _bfs_distances(jnp.repeat(free, k, axis=0), firsts.reshape(-1)).reshape(nb, k, -1)
    far = jnp.max(d1, axis=2)  # [B, k] eccentricity of each first source (-1: a wall)
    best = jnp.argmax(far, axis=1)
    d1 = jnp.take_along_axis(d1, best[:, None, None], 1)[:, 0]
    a = jnp.where(any_free, jnp.argmax(d1, axis=1), -1).astype(jnp.int32)
    d2 = _bfs_distances(free, a).reshape(flat.shape)
    b = jnp.where(any_free, jnp.argmax(d2, axis=1), -1).astype(jnp.int32)
    length = jnp.where(any_free, jnp.max(d2, axis=1), 0).astype(jnp.int32)

    def rc(i):
        return jnp.where((i >= 0)[:, None], jnp.stack([i // w, i % w], axis=1), -1).astype(jnp.int32)

    return length.reshape(batch), rc(a).reshape(batch + (2,)), rc(b).reshape(batch + (2,))


# --------------------------------------------------------------------------- helpers at any size


def horizon_for(layout_shape: tuple[int, int], factor: int = 2) -> int:
    """Episode horizon: ``factor`` x tiles of the (bordered) layout (648 at 18x18)."""
    return int(factor) * int(layout_shape[0]) * int(layout_shape[1])


@jax.jit
def _solve(layout):
    return longest_shortest_path(layout == EMPTY)


def solve_start_goal(layout) -> tuple[np.ndarray, np.ndarray, int]:
    """``(start [2], goal [2], length)`` of a layout ``[H, W]`` (bordered or not; coordinates in
    the layout's frame). ``length == 0`` means unsolvable (objective 0). Compiles per shape."""
    length, start, goal = _solve(jnp.asarray(layout, jnp.int32))
    return np.asarray(start), np.asarray(goal), int(length)


class AgentRun(NamedTuple):
    lengths: np.ndarray  # [episodes] int, horizon where the goal was missed
    reached: np.ndarray  # [episodes] bool
    path: np.ndarray | None  # [T + 1, 2] positions of episode 0 (start included), if recorded
    dirs: np.ndarray | None  # [T + 1] directions of episode 0, if recorded


@cache
def _run_fn(kind: str, episodes: int, horizon: int, record: bool, weights: str | None = None):
    policy = maze_agent.get_policy(kind, weights)
    if record:
        return jax.jit(partial(maze_agent.record_episode, policy, episodes=episodes, horizon=horizon))
    return jax.jit(partial(maze_agent.rollout, policy, episodes=episodes, horizon=horizon))


def maze_key(key: jax.Array, index) -> jax.Array:
    """The agent's key for maze ``index`` of an evaluator call with ``key``.

    Folded in rather than split from ``key``, so a maze's episodes depend on its place in the
    batch but not on the batch's size: a batch and its first rows score those rows alike.
    """
    return jax.random.fold_in(key, index)


def run_agent(
    layout,
    start,
    goal,
    key,
    kind: str = DEFAULT_AGENT["kind"],
    episodes: int = 50,
    horizon: int | None = None,
    record_path: bool = False,
    weights: str | None = None,
) -> AgentRun:
    """Run ``episodes`` episodes of agent ``kind`` on one bordered layout ``[H, W]`` (any size).

    Same key derivation as the evaluator: maze ``i`` of an evaluator call with ``key`` equals
    ``run_agent(..., key=maze_key(key, i))``. ``horizon`` defaults to 2 x tiles.
    With ``record_path`` also returns episode 0's positions and directions (until the goal or
    the horizon). ``weights``: a directory of learned parameters (``kind="learned"``; None: the
    shipped agent).
    """
    layout = jnp.asarray(layout, jnp.int32)
    if horizon is None:
        horizon = horizon_for(layout.shape)
    start, goal = jnp.asarray(start, jnp.int32), jnp.asarray(goal, jnp.int32)
    res = _run_fn(kind, int(episodes), int(horizon), False, weights)(layout, start, goal, key)
    path = dirs = None
    if record_path:
        pos, d, length = _run_fn(kind, int(episodes), int(horizon), True, weights)(layout, start, goal, key)
        n = int(length) + 1
        path, dirs = np.asarray(pos)[:n], np.asarray(d)[:n]
    return AgentRun(np.asarray(res.lengths), np.asarray(res.reached), path, dirs)


# --------------------------------------------------------------------------- the domain


def _add_border(region):
    pad = [(0, 0)] * (region.ndim - 2) + [(1, 1), (1, 1)]
    if isinstance(region, jax.Array):
        return jnp.pad(region, pad, constant_values=WALL)
    region = np.asarray(region)
    return np.pad(region, pad, constant_values=WALL)


class MazeDomain(Domain):
    """Maze: NCA interior of ``" X"`` tiles, wall border, binary solvability objective."""

    name = "maze"
    gen_tiles = " X"
    layout_tiles = " X"
    palette = {" ": "#000000", "X": "#808080"}

    def __init__(self, cfg: Mapping[str, Any]):
        super().__init__(cfg)
        names = list(cfg["measures"]["names"])
        bad = [m for m in names if m not in MEASURES]
        if bad:
            raise NcaQdError(f"maze: unknown measure(s) {bad} (known: {', '.join(MEASURES)})")
        agent = {**DEFAULT_AGENT, **dict(cfg.get("agent") or {})}
        self.agent_kind = str(agent["kind"])
        self.agent_weights = None if agent["weights"] in (None, "") else str(agent["weights"])
        # fail early on an unknown kind or unreadable weights
        maze_agent.get_policy(self.agent_kind, self.agent_weights)
        self.episodes = int(agent["episodes"])
        self.horizon_factor = int(agent["horizon_factor"])

    def seed(self, shape: tuple[int, int]) -> np.ndarray:
        """All empty but a 2x2 wall block at the centre (rows/cols ``h//2 - 1`` and ``h//2``)."""
        h, w = (int(v) for v in shape)
        if h < 2 or w < 2:
            raise NcaQdError(f"maze: seed shape must be at least 2x2, got {h}x{w}")
        out = np.full((h, w), EMPTY, dtype=np.int32)
        out[h // 2 - 1 : h // 2 + 1, w // 2 - 1 : w // 2 + 1] = WALL
        return out

    def assemble(self, region):
        """Interior(s) ``[..., h, w]`` -> bordered layout(s) ``[..., h + 2, w + 2]`` (numpy or jax)."""
        return _add_border(region)

    def horizon(self, gen_shape: tuple[int, int]) -> int:
        return horizon_for((gen_shape[0] + 2, gen_shape[1] + 2), self.horizon_factor)

    def make_evaluator(self, run_cfg: Mapping[str, Any] | None = None) -> Evaluator:
        """The jitted scorer. With ``algo.ancillary`` set in ``run_cfg`` (DSAGE) it also returns
        ``extras["ancillary"] [b, h, w]``: the agent's visits per interior tile, averaged over
        episodes (DSAGE's agent occupancy)."""
        policy = maze_agent.get_policy(self.agent_kind, self.agent_weights)
        names = self.measure_names
        episodes, factor, k = self.episodes, self.horizon_factor, self.n_tiles
        ancillary = wants_ancillary(run_cfg)

        @jax.jit
        def evaluate(regions, key):
            regions = jnp.asarray(regions, jnp.int32)
            b, h, w = regions.shape
            horizon = horizon_for((h + 2, w + 2), factor)
            layouts = jnp.pad(regions, ((0, 0), (1, 1), (1, 1)), constant_values=WALL)
            length, start, goal = longest_shortest_path(regions == EMPTY)
            start = jnp.where(start >= 0, start + 1, start)
            goal = jnp.where(goal >= 0, goal + 1, goal)
            solvable = length > 0
            keys = jax.vmap(partial(maze_key, key))(jnp.arange(b))
            res = maze_agent.rollout_batch(
                policy, layouts, start, goal, keys, episodes, horizon, solvable, count_visits=ancillary
            )
            path_length = jnp.mean(res.lengths.astype(jnp.float32), axis=1)
            values = {
                "n_walls": tile_count(regions, WALL),
                "entropy": batch_entropy(regions, k) if "entropy" in names else None,
                "path_length": path_length,
            }
            measures = jnp.stack([values[m] for m in names], axis=1).astype(jnp.float32)
            extras = {
                "start": start,
                "goal": goal,
                "path_length": path_length,
                "success_rate": jnp.mean(res.reached.astype(jnp.float32), axis=1),
                "longest_shortest_path": length,
                "episode_lengths": res.lengths,
            }
            if ancillary:
                extras["ancillary"] = res.visits[:, 1:-1, 1:-1] / episodes
            return solvable.astype(jnp.float32), measures, extras

        def evaluator(regions, key, context=None) -> EvalBatch:  # context: not needed here
            objective, measures, extras = evaluate(regions, key)
            return EvalBatch(objective=objective, measures=measures, extras=extras)

        evaluator.jitted = evaluate  # type: ignore[attr-defined]
        return evaluator
