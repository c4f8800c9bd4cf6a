"""Screening lifelong-MAPF simulator in JAX: jitted, vmapped over layouts and seeds.

A fast approximation of the exact RHCR simulator (:mod:`nca_qd.sim.rhcr`) for ranking many
layouts. Same task model (:func:`nca_qd.sim.scenario.build_scenario`): goal classes, class
cycle with a uniformly drawn first kind, weighted goal cells, dwell times, distinct uniform
initial cells, RHCR's congestion rule (every ``replan`` = h steps: more than half of the
agents neither moved nor dwelt during those h steps -> stop, failure) and throughput =
finished tasks / T with T the full horizon. By default (``congestion="crowding"``) a run also
stops, as congested, when from the 10th check on the most crowded 5x5 block has held >= 17
agents on average since the start (on a map larger than 33x36, the mean of its r most
crowded blocks, r = its blocks / a 33x36 map's: see :func:`crowd_rank`): a calibrated proxy for
the dense jams in which RHCR's windowed PBS collapses but PIBT does not
(``congestion="moved"`` applies RHCR's rule alone).

Planning differs: instead of windowed PBS over space-time A* replanned every h steps, every
timestep each agent takes one step by PIBT (Okumura et al. 2022), run as an explicit stack in
a ``lax.while_loop``. Dwelling agents stay. An agent whose best tile is empty and a candidate
of no other agent takes it (PIBT would give it that tile in any order). The others, as roots
in priority order, claim the best free candidate among {stay, 4 neighbours} ranked by the
true distance to the goal (random ties among moves); if the tile holds an undecided agent,
that agent is pushed (priority inheritance: it must move, not onto its pusher's tile,
possibly away from its goal); a pushed agent that finds no tile stays and its pusher tries
its next candidate. No vertex or swap conflict can occur (rotations of three or more agents
can, as the checker allows). Priority: ``"random"`` (default) draws a fresh agent order
every step (a random affine bijection of the agent indices, no sort), which avoids PIBT's
standing deadlocks in cluttered layouts; ``"age"`` is PIBT's (steps since the last finished
goal, fixed random tie-break).

How it differs from RHCR in outcome: PIBT keeps traffic moving by pushing agents back, so with
RHCR's congestion rule alone it almost never congests where windowed PBS collapses (e.g. the
human-designed warehouse); the crowding proxy is what makes its verdicts track RHCR's. It has
no lookahead, so its throughput is below RHCR's where RHCR runs freely, and with the crowding
proxy it is too pessimistic on some layouts (random aisles at 33x36; manufacturing with 1,800
agents at 101x102). Rank layouts with it; do not take its success/failure verdict as RHCR's.
Its agreement with RHCR (rank correlation, congestion verdicts per run and per layout, at both
sizes) is measured by ``benchmarks/bench_screen.py`` and recorded, with dates, in
docs/benchmarks.md ("Screening simulator").

``planner="windowed"`` replaces PIBT by RHCR's scheme with windowed PBS replaced by prioritized
planning in one random order per call (:mod:`nca_qd.sim.screen_windowed`: every h steps each
agent plans a w=10-step path by a space-time wavefront over its (2w+1)^2 patch, against the
paths of the agents before it; one that finds none stays; RHCR's congestion rule alone).
It is experimental and not the default: it ranks layouts better than PIBT but agrees on
congestion less (it congests too early: no priority swaps for stuck agents, agents stop at
goals inside the window), and it is an order of magnitude slower (docs/benchmarks.md).

Distances (true shortest paths from every goal cell to every cell) are computed in JAX per
layout by repeated relaxation of all goal cells at once, stored as int16 ``[G, H*W]``.

Random streams are counter-based (a 32-bit integer hash of seed, agent, goal index, time), so
goal ``k`` of agent ``a`` is a pure function of (seed, a, k): the goal log is rebuilt after the
run instead of being carried through it. Streams do not match RHCR's.

>>> r = simulate(rows, "warehouse_even", n_agents=200, T=1000, seed=0)
>>> grid = simulate_batch([rows_a, rows_b], "warehouse_even", 200, 1000, seeds=range(5))
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from nca_qd.errors import NcaQdError
from nca_qd.sim import screen_base
from nca_qd.sim.result import RunResult
from nca_qd.sim.scenario import Scenario, build_scenario
from nca_qd.sim.screen_base import (
    DENSITY_K,
    WINDOW,
    LayoutArrays,
    _draw_goal,
    _goal_cells,
    _hash,
    _initial_agents,
    _jax,
    _on_cpu,
    _round_up,
    distance_table,
    prepare,
)

__all__ = [
    "ScreenResult",
    "LayoutArrays",
    "simulate",
    "simulate_batch",
    "simulate_scenarios",
    "prepare",
    "goal_log",
]

# The screen's decisions: bump whenever a change alters any run's outcome (the evaluation's
# screen_runs.jsonl reuses recorded runs of the same version; tests/test_screen.py holds the
# digest of reference runs per version).
VERSION = 2  # 2: crowding on maps larger than 33x36 is the mean of the r most crowded blocks
PRIORITY = "random"  # "random": fresh random agent order each step; "age": PIBT's (steps
# since the last finished goal, fixed random tie-break)
# "crowding" congestion (default): RHCR's rule, or, from the CROWD_MIN_CHECKS-th check on, a
# mean since the start of >= CROWD_MEAN agents in the most crowded DENSITY_K x DENSITY_K block
# at each check -- a proxy for the dense jams in which RHCR's windowed PBS collapses and PIBT
# does not. Calibrated on 41 layouts of benchmarks/bench_screen.py's generator with seed 0 (a
# grid over threshold, first check and window; the running mean beat "3 checks in a row >= 20"
# there and on the held-out seed-1 set: per-run agreement 0.73 -> 0.80); figures use seed 1.
# CROWD_MEAN is the default; a domain whose traffic crowds more where it flows sets its own
# (``crowd_mean``; the domain config's ``simulation.screen_crowd_mean``).
# On a larger map the rule looks at the mean of the r most crowded blocks, r = the map's blocks
# / CROWD_REF_BLOCKS (those of a 33x36 map, where the thresholds were calibrated): the maximum
# over 9x as many blocks is higher at the same density (101x102: the manufacturing generator
# RHCR runs at 22.2 showed 19.6-19.8 against its threshold of 18), while a map's r most crowded
# blocks hold what its most crowded 33x36 part would (docs/benchmarks.md, "Crowding that
# scales with the map").
CROWD_REF_BLOCKS = (33 - DENSITY_K + 1) * (36 - DENSITY_K + 1)
CROWD_MEAN = 17.0
CROWD_MIN_CHECKS = 10
PLANNER = "pibt"  # or "windowed": prioritized planning over a window (screen_windowed.py)
# PIBT's congestion rule; the windowed planner applies "moved" (RHCR's) only
CONGESTION = "crowding"  # or "moved" (RHCR's rule alone), or "progress" (more than half
# neither finished a goal, dwelt, nor ended the h steps closer to it)
DRAW_ROUND = 32  # at least this many new goals are drawn per round (see draw_done)
MAX_AGENTS = 46340  # (N - 1) * N + N < 2**31 for the random order's affine map
ROOT_LOOKAHEAD = 4  # roots looked at per PIBT call for one that no push has decided yet
PREDECIDE = True  # decide the moves PIBT makes in any order before its search (same plan,
# fewer sequential calls); False runs plain PIBT (tests compare the two)
MAX_TABLE = 2**28  # int16 distance-table entries per batch (512 MiB); more -> several batches


def crowd_rank(height: int, width: int) -> int:
    """How many of a map's most crowded DENSITY_K x DENSITY_K blocks the crowding rule averages:
    one per CROWD_REF_BLOCKS blocks (a 33x36 map's), rounded: 1 at 33x36, 10 at 101x102."""
    blocks = max(1, height - DENSITY_K + 1) * max(1, width - DENSITY_K + 1)
    return max(1, (blocks + CROWD_REF_BLOCKS // 2) // CROWD_REF_BLOCKS)


def crowd_mean_for(domain_cfg: Mapping[str, Any], override: Any = None) -> float:
    """The crowding threshold a domain config asks for (``simulation.screen_crowd_mean``, else
    :data:`CROWD_MEAN`), or ``override`` where it is not None; a bad value is one clear line."""
    value = override
    if value is None:
        value = (domain_cfg.get("simulation") or {}).get("screen_crowd_mean", CROWD_MEAN)
    return _crowd_mean(value)


def _crowd_mean(value: Any) -> float:
    """A crowding threshold as a float: a positive finite number, or one clear line."""
    number = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    if not number or not 0 < value < float("inf"):
        raise NcaQdError(
            f"the crowding threshold (screen_crowd_mean) must be a positive number, got {value!r}"
        )
    return float(value)


@dataclass
class ScreenResult(RunResult):
    """Outcome of one screening run: :class:`~nca_qd.sim.result.RunResult` plus two diagnostics.

    ``cpu_seconds`` / ``wall_seconds`` are the batch's process CPU / wall time divided by the
    number of runs in the batch (compilation excluded when it was already compiled).
    ``goals[a]`` holds the goals agent ``a`` finished, then its current one.
    """

    # share of agent-steps (not dwelling) that did not bring the agent closer to its goal
    delay_rate: float = 0.0
    # the most agents in one DENSITY_K x DENSITY_K block (on a map larger than 33x36: the mean
    # of its crowd_rank most crowded blocks), at each congestion check
    crowding: np.ndarray | None = field(default=None, repr=False)

    def summary(self) -> dict:
        return {**super().summary(), "congested": self.congested}


def _neighbours(traversable):
    """``[H*W, 5]`` candidate cells (stay, up, down, left, right) and whether each is legal."""
    _, jnp = _jax()
    H, W = traversable.shape
    r, c = jnp.divmod(jnp.arange(H * W), W)
    dr = jnp.array([0, -1, 1, 0, 0])
    dc = jnp.array([0, 0, 0, -1, 1])
    rr, cc = r[:, None] + dr, c[:, None] + dc
    inside = (rr >= 0) & (rr < H) & (cc >= 0) & (cc < W)
    cell = jnp.where(inside, rr * W + cc, H * W)
    ok = inside & jnp.concatenate([traversable.reshape(-1), jnp.zeros(1, bool)])[cell]
    return jnp.where(ok, cell, H * W).astype(jnp.int32), ok


def _run_batch(
    lay_all: LayoutArrays,
    dist_all,
    lidx,
    seeds,
    *,
    n_agents,
    T,
    replan,
    cycle,
    record_paths,
    priority,
    congestion,
    crowd_mean=CROWD_MEAN,
):
    """All runs in lock-step: run ``r`` simulates layout ``lidx[r]`` with ``seeds[r]``.

    Written per run and ``jax.vmap``-ed, except that the loops (time, and PIBT's stack inside
    a timestep) run over the whole batch with a batch-wide condition, and a finished run's
    body is a no-op; this avoids the per-iteration selects over the carry that a vmapped
    ``while_loop`` would do. ``dist_all`` is ``[L, G, H*W]``.
    """
    jax, jnp = _jax()
    lax = jax.lax
    vmap = jax.vmap
    L, H, W = lay_all.traversable.shape
    HW = H * W
    G = dist_all.shape[1]
    N = n_agents
    agents = jnp.arange(N, dtype=jnp.int32)
    n_checks = -(-T // replan)
    rank = crowd_rank(H, W)  # blocks the crowding rule averages
    nbr_all, ok_all = vmap(_neighbours)(lay_all.traversable)  # [L, HW, 5]
    n_draw = min(N, max(DRAW_ROUND, N // 16))  # goals drawn per round in draw_done
    units = jnp.asarray([u for u in range(1, N + 1) if math.gcd(u, N) == 1], jnp.int32)
    dist_flat = dist_all.reshape(-1)

    def layout(li):
        return LayoutArrays(*(x[li] for x in lay_all))

    def init_one(li, seed):
        lay = layout(li)
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
            prio=jnp.zeros(N, jnp.int32),
            active=jnp.zeros(N, bool),
            congested=jnp.bool_(False),
            tasks=jnp.zeros(T, jnp.int32),
            visits=jnp.zeros(HW, jnp.int32),
            base=base,
            phase0=phase0,
            tiebreak=(_hash(base, agents, 4) & 2047).astype(jnp.int32),
            togo=dist_flat[(li * G + goal0) * HW + pos0].astype(jnp.int32),
            delays=jnp.int32(0),
            crowd_sum=jnp.int32(0),
            n_checked=jnp.int32(0),
            crowd=jnp.zeros(n_checks + 1, jnp.int32),
        )
        if record_paths:
            st["paths"] = jnp.zeros((T + 1, N), jnp.int32).at[0].set(pos0)
        return st

    def prep_one(st, li):
        """Candidates in preference order, and the agents decided without search."""
        pos, goal = st["pos"], st["goal"]
        running = ~st["congested"] & (st["t"] < T)
        dwelling = st["arrived"] & (st["stayed"] < st["dwell"])
        cand = nbr_all[li, pos]  # [N, 5]
        ok = ok_all[li, pos] & ~(dwelling[:, None] & (jnp.arange(5) > 0))
        d = dist_flat[((li * G + goal) * HW)[:, None] + jnp.minimum(cand, HW - 1)]
        rnd = _hash(st["base"], st["t"], agents[:, None] * 5 + jnp.arange(5), 5) & 7
        rnd = rnd.astype(jnp.int32).at[:, 0].set(0)
        key = jnp.where(ok, d.astype(jnp.int32) * 8 + rnd, jnp.int32(2**26)) * 8 + jnp.arange(5)
        # Preference order without a sort: each candidate's rank among the five (keys unique).
        rank = jnp.sum(key[:, None, :] < key[:, :, None], axis=2)  # [N, 5]
        slot = rank[:, :, None] == jnp.arange(5)  # [N, cand, slot]
        pref = jnp.sum(jnp.where(slot, cand[:, :, None], 0), axis=1)
        pref_ok = jnp.any(slot & ok[:, :, None], axis=1)
        occ = jnp.full(HW + 1, -1, jnp.int32).at[pos].set(agents)
        # The priority order: agent ``order0[i]`` is the i-th highest.
        if priority == "age":  # steps since the last finished goal, then a fixed random tie-break
            okey = (2**18 - jnp.minimum(st["prio"], 2**18 - 1)) * 2**11 + st["tiebreak"]
            order0 = jnp.argsort(okey).astype(jnp.int32)
        else:
            # A fresh random order every step without a sort (an argsort of N keys per run
            # and step was among the costliest parts of a step): the affine bijection
            # i -> (a*i + b) mod N with a random unit a of Z_N and a random shift b.
            h = _hash(st["base"], st["t"], 6)
            unit = units[(h % jnp.uint32(len(units))).astype(jnp.int32)]
            shift = ((h >> 16) % jnp.uint32(N)).astype(jnp.int32)
            order0 = (unit * agents + shift) % N
        # Decided before the search: dwelling agents stay; then only what PIBT decides in
        # any order. An agent whose best tile is empty and a candidate of no other agent
        # takes it; so does one whose best tile holds a decided agent that moves away and is
        # a candidate of no one else (PIBT would push that agent, whose own move is decided
        # the same way). Chains of such followers grow one link a round.
        contenders = jnp.zeros(HW + 1, jnp.int32).at[jnp.where(ok, cand, HW)].add(1)
        best = pref[:, 0]
        o = occ[best]
        oc = jnp.maximum(o, 0)
        base_ok = ~dwelling & running & pref_ok[:, 0] & (best != pos)
        free = base_ok & (o < 0) & (contenders[best] == 1) & PREDECIDE
        can_follow = base_ok & (o >= 0) & (contenders[best] == 2) & PREDECIDE

        def follow(c):
            pre, target, _ = c
            f = can_follow & ~pre & pre[oc] & (target[oc] != pos[oc])
            return pre | f, jnp.where(f, best, target), jnp.any(f)

        stay = dwelling & running
        pre = stay | free
        target = jnp.where(stay, pos, jnp.where(free, best, -1))
        pre, target, _ = lax.while_loop(lambda c: c[2], follow, (pre, target, jnp.bool_(True)))
        resv = jnp.zeros(HW + 1, bool).at[jnp.where(pre, target, HW)].set(True)
        # Roots: the undecided agents in priority order (a stable partition of order0).
        n_undecided = jnp.sum(~pre).astype(jnp.int32)
        und = ~pre[order0]
        slot = jnp.where(und, jnp.cumsum(und) - 1, n_undecided + jnp.cumsum(~und) - 1)
        order = jnp.zeros(N, jnp.int32).at[slot].set(order0)
        n_roots = jnp.where(running, n_undecided, 0).astype(jnp.int32)
        # What the search reads about an agent, in one row (one gather per call): its cell,
        # its candidates in preference order (illegal ones -> the sentinel cell HW, which is
        # always reserved) and who stands on each.
        pref_c = jnp.where(pref_ok, pref, HW)
        info = jnp.concatenate([pos[:, None], pref_c, occ[pref_c]], axis=1)  # [N, 11]
        aux = dict(info=info, order=order, n_roots=n_roots)
        carry = (
            jnp.int32(0),
            jnp.int32(0),
            jnp.int32(0),
            jnp.int32(0),
            jnp.zeros((N, 2), jnp.int32),
            target.astype(jnp.int32),
            resv.at[HW].set(True),
        )
        return carry, aux

    def pibt_one(c, x):
        """One PIBT action: start the next root, or move the top agent to its next free tile.

        An agent claims its best free candidate; if that tile holds an undecided agent, that
        agent is pushed (it must move and may not take its pusher's tile); a pushed agent
        that finds no tile stays, and its pusher tries its next candidate.

        Each call does what sequential PIBT does between two changes of state, so the plan is
        the same as one candidate and one root per call would give, in fewer calls (measured
        on bench_screen's batch: 279 calls per run and step -> about 145): the next root is
        the first of the next ``ROOT_LOOKAHEAD`` roots that no push has decided yet, and the
        five candidates are checked at once, the first free one from the current one on
        taken (blocked ones are skipped rather than tried one call each).

        State per run: ``j`` the next root's index in ``order``, ``sp`` the stack depth, ``a``
        and ``k`` the top agent and the candidate it is at (kept out of the stack, whose
        rows hold the pushers below it as (agent * 8 + candidate, cell)), ``target`` every
        agent's decided cell (-1: undecided), ``resv`` the cells taken. A call reads a few
        entries and writes at most one per array, so XLA updates them in place: on CPU its
        cost per run no longer grows with N (bench_screen's batch: 20 s -> 15 s).
        """
        j, sp, a, k, stack, target, resv = c
        order = x["order"]
        empty = sp == 0
        js = j + jnp.arange(ROOT_LOOKAHEAD)
        roots = order[jnp.minimum(js, N - 1)]
        fresh = (js < x["n_roots"]) & (target[roots] < 0)
        first = jnp.argmax(fresh)
        start = empty & jnp.any(fresh)
        a = jnp.where(start, jnp.sum(jnp.where(jnp.arange(ROOT_LOOKAHEAD) == first, roots, 0)), a)
        k = jnp.where(start, 0, k)
        sp = jnp.where(start, 1, sp)
        j = jnp.where(empty, jnp.where(start, j + first + 1, j + ROOT_LOOKAHEAD), j)
        active = sp > 0
        row = x["info"][a]
        pa, vs, os_ = row[0], row[1:6], row[6:11]
        below = stack[jnp.maximum(sp - 2, 0)]  # the pusher: (agent * 8 + candidate, cell)
        others = (os_ >= 0) & (os_ != a)
        blocked = resv[vs] | ((sp > 1) & (vs == below[1])) | (others & (target[jnp.maximum(os_, 0)] == pa))
        avail = (jnp.arange(5) >= k) & ~blocked
        kk = jnp.argmax(avail).astype(jnp.int32)
        exhausted = ~jnp.any(avail)
        sel = jnp.arange(5) == kk  # (a one-hot pick: elementwise, not a gather)
        v = jnp.sum(jnp.where(sel, vs, 0))
        o = jnp.sum(jnp.where(sel, os_, 0))
        try_ok = active & ~exhausted
        push = try_ok & (o >= 0) & (o != a) & (target[jnp.maximum(o, 0)] < 0)
        success = try_ok & ~push
        fail = active & exhausted
        cell = jnp.where(fail, pa, v)
        # (``push & (o < -1)`` is always false: it only orders the read of ``target[o]``
        # before the write below, which spares XLA two copies of ``target`` per call.)
        write = try_ok | fail | (push & (o < -1))
        # Conditional writes as scatters to an out-of-range index, dropped: no read needed.
        target = target.at[jnp.where(write, a, N)].set(cell, mode="drop")
        resv = resv.at[jnp.where(write, cell, HW + 1)].set(True, mode="drop")
        # A push keeps the pusher (and the candidate it took) on the stack and makes the
        # pushed agent the top; a failed top gives way to its pusher's next candidate.
        stack = stack.at[jnp.where(push, sp - 1, N)].set(jnp.stack([a * 8 + kk, pa]), mode="drop")
        pop = fail & (sp > 1)
        a = jnp.where(push, o, jnp.where(pop, below[0] // 8, a))
        k = jnp.where(push, 0, jnp.where(pop, below[0] % 8 + 1, kk))
        sp = jnp.where(push, sp + 1, jnp.where(success, 0, jnp.where(fail, sp - 1, sp)))
        return j, sp, a, k, stack, target, resv

    def draw_done(lay, st, done, k):
        """New goals (and dwell times) of the agents that finished one, the others' kept.

        Few agents finish a goal per step, so goals are drawn for up to ``n_draw`` of them
        at a time (their indices compacted), in a loop that runs once on almost every step,
        rather than for all N agents (13 % less screen time in bench_screen's batch)."""

        def body(c):
            goal, dwell, rem = c
            idx = jnp.nonzero(rem, size=n_draw, fill_value=N)[0]
            safe = jnp.minimum(idx, N - 1)
            g, d = _draw_goal(lay, cycle, st["base"], safe, k[safe], st["phase0"][safe])
            return (
                goal.at[idx].set(g, mode="drop"),
                dwell.at[idx].set(d, mode="drop"),
                rem.at[idx].set(False, mode="drop"),
            )

        goal, dwell, _ = lax.while_loop(lambda c: jnp.any(c[2]), body, (st["goal"], st["dwell"], done))
        return goal, dwell

    def finish_one(st, target, li):
        """Execute the planned step; goal bookkeeping; congestion check every replan steps."""
        lay = layout(li)
        running = ~st["congested"] & (st["t"] < T)
        t = st["t"] + 1
        pos = st["pos"]
        nxt = jnp.where(running, target, pos)
        moved = nxt != pos
        at = nxt == lay.goal_cells[st["goal"]]
        gbase = (li * G + st["goal"]) * HW
        dwelling = st["arrived"] & (st["stayed"] < st["dwell"])
        delayed = running & ~dwelling & (dist_flat[gbase + nxt] >= dist_flat[gbase + pos])
        stayed = jnp.where(at & st["arrived"], st["stayed"] + 1, 0)
        done = at & (stayed >= st["dwell"])
        k = st["k"] + done
        goal, dwell = draw_done(lay, st, done, k)
        again = done & (lay.goal_cells[goal] == nxt)  # next goal on this cell: arrived now
        arrived = jnp.where(done, again, at)
        stayed = jnp.where(done, 0, stayed)
        check = (t % replan == 0) | (t == T)
        togo = dist_flat[(li * G + goal) * HW + nxt].astype(jnp.int32)
        if congestion == "moved":  # RHCR's rule: moved, or dwelt at a station
            active = st["active"] | moved | (done & (st["dwell"] > 0)) | (arrived & (dwell > 0))
        else:  # "progress": finished a goal, dwelt, or ended the window closer to its goal
            active = st["active"] | done | (arrived & (dwell > 0)) | (check & (togo < st["togo"]))
        congested = check & (2 * (N - jnp.sum(active)) > N)
        new = dict(
            st,
            t=t,
            pos=nxt,
            goal=goal,
            dwell=dwell,
            arrived=arrived,
            stayed=stayed,
            k=k,
            prio=jnp.where(done, 0, st["prio"] + 1),
            active=jnp.where(check, False, active),
            congested=congested,
            togo=jnp.where(check, togo, st["togo"]),
        )
        new = {key: (jnp.where(running, val, st[key]) if key in _SMALL else val) for key, val in new.items()}
        ti = jnp.where(running, t, st["t"])
        new["tasks"] = st["tasks"].at[ti - 1].add(jnp.where(running, jnp.sum(done), 0))
        new["visits"] = st["visits"].at[nxt].add(running.astype(jnp.int32))
        new["delays"] = st["delays"] + jnp.sum(delayed)
        if record_paths:
            new["paths"] = st["paths"].at[ti].set(nxt)
        return new

    def crowding_one(pos):
        """The agents in the r most crowded k x k blocks, summed (k = DENSITY_K, r = ``rank``)."""
        grid = jnp.zeros(HW, jnp.int32).at[pos].set(1).reshape(H, W)
        cs = jnp.pad(jnp.cumsum(jnp.cumsum(grid, 0), 1), ((1, 0), (1, 0)))
        kk = min(DENSITY_K, H, W)
        block = cs[kk:, kk:] - cs[:-kk, kk:] - cs[kk:, :-kk] + cs[:-kk, :-kk]
        if rank == 1:
            return jnp.max(block).astype(jnp.int32)
        return jnp.sum(lax.top_k(block.reshape(-1), rank)[0]).astype(jnp.int32)

    def record_crowding(st, crowd, check):
        """At a check: record the crowding; the crowding rule may declare congestion."""
        crowd_sum = st["crowd_sum"] + jnp.where(check, crowd, 0)
        n_checked = st["n_checked"] + check.astype(jnp.int32)
        congested = st["congested"]
        if congestion == "crowding":  # RHCR's rule, or crowded on average since the start
            congested = congested | (
                check & (n_checked >= CROWD_MIN_CHECKS) & (crowd_sum >= crowd_mean * rank * n_checked)
            )
        ci = jnp.where(check, (st["t"] - 1) // replan, n_checks)
        return dict(
            st,
            crowd_sum=crowd_sum,
            n_checked=n_checked,
            congested=congested,
            crowd=st["crowd"].at[ci].set(crowd),
        )

    def step(st):
        carry, aux = vmap(prep_one)(st, lidx)

        carry = lax.while_loop(
            lambda c: jnp.any((c[0] < aux["n_roots"]) | (c[1] > 0)), lambda c: vmap(pibt_one)(c, aux), carry
        )
        new = vmap(finish_one)(st, carry[5], lidx)
        # Crowding only at checks (every ``replan`` steps; running runs share their clock):
        # a batch-level cond, not a vmapped select, so the other steps skip it entirely.
        running = ~st["congested"] & (st["t"] < T)
        check = running & ((new["t"] % replan == 0) | (new["t"] == T))
        crowd = lax.cond(
            jnp.any(check), vmap(crowding_one), lambda p: jnp.zeros(p.shape[0], jnp.int32), new["pos"]
        )
        return vmap(record_crowding)(new, crowd, check)

    st = vmap(init_one)(lidx, seeds)
    st = lax.while_loop(lambda s: jnp.any(~s["congested"] & (s["t"] < T)), step, st)
    res = dict(
        stop_time=st["t"],
        congested=st["congested"],
        tasks=st["tasks"],
        visits=st["visits"].reshape(-1, H, W),
        k=st["k"],
        base=st["base"],
        delays=st["delays"],
        crowd=st["crowd"][:, :n_checks],
    )
    if record_paths:
        res["paths"] = st["paths"]
    return res


_SMALL = (
    "t",
    "pos",
    "goal",
    "dwell",
    "arrived",
    "stayed",
    "k",
    "prio",
    "active",
    "congested",
    "togo",
    "crowd_sum",
    "n_checked",
)
_COMPILED: dict = {}
_EXECUTABLES: dict = {}


def _batched(
    n_agents, T, replan, cycle, record_paths, priority, congestion, planner=PLANNER, crowd_mean=CROWD_MEAN
):
    """Jitted: (stacked layouts [L, ...], distances [L, G, HW], layout index [R], seeds [R])
    -> results with leading axis R (one per run)."""
    jax, _ = _jax()
    key = (n_agents, T, replan, cycle, record_paths, priority, congestion, planner, crowd_mean)
    if key not in _COMPILED:

        def run(lay, dist, lidx, seeds):
            if planner == "windowed":
                from nca_qd.sim import screen_windowed

                return screen_windowed.run_batch(
                    lay,
                    dist,
                    lidx,
                    seeds,
                    n_agents=n_agents,
                    T=T,
                    replan=replan,
                    cycle=cycle,
                    record_paths=record_paths,
                )
            return _run_batch(
                lay,
                dist,
                lidx,
                seeds,
                n_agents=n_agents,
                T=T,
                replan=replan,
                cycle=cycle,
                record_paths=record_paths,
                priority=priority,
                congestion=congestion,
                crowd_mean=crowd_mean,
            )

        _COMPILED[key] = jax.jit(run)
    return _COMPILED[key]


def _compiled(fn, *args):
    """Ahead-of-time compiled ``fn`` for these argument shapes (cached)."""
    key = (fn, tuple((a.shape, str(a.dtype)) for a in _leaves(args)))
    if key not in _EXECUTABLES:
        _EXECUTABLES[key] = fn.lower(*args).compile()
    return _EXECUTABLES[key]


def _leaves(tree):
    jax, _ = _jax()
    return jax.tree_util.tree_leaves(tree)


def _distance_fn():
    """Jitted ``[L, H, W], [L, G] -> [L, G, H*W]``: on CPU one layout after another (each
    layout's chunks stay cache-sized, see :func:`distance_table`), elsewhere vmapped."""
    jax, _ = _jax()
    if "dist" not in _COMPILED:
        if _on_cpu():
            _COMPILED["dist"] = jax.jit(lambda t, g: jax.lax.map(lambda x: distance_table(*x), (t, g)))
        else:
            _COMPILED["dist"] = jax.jit(jax.vmap(distance_table))
    return _COMPILED["dist"]


def _distance_tables(traversable, goal_cells, threads: int):
    """A compiled callable () -> ``[L, G, H*W]`` distance tables, the goals split over
    ``threads`` CPU threads (XLA releases the GIL; a table does not depend on the split).
    Compiled here, so that a caller's clock can start after it."""
    _, jnp = _jax()
    L, G = goal_cells.shape
    parts = max(1, min(threads, G // screen_base.DIST_CHUNK)) if _on_cpu() else 1
    size = _round_up(-(-G // parts), screen_base.DIST_CHUNK) if parts > 1 else G
    padded = jnp.pad(goal_cells, ((0, 0), (0, size * parts - G)), constant_values=-1)
    exe = _compiled(_distance_fn(), traversable, padded[:, :size])
    if parts == 1:
        return lambda: exe(traversable, padded)

    def run():
        with ThreadPoolExecutor(max_workers=parts) as pool:
            outs = list(
                pool.map(lambda i: exe(traversable, padded[:, i * size : (i + 1) * size]), range(parts))
            )
        return jnp.concatenate(outs, axis=1)[:, :G]

    return run


def _default_threads() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover
        return os.cpu_count() or 1


def goal_log(lay: LayoutArrays, cycle, base, k_done: np.ndarray) -> list[np.ndarray]:
    """Rebuild each agent's goals (finished ones, then the current one) as (row, col, dwell)."""
    jax, jnp = _jax()
    N = k_done.shape[0]
    W = lay.traversable.shape[1]
    kmax = int(k_done.max()) + 1
    a = jnp.repeat(jnp.arange(N, dtype=jnp.int32), kmax)
    k = jnp.tile(jnp.arange(kmax, dtype=jnp.int32), N)
    phase0 = _hash(base, jnp.arange(N, dtype=jnp.int32), 3) % jnp.uint32(len(cycle))
    phase0 = phase0.astype(jnp.int32)
    lay_j = LayoutArrays(*(jnp.asarray(x) for x in lay))
    gi, dw = _draw_goal(lay_j, cycle, base, a, k, phase0[a])
    cells = np.asarray(lay.goal_cells)[np.asarray(gi)].reshape(N, kmax)
    dw = np.asarray(dw).reshape(N, kmax)
    return [
        np.stack(
            [cells[i, : k_done[i] + 1] // W, cells[i, : k_done[i] + 1] % W, dw[i, : k_done[i] + 1]], axis=1
        ).astype(np.int64)
        for i in range(N)
    ]


# ----------------------------------------------------------------------------- public API
def _congestion(congestion: str | None, planner: str) -> str:
    """The congestion rule asked for, or the planner's default ("moved" for the windowed one)."""
    if congestion is None:
        return "moved" if planner == "windowed" else CONGESTION
    return congestion


def _check(
    n_agents: int,
    T: int,
    replan: int,
    congestion: str | None = None,
    priority: str = PRIORITY,
    planner: str = PLANNER,
    crowd_mean: float = CROWD_MEAN,
) -> None:
    if planner not in ("pibt", "windowed"):
        raise NcaQdError(f"planner must be 'pibt' or 'windowed', got {planner!r}")
    congestion = _congestion(congestion, planner)
    if planner == "windowed" and congestion != "moved":
        raise NcaQdError(
            f"the windowed planner applies RHCR's congestion rule ('moved') only, got {congestion!r}"
        )
    if planner == "windowed" and isinstance(replan, (int, np.integer)) and replan > WINDOW:
        raise NcaQdError(f"the windowed planner replans within its {WINDOW}-step window, got replan={replan}")
    if planner == "windowed" and priority != "random":
        raise NcaQdError(f"the windowed planner draws a random order per call, got priority {priority!r}")
    if priority not in ("random", "age"):
        raise NcaQdError(f"priority must be 'random' or 'age', got {priority!r}")
    _crowd_mean(crowd_mean)
    if congestion not in ("moved", "progress", "crowding"):
        raise NcaQdError(f"congestion rule must be 'moved', 'progress' or 'crowding', got {congestion!r}")
    if isinstance(T, bool) or not isinstance(T, (int, np.integer)) or T <= 0:
        raise NcaQdError(f"horizon T must be a positive integer, got {T!r}")
    if isinstance(n_agents, bool) or not isinstance(n_agents, (int, np.integer)) or n_agents <= 0:
        raise NcaQdError(f"need at least one agent, got {n_agents!r}")
    if n_agents > MAX_AGENTS:  # the random order's a*i + b stays within int32
        raise NcaQdError(f"the screen simulates at most {MAX_AGENTS} agents, got {n_agents}")
    if not isinstance(replan, (int, np.integer)) or replan < 1:
        raise NcaQdError(f"replan (congestion check period h) must be >= 1, got {replan!r}")


def layout_groups(scens: Sequence[Scenario], max_entries: int | None = None) -> list[list[int]]:
    """Consecutive groups of scenario indices whose distance tables (``[L, G, H*W]`` int16,
    G padded to the group's largest goal count) hold at most ``max_entries`` (default
    ``MAX_TABLE``) entries; a layout too large for int32 indexing alone is an error."""
    limit = MAX_TABLE if max_entries is None else max_entries
    groups: list[list[int]] = []
    g_max = 0
    for i, s in enumerate(scens):
        hw = int(np.prod(s.shape))
        g = _round_up(_goal_cells(s).size)
        if g * hw >= 2**31:
            raise NcaQdError(
                f"layout {i} ({s.shape[0]}x{s.shape[1]}, {g} goal cells) is too "
                f"large for the screen's distance table ({g * hw:,} entries)"
            )
        if groups and (len(groups[-1]) + 1) * max(g_max, g) * hw <= limit:
            groups[-1].append(i)
            g_max = max(g_max, g)
        else:
            groups.append([i])
            g_max = g
    return groups


def simulate_scenarios(
    scens: Sequence[Scenario],
    n_agents: int,
    T: int,
    seeds: Sequence[int],
    replan: int = 5,
    record_paths: bool = False,
    priority: str = PRIORITY,
    congestion: str | None = None,
    threads: int | None = None,
    planner: str = PLANNER,
    crowd_mean: float = CROWD_MEAN,
) -> list[list[ScreenResult]]:
    """Simulate every validated scenario (one kind, one shape) with every seed, as vmapped
    batches (split over ``threads`` CPU threads, default: all available CPUs): one batch,
    or consecutive groups of layouts when the distance tables would exceed ``MAX_TABLE``
    entries (30 warehouses of 101x102 need 2.3 G). A run's result does not depend on the
    batch it is in. ``crowd_mean``: the crowding rule's threshold (agents in the most crowded
    ``DENSITY_K`` x ``DENSITY_K`` block, mean over the checks so far). Returns
    ``results[layout][seed]``."""
    _check(n_agents, T, replan, congestion, priority, planner, crowd_mean)
    congestion = _congestion(congestion, planner)
    seeds = [int(s) for s in seeds]
    if not seeds:
        return [[] for _ in scens]
    for s in scens:
        if n_agents > s.n_traversable:
            raise NcaQdError(f"{n_agents} agents but only {s.n_traversable} traversable tiles")
        if any(not np.isfinite(c.weights).all() for c in s.classes):
            raise NcaQdError("goal weights must be finite")
    out: list[list[ScreenResult]] = []
    for group in layout_groups(scens):
        out += _simulate_group(
            [scens[i] for i in group],
            n_agents,
            T,
            seeds,
            replan,
            record_paths,
            priority,
            congestion,
            threads,
            planner,
            float(crowd_mean),
        )
    return out


def _simulate_group(
    scens: Sequence[Scenario],
    n_agents: int,
    T: int,
    seeds: list[int],
    replan: int,
    record_paths: bool,
    priority: str,
    congestion: str,
    threads: int | None,
    planner: str = PLANNER,
    crowd_mean: float = CROWD_MEAN,
) -> list[list[ScreenResult]]:
    """One vmapped batch of validated scenarios (see :func:`simulate_scenarios`)."""
    lay = prepare(scens)
    cycle = tuple(int(c) for c in scens[0].cycle)
    flags = (bool(record_paths), priority, congestion, planner, float(crowd_mean))
    fn = _batched(int(n_agents), int(T), int(replan), cycle, *flags)
    jax, jnp = _jax()
    lay_j = LayoutArrays(*(jnp.asarray(x) for x in lay))
    S = len(seeds)
    runs = len(scens) * S
    lidx = np.repeat(np.arange(len(scens), dtype=np.int32), S)
    seed_r = np.tile(np.array(seeds, dtype=np.int64) % 2**32, len(scens)).astype(np.uint32)
    # Runs are split into equal chunks (the last one padded with repeats), one per thread;
    # XLA releases the GIL, so chunks run in parallel on CPU. Results do not depend on it.
    n_threads = max(1, int(threads or _default_threads()))
    threads = min(n_threads, runs)
    size = -(-runs // threads)
    pad = size * threads - runs
    lidx = np.concatenate([lidx, np.repeat(lidx[-1:], pad)])
    seed_r = np.concatenate([seed_r, np.repeat(seed_r[-1:], pad)])
    tables = _distance_tables(lay_j.traversable, lay_j.goal_cells, n_threads)
    chunks = [
        (jnp.asarray(lidx[i * size : (i + 1) * size]), jnp.asarray(seed_r[i * size : (i + 1) * size]))
        for i in range(threads)
    ]
    L, H, W = lay.traversable.shape
    dist_spec = jax.ShapeDtypeStruct((L, lay.goal_cells.shape[1], H * W), jnp.int16)
    exe = _compiled(fn, lay_j, dist_spec, *chunks[0])  # compiled before the clock starts
    cpu0, wall0 = time.process_time(), time.perf_counter()
    dist = tables()
    if threads == 1:
        parts = [jax.device_get(exe(lay_j, dist, *chunks[0]))]
    else:
        with ThreadPoolExecutor(max_workers=threads) as pool:
            parts = list(pool.map(lambda c: jax.device_get(exe(lay_j, dist, *c)), chunks))
    out = {k: np.concatenate([p[k] for p in parts])[:runs] for k in parts[0]}
    cpu = (time.process_time() - cpu0) / runs
    wall = (time.perf_counter() - wall0) / runs
    results = []
    S = len(seeds)
    for li, scen in enumerate(scens):
        row = []
        one_lay = LayoutArrays(*(x[li] for x in lay))
        for si, seed in enumerate(seeds):
            stop = int(out["stop_time"][li * S + si])
            tasks = np.asarray(out["tasks"][li * S + si]).astype(np.int64)
            finished = int(tasks.sum())
            congested = bool(out["congested"][li * S + si])
            paths = goals = None
            if record_paths:
                W = scen.shape[1]
                flat = np.asarray(out["paths"][li * S + si][: stop + 1])
                paths = np.stack([flat // W, flat % W], axis=-1).astype(np.int32)
                goals = goal_log(one_lay, cycle, out["base"][li * S + si], np.asarray(out["k"][li * S + si]))
            row.append(
                ScreenResult(
                    scenario=scen.name,
                    seed=seed,
                    n_agents=int(n_agents),
                    T=int(T),
                    throughput=finished / T,
                    success=(not congested) and stop == T,
                    congested=congested,
                    stop_time=stop,
                    finished_tasks=finished,
                    tasks_per_step=tasks,
                    tile_visits=np.asarray(out["visits"][li * S + si]).astype(np.int64),
                    cpu_seconds=cpu,
                    wall_seconds=wall,
                    goals=goals,
                    paths=paths,
                    delay_rate=float(out["delays"][li * S + si]) / max(1, stop * n_agents),
                    crowding=np.asarray(out["crowd"][li * S + si]) / crowd_rank(*scen.shape),
                )
            )
        results.append(row)
    return results


def simulate_batch(
    layouts: Sequence[Sequence[str]],
    scenario: str,
    n_agents: int,
    T: int,
    seeds: Sequence[int],
    replan: int = 5,
    record_paths: bool = False,
    priority: str = PRIORITY,
    congestion: str | None = None,
    threads: int | None = None,
    planner: str = PLANNER,
    crowd_mean: float = CROWD_MEAN,
) -> list[list[ScreenResult]]:
    """Validate layouts (rows) and simulate all of them with all seeds in one vmapped batch.

    All layouts must have one shape. Bad input (unknown scenario or tiles, unreachable goals,
    too many agents, bad T) raises :class:`NcaQdError` before anything is compiled.
    """
    _check(n_agents, T, replan, congestion, priority, planner, crowd_mean)
    scens = [
        build_scenario(list(r), scenario, n_agents=n_agents, source=f"layout {i}")
        for i, r in enumerate(layouts)
    ]
    return simulate_scenarios(
        scens, n_agents, T, seeds, replan, record_paths, priority, congestion, threads, planner, crowd_mean
    )


def simulate(
    rows: Sequence[str],
    scenario: str,
    n_agents: int,
    T: int,
    seed: int,
    replan: int = 5,
    record_paths: bool = False,
    priority: str = PRIORITY,
    congestion: str | None = None,
    planner: str = PLANNER,
    crowd_mean: float = CROWD_MEAN,
) -> ScreenResult:
    """One screening run (a batch of one)."""
    return simulate_batch(
        [rows],
        scenario,
        n_agents,
        T,
        [seed],
        replan,
        record_paths,
        priority,
        congestion,
        planner=planner,
        crowd_mean=crowd_mean,
    )[0][0]
