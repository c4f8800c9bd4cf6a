"""One planning call of the screen's windowed planner (:mod:`nca_qd.sim.screen_windowed`).

Every agent, in the call's order, searches the (2w+1)^2 patch around it by a bit-row wavefront
against a reservation table of the paths planned before it (vertex and swap conflicts barred
within the window), through its goal and on to the next one; agents whose path crosses a stuck
agent then replan. :func:`plan_window` runs one call on its own, for tests and inspection.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

from nca_qd.sim.screen_base import WINDOW, LayoutArrays, _hash, _jax

_MOVES = ((-1, 0), (1, 0), (0, -1), (0, 1))  # up, down, left, right


class _Planner(NamedTuple):
    """What one batch's planning calls share: sizes, the bit-row reservation table's geometry
    and each layout's walls as reserved bits."""

    lay_all: LayoutArrays
    dist_flat: Any  # [L * G * H * W]
    H: int
    W: int
    G: int
    N: int
    w: int  # the window
    q: int  # the reservation table's margin around the map
    Hq: int
    NW: int  # uint32 words per table row
    NP: int  # planes: vertex at t = 0..w, then (direction, t) for t < w
    wall_bits: Any  # [L, Hq, NW]
    pi: Any  # [P, P] patch row / column indices
    pj: Any

    @property
    def P(self) -> int:  # the patch's side
        return 2 * self.w + 1

    @property
    def HW(self) -> int:
        return self.H * self.W


_OPPOSITE = (1, 0, 3, 2)  # of up, down, left, right


