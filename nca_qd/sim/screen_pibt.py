"""The screen's default planner: every run of a batch stepped by PIBT in lock-step (jittable).

Every timestep each agent takes one step by PIBT (Okumura et al. 2022), run as an explicit
stack in a ``lax.while_loop``. Dwelling agents stay. An agent whose best tile is empty and a
candidate of no other agent takes it (PIBT would give it that tile in any order). The others,
as roots in priority order, claim the best free candidate among {stay, 4 neighbours} ranked by
the true distance to the goal (random ties among moves); if the tile holds an undecided agent,
that agent is pushed (priority inheritance: it must move, not onto its pusher's tile, possibly
away from its goal); a pushed agent that finds no tile stays and its pusher tries its next
candidate. No vertex or swap conflict can occur (rotations of three or more agents can, as the
checker allows). Priority: ``"random"`` draws a fresh agent order every step (a random affine
bijection of the agent indices, no sort), which avoids PIBT's standing deadlocks in cluttered
layouts; ``"age"`` is PIBT's (steps since the last finished goal, fixed random tie-break).

A run stops as congested by RHCR's rule (every ``replan`` steps, more than half of the agents
neither moved nor dwelt) or, with ``congestion="crowding"``, by the crowding rule below.

One batch's kernels share a :class:`Kernel` (the batch's sizes, options and arrays); each
function here is one part of a timestep, written per run and ``jax.vmap``-ed by
:func:`run_batch`, which owns the loops. :mod:`nca_qd.sim.screen` is the public entry.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

from nca_qd.sim.screen_base import DENSITY_K, LayoutArrays, _draw_goal, _hash, _jax, initial_state

# "crowding" congestion (the screen's default): RHCR's rule, or, from the CROWD_MIN_CHECKS-th
# check on, a mean since the start of >= CROWD_MEAN agents in the most crowded DENSITY_K x
# DENSITY_K block at each check -- a proxy for the dense jams in which RHCR's windowed PBS
# collapses and PIBT does not. Calibrated on 41 layouts of benchmarks/bench_screen.py's
# generator with seed 0 (a grid over threshold, first check and window; the running mean beat
# "3 checks in a row >= 20" there and on the held-out seed-1 set); figures use seed 1.
# CROWD_MEAN is the default; a domain whose traffic crowds more where it flows sets its own
# (``crowd_mean``; the domain config's ``simulation.screen_crowd_mean``).
# On a larger map the rule looks at the mean of the r most crowded blocks, r = the map's blocks
# / CROWD_REF_BLOCKS (those of a 33x36 map, where the thresholds were calibrated): the maximum
# over 9x as many blocks is higher at the same density, while a map's r most crowded blocks
# hold what its most crowded 33x36 part would (docs/benchmarks.md, "Crowding that scales with
# the map").
CROWD_REF_BLOCKS = (33 - DENSITY_K + 1) * (36 - DENSITY_K + 1)
CROWD_MEAN = 17.0
CROWD_MIN_CHECKS = 10
DRAW_ROUND = 32  # at least this many new goals are drawn per round (see _draw_done)
ROOT_LOOKAHEAD = 4  # roots looked at per PIBT call for one that no push has decided yet
PREDECIDE = True  # decide the moves PIBT makes in any order before its search (same plan,
# fewer sequential calls); False runs plain PIBT (tests compare the two)

# Per-run state entries that stay as they were once a run has stopped (the larger ones are
# written through masked scatters instead).
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


def crowd_rank(height: int, width: int) -> int:
    """How many of a map's most crowded DENSITY_K x DENSITY_K blocks the crowding rule averages:
    one per CROWD_REF_BLOCKS blocks (a 33x36 map's), rounded: 1 at 33x36, 10 at 101x102."""
    blocks = max(1, height - DENSITY_K + 1) * max(1, width - DENSITY_K + 1)
    return max(1, (blocks + CROWD_REF_BLOCKS // 2) // CROWD_REF_BLOCKS)


class Kernel(NamedTuple):
    """What every kernel of one batch reads: sizes and options (static) and shared arrays."""

    N: int  # agents
    T: int
    replan: int
    cycle: tuple
    record_paths: bool
    priority: str
    congestion: str
    crowd_mean: float
    H: int
    W: int
    G: int  # goal cells (padded)
    n_checks: int
    rank: int  # blocks the crowding rule averages
    n_draw: int  # goals drawn per round in _draw_done
    lay_all: LayoutArrays  # [L, ...]
    dist_flat: Any  # [L * G * H * W] int16 distances
    nbr_all: Any  # [L, HW, 5] candidate cells (stay, up, down, left, right)
    ok_all: Any  # [L, HW, 5] whether each is legal
    agents: Any  # [N] int32 agent indices
    units: Any  # units of Z_N (the random order's multipliers)

    @property
    def HW(self) -> int:
        return self.H * self.W

    def layout(self, li):
        return LayoutArrays(*(x[li] for x in self.lay_all))


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


def _kernel(lay_all, dist_all, *, n_agents, T, replan, cycle, record_paths, priority, congestion, crowd_mean):
    jax, jnp = _jax()
    L, H, W = lay_all.traversable.shape
    N = n_agents
    nbr_all, ok_all = jax.vmap(_neighbours)(lay_all.traversable)
    return Kernel(
        N=N,
        T=T,
        replan=replan,
        cycle=cycle,
        record_paths=record_paths,
        priority=priority,
        congestion=congestion,
        crowd_mean=crowd_mean,
        H=H,
        W=W,
        G=dist_all.shape[1],
        n_checks=-(-T // replan),
        rank=crowd_rank(H, W),
        n_draw=min(N, max(DRAW_ROUND, N // 16)),
        lay_all=lay_all,
        dist_flat=dist_all.reshape(-1),
        nbr_all=nbr_all,
        ok_all=ok_all,
        agents=jnp.arange(N, dtype=jnp.int32),
        units=jnp.asarray([u for u in range(1, N + 1) if math.gcd(u, N) == 1], jnp.int32),
    )


def _init_one(kn: Kernel, li, seed) -> dict:
    """A run's state at t = 0: the planners' shared start, and PIBT's own entries."""
    _, jnp = _jax()
    N = kn.N
    st = initial_state(kn.layout(li), kn.cycle, seed, N, kn.T, kn.T + 1 if kn.record_paths else None)
    goal0 = st["goal"]
    return dict(
        st,
        prio=jnp.zeros(N, jnp.int32),
        active=jnp.zeros(N, bool),
        tiebreak=(_hash(st["base"], kn.agents, 4) & 2047).astype(jnp.int32),
        togo=kn.dist_flat[(li * kn.G + goal0) * kn.HW + st["pos"]].astype(jnp.int32),
        crowd_sum=jnp.int32(0),
        n_checked=jnp.int32(0),
        crowd=jnp.zeros(kn.n_checks + 1, jnp.int32),
    )


def _preferences(kn: Kernel, st: dict, li):
    """Each agent's candidates in preference order (true distance to its goal, random ties
    among moves; a dwelling agent may only stay), whether each is legal, and who stands where."""
    _, jnp = _jax()
    HW, agents = kn.HW, kn.agents
    pos, goal = st["pos"], st["goal"]
    dwelling = st["arrived"] & (st["stayed"] < st["dwell"])
    cand = kn.nbr_all[li, pos]  # [N, 5]
    ok = kn.ok_all[li, pos] & ~(dwelling[:, None] & (jnp.arange(5) > 0))
    d = kn.dist_flat[((li * kn.G + goal) * HW)[:, None] + jnp.minimum(cand, HW - 1)]
    rnd = _hash(st["base"], st["t"], agents[:, None] * 5 + jnp.arange(5), 5) & 7
    rnd = rnd.astype(jnp.int32).at[:, 0].set(0)
    key = jnp.where(ok, d.astype(jnp.int32) * 8 + rnd, jnp.int32(2**26)) * 8 + jnp.arange(5)
    # Preference order without a sort: each candidate's rank among the five (keys unique).
    rank = jnp.sum(key[:, None, :] < key[:, :, None], axis=2)  # [N, 5]
    slot = rank[:, :, None] == jnp.arange(5)  # [N, cand, slot]
    pref = jnp.sum(jnp.where(slot, cand[:, :, None], 0), axis=1)
    pref_ok = jnp.any(slot & ok[:, :, None], axis=1)
    occ = jnp.full(HW + 1, -1, jnp.int32).at[pos].set(agents)
    return cand, ok, pref, pref_ok, occ, dwelling


def _priority_order(kn: Kernel, st: dict):
    """The step's priority order: agent ``order0[i]`` is the i-th highest."""
    _, jnp = _jax()
    N, agents = kn.N, kn.agents
    if kn.priority == "age":  # steps since the last finished goal, then a fixed random tie-break
        okey = (2**18 - jnp.minimum(st["prio"], 2**18 - 1)) * 2**11 + st["tiebreak"]
        return jnp.argsort(okey).astype(jnp.int32)
    # A fresh random order every step without a sort (an argsort of N keys per run and step
    # was among the costliest parts of a step): the affine bijection i -> (a*i + b) mod N with
    # a random unit a of Z_N and a random shift b.
    h = _hash(st["base"], st["t"], 6)
    unit = kn.units[(h % jnp.uint32(len(kn.units))).astype(jnp.int32)]
    shift = ((h >> 16) % jnp.uint32(N)).astype(jnp.int32)
    return (unit * agents + shift) % N


def _prep_one(kn: Kernel, st: dict, li):
    """Candidates in preference order, and the agents decided without search: PIBT's carry
    and what its search reads (see :func:`_pibt_one`)."""
    jax, jnp = _jax()
    N, HW = kn.N, kn.HW
    pos = st["pos"]
    running = ~st["congested"] & (st["t"] < kn.T)
    cand, ok, pref, pref_ok, occ, dwelling = _preferences(kn, st, li)
    order0 = _priority_order(kn, st)
    # Decided before the search: dwelling agents stay; then only what PIBT decides in any
    # order. An agent whose best tile is empty and a candidate of no other agent takes it; so
    # does one whose best tile holds a decided agent that moves away and is a candidate of no
    # one else (PIBT would push that agent, whose own move is decided the same way). Chains of
    # such followers grow one link a round.
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
    pre, target, _ = jax.lax.while_loop(lambda c: c[2], follow, (pre, target, jnp.bool_(True)))
    resv = jnp.zeros(HW + 1, bool).at[jnp.where(pre, target, HW)].set(True)
    # Roots: the undecided agents in priority order (a stable partition of order0).
    n_undecided = jnp.sum(~pre).astype(jnp.int32)
    und = ~pre[order0]
    slot = jnp.where(und, jnp.cumsum(und) - 1, n_undecided + jnp.cumsum(~und) - 1)
    order = jnp.zeros(N, jnp.int32).at[slot].set(order0)
    n_roots = jnp.where(running, n_undecided, 0).astype(jnp.int32)
    # What the search reads about an agent, in one row (one gather per call): its cell, its
    # candidates in preference order (illegal ones -> the sentinel cell HW, which is always
    # reserved) and who stands on each.
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


def _pibt_one(kn: Kernel, c, x):
    """One PIBT action: start the next root, or move the top agent to its next free tile.

    An agent claims its best free candidate; if that tile holds an undecided agent, that agent
    is pushed (it must move and may not take its pusher's tile); a pushed agent that finds no
    tile stays, and its pusher tries its next candidate.

    Each call does what sequential PIBT does between two changes of state, so the plan is the
    same as one candidate and one root per call would give, in fewer calls (about half as many
    on bench_screen's batch): the next root is the first of the next ``ROOT_LOOKAHEAD`` roots
    that no push has decided yet, and the five candidates are checked at once, the first free
    one from the current one on taken (blocked ones are skipped rather than tried one call
    each).

    State per run: ``j`` the next root's index in ``order``, ``sp`` the stack depth, ``a`` and
    ``k`` the top agent and the candidate it is at (kept out of the stack, whose rows hold the
    pushers below it as (agent * 8 + candidate, cell)), ``target`` every agent's decided cell
    (-1: undecided), ``resv`` the cells taken. A call reads a few entries and writes at most one
    per array, so XLA updates them in place: on CPU its cost per run does not grow with N.
    """
    _, jnp = _jax()
    N, HW = kn.N, kn.HW
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
    # (``push & (o < -1)`` is always false: it only orders the read of ``target[o]`` before the
    # write below, which spares XLA two copies of ``target`` per call.)
    write = try_ok | fail | (push & (o < -1))
    # Conditional writes as scatters to an out-of-range index, dropped: no read needed.
    target = target.at[jnp.where(write, a, N)].set(cell, mode="drop")
    resv = resv.at[jnp.where(write, cell, HW + 1)].set(True, mode="drop")
    # A push keeps the pusher (and the candidate it took) on the stack and makes the pushed
    # agent the top; a failed top gives way to its pusher's next candidate.
    stack = stack.at[jnp.where(push, sp - 1, N)].set(jnp.stack([a * 8 + kk, pa]), mode="drop")
    pop = fail & (sp > 1)
    a = jnp.where(push, o, jnp.where(pop, below[0] // 8, a))
    k = jnp.where(push, 0, jnp.where(pop, below[0] % 8 + 1, kk))
    sp = jnp.where(push, sp + 1, jnp.where(success, 0, jnp.where(fail, sp - 1, sp)))
    return j, sp, a, k, stack, target, resv


def _draw_done(kn: Kernel, lay: LayoutArrays, st: dict, done, k):
    """New goals (and dwell times) of the agents that finished one, the others' kept.

    Few agents finish a goal per step, so goals are drawn for up to ``n_draw`` of them at a
    time (their indices compacted), in a loop that runs once on almost every step, rather than
    for all N agents."""
    jax, jnp = _jax()
    N = kn.N

    def body(c):
        goal, dwell, rem = c
        idx = jnp.nonzero(rem, size=kn.n_draw, fill_value=N)[0]
        safe = jnp.minimum(idx, N - 1)
        g, d = _draw_goal(lay, kn.cycle, st["base"], safe, k[safe], st["phase0"][safe])
        return (
            goal.at[idx].set(g, mode="drop"),
            dwell.at[idx].set(d, mode="drop"),
            rem.at[idx].set(False, mode="drop"),
        )

    goal, dwell, _ = jax.lax.while_loop(lambda c: jnp.any(c[2]), body, (st["goal"], st["dwell"], done))
    return goal, dwell


def _finish_one(kn: Kernel, st: dict, target, li) -> dict:
    """Execute the planned step; goal bookkeeping; RHCR's congestion check every replan steps."""
    _, jnp = _jax()
    N, G, HW, replan, dist_flat = kn.N, kn.G, kn.HW, kn.replan, kn.dist_flat
    lay = kn.layout(li)
    running = ~st["congested"] & (st["t"] < kn.T)
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
    goal, dwell = _draw_done(kn, lay, st, done, k)
    again = done & (lay.goal_cells[goal] == nxt)  # next goal on this cell: arrived now
    arrived = jnp.where(done, again, at)
    stayed = jnp.where(done, 0, stayed)
    check = (t % replan == 0) | (t == kn.T)
    togo = dist_flat[(li * G + goal) * HW + nxt].astype(jnp.int32)
    if kn.congestion == "moved":  # RHCR's rule: moved, or dwelt at a station
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
    if kn.record_paths:
        new["paths"] = st["paths"].at[ti].set(nxt)
    return new


def _crowding_one(kn: Kernel, pos):
    """The agents in the r most crowded k x k blocks, summed (k = DENSITY_K, r = ``kn.rank``)."""
    jax, jnp = _jax()
    H, W = kn.H, kn.W
    grid = jnp.zeros(kn.HW, jnp.int32).at[pos].set(1).reshape(H, W)
    cs = jnp.pad(jnp.cumsum(jnp.cumsum(grid, 0), 1), ((1, 0), (1, 0)))
    kk = min(DENSITY_K, H, W)
    block = cs[kk:, kk:] - cs[:-kk, kk:] - cs[kk:, :-kk] + cs[:-kk, :-kk]
    if kn.rank == 1:
        return jnp.max(block).astype(jnp.int32)
    return jnp.sum(jax.lax.top_k(block.reshape(-1), kn.rank)[0]).astype(jnp.int32)


def _record_crowding(kn: Kernel, st: dict, crowd, check) -> dict:
    """At a check: record the crowding; the crowding rule may declare congestion."""
    _, jnp = _jax()
    crowd_sum = st["crowd_sum"] + jnp.where(check, crowd, 0)
    n_checked = st["n_checked"] + check.astype(jnp.int32)
    congested = st["congested"]
    if kn.congestion == "crowding":  # RHCR's rule, or crowded on average since the start
        congested = congested | (
            check & (n_checked >= CROWD_MIN_CHECKS) & (crowd_sum >= kn.crowd_mean * kn.rank * n_checked)
        )
    ci = jnp.where(check, (st["t"] - 1) // kn.replan, kn.n_checks)
    return dict(
        st,
        crowd_sum=crowd_sum,
        n_checked=n_checked,
        congested=congested,
        crowd=st["crowd"].at[ci].set(crowd),
    )


def _step(kn: Kernel, lidx, st: dict) -> dict:
    """One timestep of every run: PIBT's plan, its execution, the crowding at checks."""
    jax, jnp = _jax()
    lax, vmap = jax.lax, jax.vmap
    carry, aux = vmap(lambda s, li: _prep_one(kn, s, li))(st, lidx)
    carry = lax.while_loop(
        lambda c: jnp.any((c[0] < aux["n_roots"]) | (c[1] > 0)),
        lambda c: vmap(lambda ci, xi: _pibt_one(kn, ci, xi))(c, aux),
        carry,
    )
    new = vmap(lambda s, tg, li: _finish_one(kn, s, tg, li))(st, carry[5], lidx)
    # Crowding only at checks (every ``replan`` steps; running runs share their clock): a
    # batch-level cond, not a vmapped select, so the other steps skip it entirely.
    running = ~st["congested"] & (st["t"] < kn.T)
    check = running & ((new["t"] % kn.replan == 0) | (new["t"] == kn.T))
    crowd = lax.cond(
        jnp.any(check),
        vmap(lambda p: _crowding_one(kn, p)),
        lambda p: jnp.zeros(p.shape[0], jnp.int32),
        new["pos"],
    )
    return vmap(lambda s, c, ch: _record_crowding(kn, s, c, ch))(new, crowd, check)


def run_batch(
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

    Written per run and ``jax.vmap``-ed, except that the loops (time, and PIBT's stack inside a
    timestep) run over the whole batch with a batch-wide condition, and a finished run's body
    is a no-op; this avoids the per-iteration selects over the carry that a vmapped
    ``while_loop`` would do. ``dist_all`` is ``[L, G, H*W]``.
    """
    jax, jnp = _jax()
    kn = _kernel(
        lay_all,
        dist_all,
        n_agents=n_agents,
        T=T,
        replan=replan,
        cycle=cycle,
        record_paths=record_paths,
        priority=priority,
        congestion=congestion,
        crowd_mean=crowd_mean,
    )
    st = jax.vmap(lambda li, s: _init_one(kn, li, s))(lidx, seeds)
    st = jax.lax.while_loop(
        lambda s: jnp.any(~s["congested"] & (s["t"] < T)), lambda s: _step(kn, lidx, s), st
    )
    res = dict(
        stop_time=st["t"],
        congested=st["congested"],
        tasks=st["tasks"],
        visits=st["visits"].reshape(-1, kn.H, kn.W),
        k=st["k"],
        base=st["base"],
        delays=st["delays"],
        crowd=st["crowd"][:, : kn.n_checks],
    )
    if record_paths:
        res["paths"] = st["paths"]
    return res
