"""What every screening planner shares: a layout as padded arrays, counter-based random streams,
goal draws and the initial state of a run, and the distance tables.

:mod:`nca_qd.sim.screen` (PIBT, the default) and :mod:`nca_qd.sim.screen_windowed`
(prioritized planning over a window) both build on this module, so that the planners of a seed
start from the same state and draw the same goals; neither imports the other's internals.

Random streams are counter-based (a 32-bit integer hash of seed, agent, goal index, time), so
goal ``k`` of agent ``a`` is a pure function of (seed, a, k).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from nca_qd.errors import NcaQdError
from nca_qd.sim.scenario import Scenario

INF16 = 30000  # "unreachable" in the int16 distance table
DENSITY_K = 5  # side of the blocks the crowding rule counts agents in
DIST_CHUNK = 64  # goals per block of the distance relaxation on CPU (see distance_table)
WINDOW = 10  # the windowed planner's window w (RHCR's); at most 15 (a patch row is 2w+1 bits)
_PAD = 64  # goal-table and class sizes are padded to multiples of this (fewer recompiles)


class LayoutArrays(NamedTuple):
    """One layout (or a batch, with a leading axis) as padded arrays."""

    traversable: np.ndarray  # bool [H, W]
    goal_cells: np.ndarray  # int32 [G] flat cell of each distinct goal cell, -1 = padding
    class_goal: np.ndarray  # int32 [C, K] index into goal_cells, 0 = padding
    class_cum: np.ndarray  # float32 [C, K] cumulative weights, +inf = padding
    class_count: np.ndarray  # int32 [C]
    class_dwell: np.ndarray  # int32 [C]


def _round_up(n: int, m: int = _PAD) -> int:
    return max(m, -(-n // m) * m)


def _goal_cells(scen: Scenario) -> np.ndarray:
    """The distinct flat cells that are goals of any class (sorted): the distance table's rows."""
    return np.unique(np.concatenate([c.cells for c in scen.classes]))


def prepare(
    scens: Sequence[Scenario], pad_goals: int | None = None, pad_class: int | None = None
) -> LayoutArrays:
    """Stack validated scenarios of one scenario kind and one shape into padded arrays."""
    if not scens:
        raise NcaQdError("no layouts to simulate")
    names = {s.name for s in scens}
    shapes = {s.shape for s in scens}
    if len(names) != 1 or len(shapes) != 1:
        raise NcaQdError(
            f"a batch needs layouts of one scenario and one shape, got {sorted(names)} and {sorted(shapes)}"
        )
    uniq = [_goal_cells(s) for s in scens]
    G = pad_goals or _round_up(max(u.size for u in uniq))
    K = pad_class or _round_up(max(c.cells.size for s in scens for c in s.classes))
    C = len(scens[0].classes)
    out = []
    for s, u in zip(scens, uniq):
        gc = np.full(G, -1, np.int32)
        gc[: u.size] = u
        cg = np.zeros((C, K), np.int32)
        cum = np.full((C, K), np.inf, np.float32)
        for i, c in enumerate(s.classes):
            cg[i, : c.cells.size] = np.searchsorted(u, c.cells)
            cum[i, : c.cells.size] = np.cumsum(c.weights)
        out.append(
            LayoutArrays(
                s.traversable.astype(bool),
                gc,
                cg,
                cum,
                np.array([c.cells.size for c in s.classes], np.int32),
                np.array([c.dwell for c in s.classes], np.int32),
            )
        )
    return LayoutArrays(*(np.stack(x) for x in zip(*out)))


def _jax():
    import jax
    import jax.numpy as jnp

    return jax, jnp


def _on_cpu() -> bool:
    """Whether JAX runs on CPU: the distance tables then go in cache-sized chunks."""
    jax, _ = _jax()
    return jax.default_backend() == "cpu"


def _mix(x):
    """32-bit integer hash (murmur3 finaliser) on uint32 arrays."""
    _, jnp = _jax()
    x = x ^ (x >> 16)
    x = x * jnp.uint32(0x85EBCA6B)
    x = x ^ (x >> 13)
    x = x * jnp.uint32(0xC2B2AE35)
    return x ^ (x >> 16)


def _hash(*parts):
    _, jnp = _jax()
    h = jnp.uint32(0x9E3779B9)
    for p in parts:
        h = _mix(h ^ (jnp.asarray(p).astype(jnp.uint32) + jnp.uint32(0x7F4A7C15)))
    return h


def _uniform(h):
    _, jnp = _jax()
    return (h >> 8).astype(jnp.float32) * jnp.float32(1.0 / 16777216.0)