def _planner(lay_all: LayoutArrays, dist_all, n_agents: int, window: int):
    """``plan_call(pos [N], goal [N], goal2 [N], drem [N], li, order [N], salt) -> (paths
    [N, w+1], stuck [N])``:
    one planning call of one run (vmap it over runs), paths as flat cells, free of vertex and
    swap conflicts within the window; ``stuck``: the agents that found no path and stay."""
    _, jnp = _jax()
    L, H, W = lay_all.traversable.shape
    w = int(window)
    P = 2 * w + 1
    q = w + 1
    Hq, Wq = H + 2 * q, W + 2 * q
    NW = max(-(-Wq // 32), W // 32 + 2)
    pi, pj = jnp.meshgrid(jnp.arange(P), jnp.arange(P), indexing="ij")
    # Walls (and everything off the map) as reserved bits, per layout: [L, Hq, NW].
    wall = jnp.pad(~lay_all.traversable, ((0, 0), (q, q), (q, NW * 32 - W - q)), constant_values=True)
    wall_bits = jnp.sum(
        jnp.where(
            wall.reshape(L, Hq, NW, 32), jnp.uint32(1) << jnp.arange(32, dtype=jnp.uint32), jnp.uint32(0)
        ),
        axis=-1,
        dtype=jnp.uint32,
    )
    pl = _Planner(
        lay_all=lay_all,
        dist_flat=dist_all.reshape(-1),
        H=H,
        W=W,
        G=dist_all.shape[1],
        N=n_agents,
        w=w,
        q=q,
        Hq=Hq,
        NW=NW,
        NP=(w + 1) + 4 * w,
        wall_bits=wall_bits,
        pi=pi,
        pj=pj,
    )
    return functools.partial(_plan_call, pl)


def _bit(row, j):
    _, jnp = _jax()
    return ((row >> j.astype(jnp.uint32)) & jnp.uint32(1)) > 0


def _patch(pl: _Planner, tab, pos):
    """The agent's patch of ``tab``: its row and column, the cells free at each t ``[w+1, P]``
    and, per direction d, the cells a move in d may not enter at step t -> t+1 ``[w, P]``."""
    jax, jnp = _jax()
    w, P = pl.w, pl.P
    full = jnp.uint32((1 << P) - 1)
    r, c = pos // pl.W, pos % pl.W
    x0 = c + 1  # the patch's first column in the table
    word = x0 // 32
    sh = (x0 % 32).astype(jnp.uint32)
    rows = jax.lax.dynamic_slice(tab, (0, r + 1, word), (pl.NP, P, 2))
    hi = jnp.where(sh == 0, jnp.uint32(0), rows[..., 1] << (jnp.uint32(32) - sh))
    win = ((rows[..., 0] >> sh) | hi) & full  # [NP, P]
    free = ~win[: w + 1] & full
    moves = win[w + 1 :].reshape(4, w, P)
    return r, c, free, [moves[_OPPOSITE[d]] for d in range(4)]


def _expand(pl: _Planner, blk, cur, t):
    """The cells one step from ``cur`` (a bit-row layer) at step t -> t+1, swaps barred."""
    _, jnp = _jax()
    full = jnp.uint32((1 << pl.P) - 1)
    zero = jnp.zeros(1, jnp.uint32)
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


def _reach(pl: _Planner, free, blk, gi, gj, inside, drem):
    """The two wavefront layers ``[w+1, P]``: ``Rs`` reachable before the goal is done, ``R2s``
    after it (arrived, then stood on it ``drem`` more steps); and whether the goal cell is free
    and reached at each t."""
    _, jnp = _jax()
    w, P = pl.w, pl.P
    times = jnp.arange(w + 1, dtype=jnp.int32)
    R = [jnp.where(jnp.arange(P) == w, jnp.uint32(1 << w), jnp.uint32(0))]
    for t in range(w):
        R.append(_expand(pl, blk, R[-1], t) & free[t + 1])
    Rs = jnp.stack(R)
    g_free = inside & _bit(free[:, gi], gj)  # [w+1]
    at_goal = inside & _bit(Rs[:, gi], gj)  # on the goal at t, before it is done
    # The goal is done at t when the agent arrived at t - drem and stood there since.
    tau = times - drem
    tau_c = jnp.clip(tau, 0, w)
    gcnt = jnp.concatenate([jnp.zeros(1, jnp.int32), jnp.cumsum(g_free.astype(jnp.int32))])
    stood = gcnt[times + 1] - gcnt[tau_c] == drem + 1
    inj = (times >= 1) & (tau >= 0) & at_goal[tau_c] & stood
    gbit = jnp.where(jnp.arange(P) == gi, jnp.uint32(1) << gj.astype(jnp.uint32), jnp.uint32(0))
    R2 = [jnp.zeros(P, jnp.uint32)]
    for t in range(w):
        R2.append((_expand(pl, blk, R2[-1], t) | jnp.where(inj[t + 1], gbit, jnp.uint32(0))) & free[t + 1])
    return Rs, jnp.stack(R2), g_free, at_goal


def _nearest(pl: _Planner, layer, g, li, r, c, tie):
    """The patch cell of ``layer`` nearest to goal ``g`` (true distance, random ties)."""
    _, jnp = _jax()
    w, W = pl.w, pl.W
    rr = jnp.clip(r - w + pl.pi, 0, pl.H - 1)
    cc = jnp.clip(c - w + pl.pj, 0, W - 1)
    end = ((layer[:, None] >> jnp.arange(pl.P, dtype=jnp.uint32)) & jnp.uint32(1)) > 0  # [P, P]
    d = pl.dist_flat[(li * pl.G + g) * pl.HW + rr * W + cc].astype(jnp.int32)
    key = jnp.where(end, d * 1024 + tie, jnp.int32(2**30)).reshape(-1)
    return jnp.argmin(key).astype(jnp.int32)


def _backtrack(pl: _Planner, Rs, R2s, blk, yi, yj, l2, s_lo, drem):
    """The path's patch cells ``(rows, cols)`` at t = 0..w, back from its end ``(yi, yj)``,
    staying where possible (so the agent moves as early as it can); ``l2``: the end is in the
    after-the-goal layer; standing on the goal for s_lo < t <= s_hi."""
    _, jnp = _jax()
    w, P = pl.w, pl.P
    s_hi = jnp.int32(w)
    pis, pjs = [None] * (w + 1), [None] * (w + 1)
    for t in range(w, 0, -1):
        pis[t], pjs[t] = yi, yj
        ci = jnp.stack([yi] + [yi - dr for dr, _ in _MOVES])
        cj = jnp.stack([yj] + [yj - dc for _, dc in _MOVES])
        ok_c = (ci >= 0) & (ci < P) & (cj >= 0) & (cj < P)
        ci_c, cj_c = jnp.clip(ci, 0, P - 1), jnp.clip(cj, 0, P - 1)
        swap = jnp.stack([jnp.bool_(False)] + [_bit(blk[k][t - 1, yi], yj) for k in range(4)])
        valid1 = ok_c & _bit(Rs[t - 1, ci_c], cj_c) & ~swap
        valid2 = ok_c & _bit(R2s[t - 1, ci_c], cj_c) & ~swap
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
    return jnp.stack(pis), jnp.stack(pjs)


def _plan_agent(pl: _Planner, tab, li, a, pos, goal, goal2, drem, salt):
    """(path [w+1] flat cells, found) for agent ``a`` at ``pos`` against the table ``tab``.

    ``tab`` ``[NP, Hq, NW]`` uint32 holds bit rows of the map (with a margin of w+1): plane
    t <= w the cells reserved at t (walls in every plane), plane w+1 + e*w + t the cells whose
    occupant at t moves in direction e at step t -> t+1. The wavefront runs on the patch's bit
    rows (one uint32 per row): ``R[t]`` the cells reachable at t, ``free[t]`` the cells not
    reserved at t, ``blk[d][t]`` the cells y that a move in direction d may not enter at step
    t -> t+1 (y's occupant at t moves the opposite way: a swap).

    Two layers, as RHCR's goal sequence: ``R`` before the current goal is done, ``R2`` after it
    (the agent stood on ``goal`` for ``drem`` more steps after arriving, then heads for
    ``goal2``). A path that finishes its goal inside the window is preferred and ends nearest
    ``goal2``; otherwise one that arrives and stands on the goal to the end of the window;
    otherwise the cell at step w nearest ``goal``."""
    jax, jnp = _jax()
    w, P, W = pl.w, pl.P, pl.W
    times = jnp.arange(w + 1, dtype=jnp.int32)
    r, c, free, blk = _patch(pl, tab, pos)
    gcell = pl.lay_all.goal_cells[li][goal]
    gi, gj = gcell // W - r + w, gcell % W - c + w
    inside = (gi >= 0) & (gi < P) & (gj >= 0) & (gj < P)
    gi, gj = jnp.clip(gi, 0, P - 1), jnp.clip(gj, 0, P - 1)
    Rs, R2s, g_free, at_goal = _reach(pl, free, blk, gi, gj, inside, drem)
    done_in = R2s[w].max() > 0
    # Else: arrival at the goal and standing on it to the window's end.
    hold = jnp.flip(jax.lax.cummin(jnp.flip(g_free.astype(jnp.int32)))) > 0  # free from t to w
    arrive = at_goal & hold & (times >= 1)
    has_arr = jnp.any(arrive)
    t_arr = jnp.argmax(arrive).astype(jnp.int32)
    # Else: the reachable cell at step w nearest to the goal. Random ties in both.
    hs = _hash(salt, a, 7)
    odd = (hs | jnp.uint32(1)).astype(jnp.int32) & 0xFFFF
    lin = (pl.pi * P + pl.pj).astype(jnp.int32)
    tie = (lin * odd + (hs >> 16).astype(jnp.int32)) & 1023
    best2 = _nearest(pl, R2s[w], goal2, li, r, c, tie)
    best1 = _nearest(pl, Rs[w], goal, li, r, c, tie)
    found = done_in | has_arr | (Rs[w].max() > 0)
    yi = jnp.where(done_in, best2 // P, jnp.where(has_arr, gi, best1 // P))
    yj = jnp.where(done_in, best2 % P, jnp.where(has_arr, gj, best1 % P))
    # Standing on the goal for s_lo < t <= s_hi (arrived at s_lo).
    s_lo = jnp.where(has_arr & ~done_in, t_arr, jnp.int32(w + 1))
    pis, pjs = _backtrack(pl, Rs, R2s, blk, yi, yj, done_in, s_lo, drem)
    path = (r - w + pis) * W + (c - w + pjs)
    return jnp.where(found, path, pos).astype(jnp.int32), found


def _entries(pl: _Planner, path):
    """The table entries (plane, row, word, bit) of ``path`` [..., w+1]: its cells at t = 0..w,
    then its moves (plane row ``Hq``, out of range, where it waits)."""
    _, jnp = _jax()
    w, q, W = pl.w, pl.q, pl.W
    times = jnp.arange(w + 1, dtype=jnp.int32)
    pr, pc = path // W + q, path % W + q
    dr, dc = pr[..., 1:] - pr[..., :-1], pc[..., 1:] - pc[..., :-1]
    e = jnp.where(dr < 0, 0, jnp.where(dr > 0, 1, jnp.where(dc < 0, 2, 3)))
    plane = jnp.concatenate([jnp.broadcast_to(times, path.shape), w + 1 + e * w + times[:-1]], axis=-1)
    row = jnp.concatenate([pr, jnp.where((dr != 0) | (dc != 0), pr[..., :-1], pl.Hq)], axis=-1)
    col = jnp.concatenate([pc, pc[..., :-1]], axis=-1)
    return plane, row, col // 32, jnp.uint32(1) << (col % 32).astype(jnp.uint32)


def _reserve(pl: _Planner, tab, path):
    """Reserve ``path`` [w+1] (flat cells) in ``tab`` (bits or-ed in)."""
    _, jnp = _jax()
    plane, row, word, b = _entries(pl, path)
    old = tab[plane, jnp.minimum(row, pl.Hq - 1), word]
    return tab.at[plane, row, word].set(old | b, mode="drop")


def _empty_table(pl: _Planner, li):
    _, jnp = _jax()
    w = pl.w
    return jnp.concatenate(
        [
            jnp.broadcast_to(pl.wall_bits[li], (w + 1, pl.Hq, pl.NW)),
            jnp.zeros((4 * w, pl.Hq, pl.NW), jnp.uint32),
        ]
    )


def _conflicts(pl: _Planner, paths, fixed, pos):
    """Agents (not stuck) whose path crosses a stuck agent's cell within the window."""
    _, jnp = _jax()
    stay = jnp.zeros(pl.HW + 1, bool).at[jnp.where(fixed, pos, pl.HW)].set(True)
    return ~fixed & jnp.any(stay[paths[:, 1:]], axis=1)


def _plan_call(pl: _Planner, pos, goal, goal2, drem, li, order, salt):
    """One planning call of one run: every agent in ``order`` against those before it; then,
    until none is left, the agents whose path crosses a stuck agent replan (in that order)."""
    jax, jnp = _jax()
    lax = jax.lax
    N, w = pl.N, pl.w

    def body(i, c):
        occ, paths, fixed = c
        a = order[i]
        path, ok = _plan_agent(pl, occ, li, a, pos[a], goal[a], goal2[a], drem[a], salt)
        return _reserve(pl, occ, path), paths.at[a].set(path), fixed.at[a].set(~ok)

    occ0 = _empty_table(pl, li)
    paths0 = jnp.repeat(pos[:, None], w + 1, axis=1)
    occ, paths, fixed = lax.fori_loop(0, N, body, (occ0, paths0, jnp.zeros(N, bool)))

    def repair(c):
        occ, paths, fixed, bad = c
        # Rebuilt from the paths kept: their bits are distinct, so adding them ors them.
        plane, row, word, b = _entries(pl, paths)
        row = jnp.where(bad[:, None], pl.Hq, row)
        occ = occ0.at[plane, row, word].add(b, mode="drop")
        todo = bad[order]  # replanned in the call's order
        n_todo = jnp.sum(todo)
        idx = order[jnp.nonzero(todo, size=N, fill_value=0)[0]]

        def again(c2):
            j, occ, paths, fixed = c2
            a = idx[j]
            path, ok = _plan_agent(pl, occ, li, a, pos[a], goal[a], goal2[a], drem[a], salt)
            return j + 1, _reserve(pl, occ, path), paths.at[a].set(path), fixed.at[a].set(~ok)

        _, occ, paths, fixed = lax.while_loop(lambda c2: c2[0] < n_todo, again, (0, occ, paths, fixed))
        return occ, paths, fixed, _conflicts(pl, paths, fixed, pos)

    c = (occ, paths, fixed, _conflicts(pl, paths, fixed, pos))
    _, paths, fixed, _ = lax.while_loop(lambda c: jnp.any(c[3]), repair, c)
    return paths, fixed


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


__all__ = ["plan_window"]
