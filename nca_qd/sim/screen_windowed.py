"""The screen's windowed prioritized planner (``planner="windowed"`` of :mod:`nca_qd.sim.screen`).

RHCR's scheme with windowed PBS replaced by prioritized planning in one fixed order per call:
every ``replan`` = h steps the agents, in a fresh random order (agents dwelling at a goal
first), each plan a ``window`` = w step path by space-time search on a reservation table
holding the paths of the agents planned before them; the first h steps of every path are
executed, then everyone replans.

Per agent the search is a wavefront over the (2w+1)^2 patch around it (every cell a w-step
path can reach): ``reach[t+1] = free[t+1] & (reach[t] | moves into it)``, where ``free[t]``
excludes walls and cells reserved at time t, and a move x -> y at step t -> t+1 is barred when
the agent reserved on y at t is on x at t+1 (a swap). Conflicts forbidden within the window:
vertex and swap, as in PBS; nothing is reserved after step w. The path minimises the time of
arrival at the agent's current goal if it can arrive within the window and then stand on the
goal until step w (the cell free from arrival to w); otherwise w + the true distance to the
goal (the screen's distance tables) from the cell reached at step w, random ties. As in RHCR,
where an agent plans through its goal sequence, a goal finished inside the window leads on to
the next one: a second wavefront holds the cells reachable *after* the goal is done (the agent
arrived, then stood on it for its dwell), and a path that finishes its goal in the window is
preferred and ends nearest the next goal. (Without it an agent parked on its goal to the end
of the window, blocking the aisle for the agents planned after it: on 27 held-out layouts the
screen's throughput where both flow went from 0.76 to 0.89 of RHCR's with the second layer.)
The path is recovered by a backtrack through the stored wavefronts (waiting as late as
possible).

An agent that finds no path stays where it is, reserved there for the whole window. Agents
planned earlier whose paths cross its cell are then replanned (the stuck agents fixed first,
the rest in the call's order), until no path crosses a stuck agent: every executed step is
free of vertex and swap conflicts.

Execution, goal bookkeeping, congestion and throughput follow ``rhcr.cpp``: goals are done
when the agent has stood on the goal cell for the arrival step plus its dwell; after each
round, more than half of the agents stuck (stood on one cell at the round's times t .. t+h-1
and were not dwelling there) -> congested, stop; throughput = finished tasks / T. Goals are
the screen's counter-based streams (the planner looks at an agent's current goal and the
one after it, drawn from the same stream).

How it compares with exact RHCR and with the PIBT screen (rank correlation, congestion
agreement, throughput where both flow, speed) and the variants measured and not kept are in
docs/benchmarks.md ("Screening simulator", ``screen.planner=windowed``). Not the screen's
default.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

from nca_qd.sim.screen_base import DENSITY_K, WINDOW, LayoutArrays, _draw_goal, _hash, _jax, initial_state
from nca_qd.sim.screen_windowed_call import _planner, plan_window


class _Rounds(NamedTuple):
    """What every planning round of one batch reads (sizes, options, shared arrays)."""

    N: int
    T: int
    h: int  # replan period: steps executed per round
    cycle: tuple
    record_paths: bool
    H: int
    W: int
    G: int
    n_rounds: int
    lay_all: LayoutArrays
    dist_flat: Any
    agents: Any
    units: Any  # units of Z_N (the random order's multipliers)
    plan_call: Any

    @property
    def HW(self) -> int:
        return self.H * self.W

    def layout(self, li):
        return LayoutArrays(*(x[li] for x in self.lay_all))


def _plan_one(rd: _Rounds, st: dict, li):
    """One planning call: a fresh random order (dwelling agents first), then the search."""
    _, jnp = _jax()
    N, agents = rd.N, rd.agents
    hs = _hash(st["base"], st["t"], 6)
    unit = rd.units[(hs % jnp.uint32(len(rd.units))).astype(jnp.int32)]
    shift = ((hs >> 16) % jnp.uint32(N)).astype(jnp.int32)
    order0 = (unit * agents + shift) % N
    dwelling = st["arrived"] & (st["stayed"] < st["dwell"])
    first = dwelling[order0]
    n_first = jnp.sum(first)
    slot = jnp.where(first, jnp.cumsum(first) - 1, n_first + jnp.cumsum(~first) - 1)
    order = jnp.zeros(N, jnp.int32).at[slot].set(order0)
    goal2, _ = _draw_goal(rd.layout(li), rd.cycle, st["base"], agents, st["k"] + 1, st["phase0"])
    drem = jnp.where(st["arrived"], jnp.maximum(st["dwell"] - st["stayed"], 0), st["dwell"])
    salt = _hash(st["base"], st["t"], 8)
    return rd.plan_call(st["pos"], st["goal"], goal2, drem, li, order, salt)[0]


def _init_one(rd: _Rounds, li, seed) -> dict:
    """A run's state at t = 0: the planners' shared start, and this planner's own entries
    (room for the h steps a last round may plan past T)."""
    _, jnp = _jax()
    T, h = rd.T, rd.h
    st = initial_state(rd.layout(li), rd.cycle, seed, rd.N, T + h, T + h + 1 if rd.record_paths else None)
    return dict(st, tasking=jnp.zeros(rd.N, bool), crowd=jnp.zeros(rd.n_rounds + 1, jnp.int32))


def _crowding(rd: _Rounds, pos):
    """The most agents in one DENSITY_K x DENSITY_K block."""
    _, jnp = _jax()
    H, W = rd.H, rd.W
    grid = jnp.zeros(rd.HW, jnp.int32).at[pos].set(1).reshape(H, W)
    cs = jnp.pad(jnp.cumsum(jnp.cumsum(grid, 0), 1), ((1, 0), (1, 0)))
    kk = min(DENSITY_K, H, W)
    block = cs[kk:, kk:] - cs[:-kk, kk:] - cs[kk:, :-kk] + cs[:-kk, :-kk]
    return jnp.max(block).astype(jnp.int32)


def _execute(rd: _Rounds, li, plan, live, s, start, x: dict) -> dict:
    """Execute step ``s`` (1-based) of the plan where ``live``: RHCR's goal bookkeeping."""
    _, jnp = _jax()
    T, h, HW, dist_flat = rd.T, rd.h, rd.HW, rd.dist_flat
    lay = rd.layout(li)
    x = dict(x)
    pos = x["pos"]
    nxt = jnp.where(live, plan[:, s], pos)
    gbase = (li * rd.G + x["goal"]) * HW
    dwelling = x["arrived"] & (x["stayed"] < x["dwell"])
    delayed = live & ~dwelling & (dist_flat[gbase + nxt] >= dist_flat[gbase + pos])
    at = nxt == lay.goal_cells[x["goal"]]
    tasking = at & x["arrived"] & (x["dwell"] > 0)
    stayed = jnp.where(at & x["arrived"], x["stayed"] + 1, 0)
    done = at & (stayed >= x["dwell"])
    k = x["k"] + done
    g, dw = _draw_goal(lay, rd.cycle, x["base"], rd.agents, k, x["phase0"])
    goal = jnp.where(done, g, x["goal"])
    again = done & (lay.goal_cells[goal] == nxt)
    new = dict(
        pos=nxt,
        goal=goal,
        dwell=jnp.where(done, dw, x["dwell"]),
        arrived=jnp.where(done, again, at),
        stayed=jnp.where(done, 0, stayed),
        tasking=tasking,
        k=k,
        stuck=x["stuck"] & ~((s < h) & ((nxt != start) | tasking)),
    )
    for key, val in new.items():
        x[key] = jnp.where(live, val, x[key])
    ti = jnp.where(live, x["t"] + s, T + h + 1)
    x["tasks"] = x["tasks"].at[ti - 1].add(jnp.sum(done), mode="drop")
    x["visits"] = x["visits"].at[nxt].add(live.astype(jnp.int32))
    x["delays"] = x["delays"] + jnp.sum(delayed)
    if rd.record_paths:
        x["paths"] = x["paths"].at[ti].set(nxt, mode="drop")
    return x


