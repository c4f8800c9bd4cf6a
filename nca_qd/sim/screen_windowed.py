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

import functools
import math

from nca_qd.sim.screen_base import DENSITY_K, WINDOW, LayoutArrays, _draw_goal, _hash, _initial_agents, _jax

_MOVES = ((-1, 0), (1, 0), (0, -1), (0, 1))  # up, down, left, right


def _planner(lay_all: LayoutArrays, dist_all, n_agents: int, window: int):
    """``plan_call(pos [N], goal [N], goal2 [N], drem [N], li, order [N], salt) -> (paths
    [N, w+1], stuck [N])``:
    one planning call of one run (vmap it over runs), paths as flat cells, free of vertex and
    swap conflicts within the window; ``stuck``: the agents that found no path and stay."""
    jax, jnp = _jax()
    lax = jax.lax
    L, H, W = lay_all.traversable.shape
    HW = H * W
    G = dist_all.shape[1]
    N = n_agents
    w = int(window)
    P = 2 * w + 1
    dist_flat = dist_all.reshape(-1)
    pi, pj = jnp.meshgrid(jnp.arange(P), jnp.arange(P), indexing="ij")
    lin = (pi * P + pj).astype(jnp.int32)
    times = jnp.arange(w + 1, dtype=jnp.int32)
    q = w + 1  # the reservation table's margin around the map
    Hq, Wq = H + 2 * q, W + 2 * q
    NW = max(-(-Wq // 32), W // 32 + 2)  # uint32 words per table row
    NP = (w + 1) + 4 * w  # planes: vertex at t = 0..w, then (direction, t) for t < w
    bits_idx = jnp.arange(P, dtype=jnp.uint32)
    full = jnp.uint32((1 << P) - 1)
    # Walls (and everything off the map) as reserved bits, per layout: [L, Hq, NW].
    wall = jnp.pad(~lay_all.traversable, ((0, 0), (q, q), (q, NW * 32 - W - q)), constant_values=True)
    wall_bits = jnp.sum(
        jnp.where(
            wall.reshape(L, Hq, NW, 32), jnp.uint32(1) << jnp.arange(32, dtype=jnp.uint32), jnp.uint32(0)
        ),
        axis=-1,
        dtype=jnp.uint32,
    )
    opposite = (1, 0, 3, 2)  # of up, down, left, right

    # ------------------------------------------------------------------ one agent's search
    def bit(row, j):
        return ((row >> j.astype(jnp.uint32)) & jnp.uint32(1)) > 0

    def plan_agent(tab, li, a, pos, goal, goal2, drem, salt):
        """(path [w+1] flat cells, found) for agent ``a`` at ``pos`` against the table ``tab``.

        ``tab`` ``[NP, Hq, NW]`` uint32 holds bit rows of the map (with a margin of w+1): plane
        t <= w the cells reserved at t (walls in every plane), plane w+1 + e*w + t the cells
        whose occupant at t moves in direction e at step t -> t+1. The wavefront runs on the
        patch's bit rows (one uint32 per row): ``R[t]`` the cells reachable at t, ``free[t]``
        the cells not reserved at t, ``blk[d][t]`` the cells y that a move in direction d may
        not enter at step t -> t+1 (y's occupant at t moves the opposite way: a swap).

        Two layers, as RHCR's goal sequence: ``R`` before the current goal is done, ``R2``
        after it (the agent stood on ``goal`` for ``drem`` more steps after arriving, then
        heads for ``goal2``). A path that finishes its goal inside the window is preferred and
        ends nearest ``goal2``; otherwise one that arrives and stands on the goal to the end of
        the window; otherwise the cell at step w nearest ``goal``."""
        r, c = pos // W, pos % W
        x0 = c + 1  # the patch's first column in the table
        word = x0 // 32
        sh = (x0 % 32).astype(jnp.uint32)
        rows = lax.dynamic_slice(tab, (0, r + 1, word), (NP, P, 2))
        hi = jnp.where(sh == 0, jnp.uint32(0), rows[..., 1] << (jnp.uint32(32) - sh))
        win = ((rows[..., 0] >> sh) | hi) & full  # [NP, P]
        free = ~win[: w + 1] & full
        moves = win[w + 1 :].reshape(4, w, P)
        blk = [moves[opposite[d]] for d in range(4)]
        zero = jnp.zeros(1, jnp.uint32)

        def expand(cur, t):
            srcs = (
                jnp.concatenate([cur[1:], zero]),  # up: from the row below
                jnp.concatenate([zero, cur[:-1]]),  # down: from the row above
                cur >> 1,  # left: from the column to the right
                (cur << 1) & full,  # right: from the column to the left
            )
            nxt = cur
            for m in range(4):
                nxt = nxt | (srcs[m] & ~blk[m][t])
            return nxt

        R = [jnp.where(jnp.arange(P) == w, jnp.uint32(1 << w), jnp.uint32(0))]
        for t in range(w):
            R.append(expand(R[-1], t) & free[t + 1])
        Rs = jnp.stack(R)  # [w+1, P]
        gcell = lay_all.goal_cells[li][goal]
        gi, gj = gcell // W - r + w, gcell % W - c + w
        inside = (gi >= 0) & (gi < P) & (gj >= 0) & (gj < P)
        gi, gj = jnp.clip(gi, 0, P - 1), jnp.clip(gj, 0, P - 1)
        g_free = inside & bit(free[:, gi], gj)  # [w+1]
        at_goal = inside & bit(Rs[:, gi], gj)  # on the goal at t, before it is done
        # The goal is done at t when the agent arrived at t - drem and stood there since.
        tau = times - drem
        tau_c = jnp.clip(tau, 0, w)
        gcnt = jnp.concatenate([jnp.zeros(1, jnp.int32), jnp.cumsum(g_free.astype(jnp.int32))])
        stood = gcnt[times + 1] - gcnt[tau_c] == drem + 1
        inj = (times >= 1) & (tau >= 0) & at_goal[tau_c] & stood
        gbit = jnp.where(jnp.arange(P) == gi, jnp.uint32(1) << gj.astype(jnp.uint32), jnp.uint32(0))
        R2 = [jnp.zeros(P, jnp.uint32)]
        for t in range(w):
            R2.append((expand(R2[-1], t) | jnp.where(inj[t + 1], gbit, jnp.uint32(0))) & free[t + 1])
        R2s = jnp.stack(R2)
        done_in = R2s[w].max() > 0
        # Else: arrival at the goal and standing on it to the window's end.
        hold = jnp.flip(lax.cummin(jnp.flip(g_free.astype(jnp.int32)))) > 0  # free from t to w
        arrive = at_goal & hold & (times >= 1)
        has_arr = jnp.any(arrive)
        t_arr = jnp.argmax(arrive).astype(jnp.int32)
        # Else: the reachable cell at step w nearest to the goal. Random ties in both.
        rr = jnp.clip(r - w + pi, 0, H - 1)
        cc = jnp.clip(c - w + pj, 0, W - 1)
        hs = _hash(salt, a, 7)
        odd = (hs | jnp.uint32(1)).astype(jnp.int32) & 0xFFFF
        tie = (lin * odd + (hs >> 16).astype(jnp.int32)) & 1023

        def nearest(layer, g):
            end = ((layer[:, None] >> bits_idx) & jnp.uint32(1)) > 0  # [P, P]
            d = dist_flat[(li * G + g) * HW + rr * W + cc].astype(jnp.int32)
            key = jnp.where(end, d * 1024 + tie, jnp.int32(2**30)).reshape(-1)
            return jnp.argmin(key).astype(jnp.int32)

        best2 = nearest(R2s[w], goal2)
        best1 = nearest(Rs[w], goal)
        found = done_in | has_arr | (Rs[w].max() > 0)
        yi = jnp.where(done_in, best2 // P, jnp.where(has_arr, gi, best1 // P))
        yj = jnp.where(done_in, best2 % P, jnp.where(has_arr, gj, best1 % P))
        l2 = done_in
        # Standing on the goal for s_lo < t <= s_hi (arrived at s_lo).
        s_lo = jnp.where(has_arr & ~done_in, t_arr, jnp.int32(w + 1))
        s_hi = jnp.int32(w)
        # Backtrack: stay where possible (so the agent moves as early as it can).
        pis, pjs = [None] * (w + 1), [None] * (w + 1)
        for t in range(w, 0, -1):
            pis[t], pjs[t] = yi, yj
            ci = jnp.stack([yi] + [yi - dr for dr, _ in _MOVES])
            cj = jnp.stack([yj] + [yj - dc for _, dc in _MOVES])
            ok_c = (ci >= 0) & (ci < P) & (cj >= 0) & (cj < P)
            ci_c, cj_c = jnp.clip(ci, 0, P - 1), jnp.clip(cj, 0, P - 1)
            swap = jnp.stack([jnp.bool_(False)] + [bit(blk[k][t - 1, yi], yj) for k in range(4)])
            valid1 = ok_c & bit(Rs[t - 1, ci_c], cj_c) & ~swap
            valid2 = ok_c & bit(R2s[t - 1, ci_c], cj_c) & ~swap
            # In R2 with no R2 predecessor: here the goal was done; back to R, standing.
            switch = l2 & ~jnp.any(valid2)
            l2 = l2 & ~switch
            s_lo = jnp.where(switch, t - drem, s_lo)
            s_hi = jnp.where(switch, t, s_hi)
            standing = ~l2 & (t > s_lo) & (t <= s_hi)
            k = jnp.argmax(jnp.where(l2, valid2, valid1))
            yi = jnp.where(standing, yi, ci_c[k])
            yj = jnp.where(standing, yj, cj_c[k])
        pis[0], pjs[0] = yi, yj
        path = (r - w + jnp.stack(pis)) * W + (c - w + jnp.stack(pjs))
        return jnp.where(found, path, pos).astype(jnp.int32), found

    def entries(path):
        """The table entries (plane, row, word, bit) of ``path`` [..., w+1]: its cells at
        t = 0..w, then its moves (plane row ``Hq``, out of range, where it waits)."""
        pr, pc = path // W + q, path % W + q
        dr, dc = pr[..., 1:] - pr[..., :-1], pc[..., 1:] - pc[..., :-1]
        e = jnp.where(dr < 0, 0, jnp.where(dr > 0, 1, jnp.where(dc < 0, 2, 3)))
        plane = jnp.concatenate([jnp.broadcast_to(times, path.shape), w + 1 + e * w + times[:-1]], axis=-1)
        row = jnp.concatenate([pr, jnp.where((dr != 0) | (dc != 0), pr[..., :-1], Hq)], axis=-1)
        col = jnp.concatenate([pc, pc[..., :-1]], axis=-1)
        return plane, row, col // 32, jnp.uint32(1) << (col % 32).astype(jnp.uint32)

    def reserve(tab, path):
        """Reserve ``path`` [w+1] (flat cells) in ``tab`` (bits or-ed in)."""
        plane, row, word, b = entries(path)
        old = tab[plane, jnp.minimum(row, Hq - 1), word]
        return tab.at[plane, row, word].set(old | b, mode="drop")

    def empty_table(li):
        return jnp.concatenate(
            [jnp.broadcast_to(wall_bits[li], (w + 1, Hq, NW)), jnp.zeros((4 * w, Hq, NW), jnp.uint32)]
        )

    def conflicts(paths, fixed, pos):
        """Agents (not stuck) whose path crosses a stuck agent's cell within the window."""
        stay = jnp.zeros(HW + 1, bool).at[jnp.where(fixed, pos, HW)].set(True)
        return ~fixed & jnp.any(stay[paths[:, 1:]], axis=1)

    def plan_call(pos, goal, goal2, drem, li, order, salt):
        def body(i, c):
            occ, paths, fixed = c
            a = order[i]
            path, ok = plan_agent(occ, li, a, pos[a], goal[a], goal2[a], drem[a], salt)
            return reserve(occ, path), paths.at[a].set(path), fixed.at[a].set(~ok)

        occ0 = empty_table(li)
        paths0 = jnp.repeat(pos[:, None], w + 1, axis=1)
        occ, paths, fixed = lax.fori_loop(0, N, body, (occ0, paths0, jnp.zeros(N, bool)))

        def repair(c):
            occ, paths, fixed, bad = c
            # Rebuilt from the paths kept: their bits are distinct, so adding them ors them.
            plane, row, word, b = entries(paths)
            row = jnp.where(bad[:, None], Hq, row)
            occ = occ0.at[plane, row, word].add(b, mode="drop")
            todo = bad[order]  # replanned in the call's order
            n_todo = jnp.sum(todo)
            idx = order[jnp.nonzero(todo, size=N, fill_value=0)[0]]

            def again(c2):
                j, occ, paths, fixed = c2
                a = idx[j]
                path, ok = plan_agent(occ, li, a, pos[a], goal[a], goal2[a], drem[a], salt)
                return j + 1, reserve(occ, path), paths.at[a].set(path), fixed.at[a].set(~ok)

            _, occ, paths, fixed = lax.while_loop(lambda c2: c2[0] < n_todo, again, (0, occ, paths, fixed))
            return occ, paths, fixed, conflicts(paths, fixed, pos)

        c = (occ, paths, fixed, conflicts(paths, fixed, pos))
        _, paths, fixed, _ = lax.while_loop(lambda c: jnp.any(c[3]), repair, c)
        return paths, fixed

    return plan_call


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
    lax = jax.lax
    vmap = jax.vmap
    L, H, W = lay_all.traversable.shape
    HW = H * W
    G = dist_all.shape[1]
    N = n_agents
    h = replan
    w = int(window)  # >= h (checked by screen._check)
    agents = jnp.arange(N, dtype=jnp.int32)
    n_rounds = -(-T // h)
    units = jnp.asarray([u for u in range(1, N + 1) if math.gcd(u, N) == 1], jnp.int32)
    dist_flat = dist_all.reshape(-1)
    plan_call = _planner(lay_all, dist_all, N, w)

    def layout(li):
        return LayoutArrays(*(x[li] for x in lay_all))

    def plan_one(st, li):
        """One planning call: a fresh random order (dwelling agents first), then the search."""
        hs = _hash(st["base"], st["t"], 6)
        unit = units[(hs % jnp.uint32(len(units))).astype(jnp.int32)]
        shift = ((hs >> 16) % jnp.uint32(N)).astype(jnp.int32)
        order0 = (unit * agents + shift) % N
        dwelling = st["arrived"] & (st["stayed"] < st["dwell"])
        first = dwelling[order0]
        n_first = jnp.sum(first)
        slot = jnp.where(first, jnp.cumsum(first) - 1, n_first + jnp.cumsum(~first) - 1)
        order = jnp.zeros(N, jnp.int32).at[slot].set(order0)
        goal2, _ = _draw_goal(layout(li), cycle, st["base"], agents, st["k"] + 1, st["phase0"])
        drem = jnp.where(st["arrived"], jnp.maximum(st["dwell"] - st["stayed"], 0), st["dwell"])
        salt = _hash(st["base"], st["t"], 8)
        return plan_call(st["pos"], st["goal"], goal2, drem, li, order, salt)[0]

    # ------------------------------------------------------------------ state and execution
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
            tasking=jnp.zeros(N, bool),
            k=jnp.zeros(N, jnp.int32),
            congested=jnp.bool_(False),
            tasks=jnp.zeros(T + h, jnp.int32),
            visits=jnp.zeros(HW, jnp.int32),
            base=base,
            phase0=phase0,
            delays=jnp.int32(0),
            crowd=jnp.zeros(n_rounds + 1, jnp.int32),
        )
        if record_paths:
            st["paths"] = jnp.zeros((T + h + 1, N), jnp.int32).at[0].set(pos0)
        return st

    def crowding(pos):
        grid = jnp.zeros(HW, jnp.int32).at[pos].set(1).reshape(H, W)
        cs = jnp.pad(jnp.cumsum(jnp.cumsum(grid, 0), 1), ((1, 0), (1, 0)))
        kk = min(DENSITY_K, H, W)
        block = cs[kk:, kk:] - cs[:-kk, kk:] - cs[kk:, :-kk] + cs[:-kk, :-kk]
        return jnp.max(block).astype(jnp.int32)

    def round_one(st, li):
        lay = layout(li)
        running = ~st["congested"] & (st["t"] < T)
        plan = plan_one(st, li)
        steps = jnp.minimum(h, T - st["t"])
        start = st["pos"]

        def step(s, c):
            """Execute step ``s`` (1-based) of the plan: RHCR's goal bookkeeping."""
            x = dict(c)
            live = running & (s <= steps)
            pos = x["pos"]
            nxt = jnp.where(live, plan[:, s], pos)
            gbase = (li * G + x["goal"]) * HW
            dwelling = x["arrived"] & (x["stayed"] < x["dwell"])
            delayed = live & ~dwelling & (dist_flat[gbase + nxt] >= dist_flat[gbase + pos])
            at = nxt == lay.goal_cells[x["goal"]]
            tasking = at & x["arrived"] & (x["dwell"] > 0)
            stayed = jnp.where(at & x["arrived"], x["stayed"] + 1, 0)
            done = at & (stayed >= x["dwell"])
            k = x["k"] + done
            g, dw = _draw_goal(lay, cycle, x["base"], agents, k, x["phase0"])
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
            if record_paths:
                x["paths"] = x["paths"].at[ti].set(nxt, mode="drop")
            return x

        c = dict(st, stuck=~st["tasking"])
        c = lax.fori_loop(1, h + 1, step, c)
        t = st["t"] + jnp.where(running, steps, 0)
        congested = st["congested"] | (running & (2 * jnp.sum(c.pop("stuck")) > N))
        ri = jnp.where(running, st["t"] // h, n_rounds)
        return dict(
            c,
            t=t,
            congested=congested,
            crowd=st["crowd"].at[ri].set(crowding(c["pos"])),
        )

    st = vmap(init_one)(lidx, seeds)
    st = lax.while_loop(
        lambda s: jnp.any(~s["congested"] & (s["t"] < T)), lambda s: vmap(round_one)(s, lidx), st
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


def _pad_to(n: int, step: int) -> int:
    return -(-n // step) * step


@functools.cache
def _plan_window_program(n_agents: int, window: int):
    """One jitted planning call per (agents, window): the layout and its distance table are
    arguments, so that calls on maps padded to the same shape share one compilation."""
    jax, _ = _jax()

    def call(lay, dist, pos, goal, goal2, drem, order, salt):
        return _planner(lay, dist, n_agents, window)(pos, goal, goal2, drem, 0, order, salt)

    return jax.jit(call)


def plan_window(
    traversable, starts, goals, order=None, window: int = WINDOW, seed: int = 0, next_goals=None, dwell=None
):
    """One planning call on its own, for tests and inspection: agents at ``starts`` (row, col)
    with goals ``goals`` (row, col), planned in ``order`` (default: index order); after its goal
    (and ``dwell`` steps standing on it, default 0) each heads for ``next_goals`` (default: the
    same goal). Returns
    (paths ``[N, w+1, 2]`` as (row, col), stuck ``[N]``: the agents that found no path).
    The map is padded with walls to multiples of 32 and the goal list to multiples of 8, so that
    small maps share one compiled program; only random tie-breaks (hashed from cell numbers) can
    differ from an unpadded call."""
    import numpy as np

    jax, jnp = _jax()
    from nca_qd.sim.screen_base import distance_table

    trav0 = np.asarray(traversable, bool)
    trav = np.zeros((_pad_to(trav0.shape[0], 32), _pad_to(trav0.shape[1], 32)), bool)
    trav[: trav0.shape[0], : trav0.shape[1]] = trav0
    H, W = trav.shape
    N = len(starts)
    pos = np.array([r * W + c for r, c in starts], np.int32)
    cells = np.array([r * W + c for r, c in goals], np.int32)
    nxt = np.array([r * W + c for r, c in (goals if next_goals is None else next_goals)], np.int32)
    uniq, inv = np.unique(np.concatenate([cells, nxt]), return_inverse=True)
    uniq = np.concatenate([uniq, np.full(_pad_to(len(uniq), 8) - len(uniq), uniq[-1])])
    goal, goal2 = inv[:N], inv[N:]
    lay = LayoutArrays(
        trav[None],
        uniq[None].astype(np.int32),
        np.zeros((1, 1, 1), np.int32),
        np.zeros((1, 1, 1), np.float32),
        np.ones((1, 1), np.int32),
        np.zeros((1, 1), np.int32),
    )
    lay_j = LayoutArrays(*(jnp.asarray(x) for x in lay))
    dist = distance_table(lay_j.traversable[0], lay_j.goal_cells[0])[None]
    order = np.arange(N, dtype=np.int32) if order is None else np.asarray(order, np.int32)
    drem = jnp.asarray(np.zeros(N) if dwell is None else np.asarray(dwell), jnp.int32)
    g, g2 = jnp.asarray(goal.astype(np.int32)), jnp.asarray(goal2.astype(np.int32))
    program = _plan_window_program(N, int(window))
    paths, stuck = program(lay_j, dist, jnp.asarray(pos), g, g2, drem, jnp.asarray(order), _hash(seed, 9))
    paths = np.asarray(paths)
    return np.stack([paths // W, paths % W], axis=-1), np.asarray(stuck)


__all__ = ["WINDOW", "plan_window", "run_batch"]