def distance_table(traversable, goal_cells, chunk: int | None = None):
    """int16 ``[G, H*W]`` shortest-path distances from each goal cell (INF16: unreachable).

    Repeated relaxation (every traversable cell takes the least of its own value and its
    neighbours' + 1) until nothing changes. The goals are the minor axis, so a sweep is four
    shifted row slices of a ``[H*W, chunk]`` block, and they go in chunks of ``chunk``
    (default :data:`DIST_CHUNK` on CPU, all goals at once elsewhere): on CPU a chunk's block
    stays in cache through its sweeps and stops when its own goals have converged (human
    101x102 warehouse, idle 2-core machine: 13.3 s with whole-table sweeps in ``[G, H, W]``,
    2.7 s now; on an accelerator one wide block keeps it busy). ``goal_cells`` < 0 (padding) or on a
    wall: rows of INF16.
    """
    jax, jnp = _jax()
    H, W = traversable.shape
    HW = H * W
    G = goal_cells.shape[0]
    if chunk is None:
        chunk = DIST_CHUNK if _on_cpu() else G
    C = max(1, min(int(chunk), G))
    n = -(-G // C)
    goals = jnp.concatenate([goal_cells.astype(jnp.int32), jnp.full(n * C - G, -1, jnp.int32)]).reshape(n, C)
    inf = jnp.int16(INF16)
    trav = traversable.reshape(HW, 1)
    col = jnp.arange(HW) % W
    has_left, has_right = (col > 0)[:, None], (col < W - 1)[:, None]

    def relax(d):
        p = jnp.pad(d, ((W, W), (0, 0)), constant_values=INF16)
        up, down = p[:HW], p[2 * W :]
        left = jnp.where(has_left, p[W - 1 : W - 1 + HW], inf)
        right = jnp.where(has_right, p[W + 1 : W + 1 + HW], inf)
        best = jnp.minimum(jnp.minimum(up, down), jnp.minimum(left, right))
        best = jnp.minimum(best, inf - 1) + 1
        return jnp.where(trav, jnp.minimum(d, best), inf)

    def body(c):
        d, _ = c
        nd = relax(relax(d))  # two sweeps per convergence test
        return nd, jnp.any(nd != d)

    def one_chunk(g):
        source = (g >= 0) & trav[jnp.clip(g, 0), 0]
        d = (
            jnp.full((HW, C), inf, jnp.int16)
            .at[jnp.clip(g, 0), jnp.arange(C)]
            .set(jnp.where(source, jnp.int16(0), inf))
        )
        d, _ = jax.lax.while_loop(lambda c: c[1], body, (d, jnp.bool_(True)))
        return d.T

    return jax.lax.map(one_chunk, goals).reshape(n * C, HW)[:G]


def _draw_goal(lay: LayoutArrays, cycle, base, agent, k, phase0):
    """Goal ``k`` of ``agent``: (goal-table index, class dwell). Vectorised over agents."""
    _, jnp = _jax()
    L = len(cycle)
    cyc = jnp.asarray(cycle, jnp.int32)
    cls = cyc[(phase0 + k) % L]
    u = _uniform(_hash(base, agent, k, 1))
    total = lay.class_cum[jnp.arange(lay.class_cum.shape[0]), lay.class_count - 1]
    idx = jnp.zeros_like(agent)
    for ci in range(lay.class_cum.shape[0]):
        i = jnp.searchsorted(lay.class_cum[ci], u * total[ci], side="right")
        i = jnp.clip(i, 0, lay.class_count[ci] - 1)
        idx = jnp.where(cls == ci, lay.class_goal[ci][i], idx)
    return idx.astype(jnp.int32), lay.class_dwell[cls]


def _initial_agents(lay: LayoutArrays, cycle, base, n_agents: int):
    """A run's start: distinct cells drawn uniformly over traversable tiles, each agent's
    phase in the task cycle and its first goal. Shared by every planner, so that the planners
    of a seed start from the same state. Returns (cells, phases, goals, dwells)."""
    _, jnp = _jax()
    agents = jnp.arange(n_agents, dtype=jnp.int32)
    trav = lay.traversable.reshape(-1)
    score = jnp.where(trav, _hash(base, jnp.arange(trav.size), 2), jnp.uint32(0xFFFFFFFF))
    pos0 = jnp.argsort(score)[:n_agents].astype(jnp.int32)
    phase0 = (_hash(base, agents, 3) % jnp.uint32(len(cycle))).astype(jnp.int32)
    goal0, dwell0 = _draw_goal(lay, cycle, base, agents, jnp.zeros(n_agents, jnp.int32), phase0)
    return pos0, phase0, goal0, dwell0


def initial_state(lay: LayoutArrays, cycle, seed, n_agents: int, n_tasks: int, n_paths: int | None) -> dict:
    """The run state every planner starts from (its own entries added by the planner): the
    shared initial agents of this layout and seed, counters at zero, ``tasks`` per timestep
    (``n_tasks`` slots) and, with ``n_paths``, each agent's cell per timestep from t = 0."""
    _, jnp = _jax()
    N = n_agents
    base = _hash(seed, 0x51ED)
    pos0, phase0, goal0, dwell0 = _initial_agents(lay, cycle, base, N)
    st = dict(
        t=jnp.int32(0),
        pos=pos0,
        goal=goal0,
        dwell=dwell0,
        arrived=jnp.zeros(N, bool),
        stayed=jnp.zeros(N, jnp.int32),
        k=jnp.zeros(N, jnp.int32),
        congested=jnp.bool_(False),
        tasks=jnp.zeros(n_tasks, jnp.int32),
        visits=jnp.zeros(lay.traversable.size, jnp.int32),
        base=base,
        phase0=phase0,
        delays=jnp.int32(0),
    )
    if n_paths is not None:
        st["paths"] = jnp.zeros((n_paths, N), jnp.int32).at[0].set(pos0)
    return st