def _round_one(rd: _Rounds, st: dict, li) -> dict:
    """One round of a run: plan, execute h steps, RHCR's congestion rule, the crowding."""
    jax, jnp = _jax()
    T, h = rd.T, rd.h
    running = ~st["congested"] & (st["t"] < T)
    plan = _plan_one(rd, st, li)
    steps = jnp.minimum(h, T - st["t"])
    start = st["pos"]
    c = dict(st, stuck=~st["tasking"])
    c = jax.lax.fori_loop(
        1, h + 1, lambda s, x: _execute(rd, li, plan, running & (s <= steps), s, start, x), c
    )
    t = st["t"] + jnp.where(running, steps, 0)
    congested = st["congested"] | (running & (2 * jnp.sum(c.pop("stuck")) > rd.N))
    ri = jnp.where(running, st["t"] // h, rd.n_rounds)
    return dict(
        c,
        t=t,
        congested=congested,
        crowd=st["crowd"].at[ri].set(_crowding(rd, c["pos"])),
    )


def run_batch(
    lay_all: LayoutArrays,
    dist_all,
    lidx,
    seeds,
    *,
    n_agents: int,
    T: int,
    replan: int,
    cycle: tuple,
    record_paths: bool,
    window: int = WINDOW,
):
    """All runs in lock-step (run ``r``: layout ``lidx[r]``, seed ``seeds[r]``); the same
    results dictionary as :func:`nca_qd.sim.screen_pibt.run_batch`."""
    jax, jnp = _jax()
    L, H, W = lay_all.traversable.shape
    N = n_agents
    n_rounds = -(-T // replan)
    rd = _Rounds(
        N=N,
        T=T,
        h=replan,
        cycle=cycle,
        record_paths=record_paths,
        H=H,
        W=W,
        G=dist_all.shape[1],
        n_rounds=n_rounds,
        lay_all=lay_all,
        dist_flat=dist_all.reshape(-1),
        agents=jnp.arange(N, dtype=jnp.int32),
        units=jnp.asarray([u for u in range(1, N + 1) if math.gcd(u, N) == 1], jnp.int32),
        plan_call=_planner(lay_all, dist_all, N, int(window)),  # window >= h (screen._check)
    )
    st = jax.vmap(lambda li, s: _init_one(rd, li, s))(lidx, seeds)
    st = jax.lax.while_loop(
        lambda s: jnp.any(~s["congested"] & (s["t"] < T)),
        lambda s: jax.vmap(lambda x, li: _round_one(rd, x, li))(s, lidx),
        st,
    )
    res = dict(
        stop_time=st["t"],
        congested=st["congested"],
        tasks=st["tasks"][:, :T],
        visits=st["visits"].reshape(-1, H, W),
        k=st["k"],
        base=st["base"],
        delays=st["delays"],
        crowd=st["crowd"][:, :n_rounds],
    )
    if record_paths:
        res["paths"] = st["paths"][:, : T + 1]
    return res


__all__ = ["WINDOW", "plan_window", "run_batch"]
