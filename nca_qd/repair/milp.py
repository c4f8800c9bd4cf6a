"""The exact repair MILP over a window of cells, the rest of the layout held fixed (HiGHS).

Variables (paper, after Zhang et al. 2023): a binary ``x[c, t]`` per window cell ``c`` and tile
``t`` with one tile per cell; the objective is the weighted Hamming distance to the unrepaired
layout. Connectivity is a single-commodity flow: continuous ``f_ij <= N`` on directed edges,
``in_i + supply_i = demand_i + out_i`` with demand 1 on every passable node, and no flow leaves
or enters a blocking cell (``f_ij <= N * passable_i`` and ``<= N * passable_j``).

Window = the whole free area gives the paper's monolithic model (``method=full``). For a
smaller window, the fixed passable cells outside are contracted into one node per connected
outside component (connected through outside cells only); such a node always demands flow and
links to the window cells it touches. The layout is connected iff the contracted graph is, so
the window model is exact *for the window*: any solution it returns makes the whole layout
valid (given valid cells outside the window's reach), and it finds the best layout among those
that differ from the current one only inside the window. With at least one outside node, the
first one is the flow source; with none (full manufacturing map), a binary ``y_c`` chooses the
source cell (``sum y = 1``, ``y_c <= passable_c``) so no valid layout is excluded.
"""

from __future__ import annotations

import os
import sys
import time
from collections import deque
from dataclasses import dataclass

import highspy
import numpy as np
from scipy import ndimage

from nca_qd.layouts.rules import Rules, neighbours

_BANNER_SILENCED = False


def quiet_highs() -> highspy.Highs:
    """A silent HiGHS instance. HiGHS prints its banner to the C-level stdout when a process
    constructs its first instance, before any option can be set: that first construction runs
    with file descriptor 1 on /dev/null, so run logs do not repeat it once per worker."""
    global _BANNER_SILENCED
    if _BANNER_SILENCED:
        hs = highspy.Highs()
    else:
        sys.stdout.flush()
        saved = os.dup(1)
        try:
            with open(os.devnull, "w") as null:
                os.dup2(null.fileno(), 1)
                hs = highspy.Highs()
        finally:
            os.dup2(saved, 1)
            os.close(saved)
        _BANNER_SILENCED = True
    hs.setOptionValue("output_flag", False)
    return hs


_FOUR = ndimage.generate_binary_structure(2, 1)


@dataclass
class WindowResult:
    """Outcome of one window solve.

    status: ``optimal`` (proven for the window), ``feasible`` (a solution, not proven optimal, at
        the time limit), ``infeasible`` (proven: no valid layout differs only in the window),
        ``timeout`` (no solution in time).
    layout: the full layout with the window re-solved (None unless optimal/feasible).
    objective: weighted Hamming distance inside the window (None without a solution).
    bound: proven lower bound on that distance (HiGHS's dual bound, less any tie costs, rounded
        up to the integer distances); None when the solver proved nothing.
    nodes: branch-and-bound nodes HiGHS explored.
    fractional: (LP relaxation, status ``fractional``) bool ``[h, w]``, the window cells whose
        tile is fractional in the LP's solution.
    iterations: (LP relaxation) simplex iterations, the LP's work.
    """

    status: str
    layout: np.ndarray | None
    objective: float | None
    seconds: float
    n_cells: int
    bound: float | None = None
    nodes: int = 0
    fractional: np.ndarray | None = None
    iterations: int = 0


class _Rows:
    """Row-wise sparse constraint matrix accumulated in Python lists (CSR at the end)."""

    def __init__(self) -> None:
        self.lower: list[float] = []
        self.upper: list[float] = []
        self.starts: list[int] = []
        self.index: list[int] = []
        self.value: list[float] = []

    def add(self, cols: list[int], vals: list[float], lo: float, hi: float) -> None:
        self.starts.append(len(self.index))
        self.index.extend(cols)
        self.value.extend(vals)
        self.lower.append(lo)
        self.upper.append(hi)


@dataclass
class _Graph:
    """A window's MILP layout: its cells, the flow graph contracted over the outside
    traversable components (super nodes), and where each block of columns starts."""

    cells: list[tuple[int, int]]
    cid: np.ndarray  # [h, w] window cell index, -1 outside
    free: list[int]  # the tiles a window cell may take (column k of a cell is free[k])
    pass_k: list[int]  # the passable ones among them
    touched: list[int]  # labels of the outside components the window touches
    edges: list[tuple[int, int]]  # directed edges between cells and super nodes
    n_nodes: int

    @property
    def n(self) -> int:
        return len(self.cells)

    @property
    def K(self) -> int:
        return len(self.free)

    @property
    def big_n(self) -> float:
        return float(self.n_nodes)

    @property
    def use_source_vars(self) -> bool:  # no outside component: the source is chosen in the window
        return not self.touched

    @property
    def source(self) -> int | None:  # the first outside component
        return None if self.use_source_vars else self.n

    @property
    def n_x(self) -> int:
        return self.n * self.K

    @property
    def f0(self) -> int:
        return self.n_x

    @property
    def y0(self) -> int:
        return self.f0 + len(self.edges)

    @property
    def s0(self) -> int:
        return self.y0 + (self.n if self.use_source_vars else 0)

    @property
    def n_cols(self) -> int:
        return self.s0 + (self.n if self.use_source_vars else 0)

    def xcol(self, i: int, k: int) -> int:
        return i * self.K + k


def _window_graph(current: np.ndarray, window: np.ndarray, rules: Rules) -> _Graph | None:
    """The window's graph, or None when an outside traversable region cannot be reached from
    the window (no repair inside the window can connect it)."""
    h, w = current.shape
    cells = [tuple(map(int, rc)) for rc in np.argwhere(window)]
    n = len(cells)
    cid = -np.ones((h, w), dtype=np.int64)
    for i, (r, c) in enumerate(cells):
        cid[r, c] = i
    free = list(rules.free_tiles)
    pass_k = [k for k, t in enumerate(free) if t in rules.passable]
    # Outside passable components -> super nodes.
    outside_pass = rules.passable_mask(current) & ~window
    labels, n_lab = ndimage.label(outside_pass, structure=_FOUR)
    touches: list[set[int]] = [set() for _ in range(n)]
    for i, (r, c) in enumerate(cells):
        for rr, cc in neighbours(r, c, h, w):
            if labels[rr, cc] > 0:
                touches[i].add(int(labels[rr, cc]))
    touched = sorted(set().union(*touches)) if n else []
    if n_lab > len(touched):
        return None
    super_of = {lab: n + s for s, lab in enumerate(touched)}
    # Directed edges of the contracted graph.
    edges: list[tuple[int, int]] = []
    for i, (r, c) in enumerate(cells):
        for rr, cc in neighbours(r, c, h, w):
            j = cid[rr, cc]
            if j >= 0:
                edges.append((i, int(j)))
        for lab in sorted(touches[i]):
            s = super_of[lab]
            edges.append((i, s))
            edges.append((s, i))
    return _Graph(cells, cid, free, pass_k, touched, edges, n + len(touched))


def _columns(g: _Graph, layout_in: np.ndarray, rules: Rules):
    """Objective (weighted Hamming distance to ``layout_in``, as an offset minus the kept
    cells' weights), bounds and integrality of every column."""
    k_of = {t: k for k, t in enumerate(g.free)}
    weights = rules.objective_weights(layout_in)
    cost = np.zeros(g.n_cols)
    offset = 0.0
    for i, (r, c) in enumerate(g.cells):
        wgt = float(weights[r, c])
        offset += wgt
        k = k_of.get(int(layout_in[r, c]))
        if k is not None:
            cost[g.xcol(i, k)] = -wgt
    lower = np.zeros(g.n_cols)
    upper = np.ones(g.n_cols)
    upper[g.f0 : g.f0 + len(g.edges)] = g.big_n
    integrality = np.zeros(g.n_cols, dtype=np.int32)
    integrality[: g.n_x] = 1
    if g.use_source_vars:
        upper[g.s0 : g.s0 + g.n] = g.big_n
        integrality[g.y0 : g.y0 + g.n] = 1
    return cost, lower, upper, integrality, offset


def _tile_and_flow_rows(g: _Graph, rows: _Rows) -> None:
    """One tile per cell; a single-commodity flow from the source reaching every passable
    cell and every outside component (connectivity)."""
    inf = highspy.kHighsInf
    n, K, big_n, pass_k, xcol = g.n, g.K, g.big_n, g.pass_k, g.xcol
    for i in range(n):
        rows.add([xcol(i, k) for k in range(K)], [1.0] * K, 1.0, 1.0)
    # Flow capacities: nothing leaves or enters a blocking window cell.
    for e, (a, b) in enumerate(g.edges):
        for node in (a, b):
            if node < n:
                rows.add(
                    [g.f0 + e] + [xcol(node, k) for k in pass_k], [1.0] + [-big_n] * len(pass_k), -inf, 0.0
                )
    # Conservation: in - out (+ supply) = demand.
    inc: list[list[int]] = [[] for _ in range(g.n_nodes)]
    out: list[list[int]] = [[] for _ in range(g.n_nodes)]
    for e, (a, b) in enumerate(g.edges):
        out[a].append(g.f0 + e)
        inc[b].append(g.f0 + e)
    for v in range(g.n_nodes):
        if v == g.source:
            continue
        cols = inc[v] + out[v]
        vals = [1.0] * len(inc[v]) + [-1.0] * len(out[v])
        if v < n:
            cols = cols + [xcol(v, k) for k in pass_k]
            vals = vals + [-1.0] * len(pass_k)
            if g.use_source_vars:
                cols.append(g.s0 + v)
                vals.append(1.0)
            rows.add(cols, vals, 0.0, 0.0)
        else:
            rows.add(cols, vals, 1.0, 1.0)
    if g.use_source_vars:
        y0, s0 = g.y0, g.s0
        rows.add([y0 + i for i in range(n)], [1.0] * n, 1.0, 1.0)
        for i in range(n):
            rows.add([s0 + i, y0 + i], [1.0, -big_n], -inf, 0.0)
            rows.add([y0 + i] + [xcol(i, k) for k in pass_k], [1.0] + [-1.0] * len(pass_k), -inf, 0.0)
        all_pass = [xcol(i, k) for i in range(n) for k in pass_k]
        rows.add([s0 + i for i in range(n)] + all_pass, [1.0] * n + [-1.0] * len(all_pass), 0.0, 0.0)


def _rule_rows(g: _Graph, current: np.ndarray, window: np.ndarray, rules: Rules, rows: _Rows) -> None:
    """The domain's adjacency rules on the window's cells and the fixed cells around them, and
    its count rules (the window makes up what the fixed part lacks)."""
    inf = highspy.kHighsInf
    h, w = current.shape
    ring = np.zeros((h, w), dtype=bool)
    ring[1:, :] |= window[:-1, :]
    ring[:-1, :] |= window[1:, :]
    ring[:, 1:] |= window[:, :-1]
    ring[:, :-1] |= window[:, 1:]
    ring &= ~window
    check_cells = g.cells + [tuple(map(int, rc)) for rc in np.argwhere(ring)]
    for rule in rules.adjacency:
        a_k = [k for k, t in enumerate(g.free) if t in rule.tiles]
        b_k = [k for k, t in enumerate(g.free) if t in rule.needs]
        for r, c in check_cells:
            i = g.cid[r, c]
            cols: list[int] = []
            vals: list[float] = []
            if i >= 0:
                cols += [g.xcol(int(i), k) for k in a_k]
                vals += [1.0] * len(a_k)
                a_const = 0.0
            else:
                if int(current[r, c]) not in rule.tiles:
                    continue
                a_const = 1.0
            b_const = 0.0
            for rr, cc in neighbours(r, c, h, w):
                j = g.cid[rr, cc]
                if j >= 0:
                    cols += [g.xcol(int(j), k) for k in b_k]
                    vals += [-1.0] * len(b_k)
                elif int(current[rr, cc]) in rule.needs:
                    b_const += 1.0
            if not cols:
                continue
            rows.add(cols, vals, -inf, b_const - a_const)
    for rule in rules.counts:
        outside = int((np.isin(current, list(rule.tiles)) & ~window).sum())
        t_k = [k for k, t in enumerate(g.free) if t in rule.tiles]
        cols = [g.xcol(i, k) for i in range(g.n) for k in t_k]
        need = float(rule.value - outside)
        hi = need if rule.op == "==" else inf
        rows.add(cols, [1.0] * len(cols), need, hi)


def _options(
    hs, time_limit, threads, seed, max_nodes, check_limit, relaxation, iteration_limit, lp_solver
) -> None:
    """HiGHS's limits (work limits where set) and what a solve proves."""
    hs.setOptionValue("time_limit", max(0.05, float(time_limit)))
    hs.setOptionValue("threads", int(threads))
    hs.setOptionValue("random_seed", int(seed))
    if max_nodes is not None:
        hs.setOptionValue("mip_max_nodes", int(max_nodes))
    if check_limit is not None:
        _stop_after_checks(hs, int(check_limit))
    hs.setOptionValue("mip_rel_gap", 0.0)
    # Integer weights: a gap below 1 proves optimality.
    hs.setOptionValue("mip_abs_gap", 0.999)
    if relaxation:
        hs.setOptionValue("solve_relaxation", True)
        hs.setOptionValue("simplex_strategy", 4)  # primal: it starts from the valid layout
        if lp_solver == "ipm":  # interior point, then crossover to a vertex (rounding wants one)
            hs.setOptionValue("solver", "ipm")
            hs.setOptionValue("run_crossover", "on")
    if iteration_limit is not None:
        hs.setOptionValue("simplex_iteration_limit", int(iteration_limit))


def _load(hs, columns, rows: _Rows) -> None:
    """Columns (objective, bounds, integrality) and rows into ``hs``."""
    cost, lower, upper, integrality, offset = columns
    n_cols = len(cost)
    hs.addCols(
        n_cols,
        cost,
        lower,
        upper,
        0,
        np.array([], dtype=np.int32),
        np.array([], dtype=np.int32),
        np.array([], dtype=np.float64),
    )
    hs.changeColsIntegrality(n_cols, np.arange(n_cols, dtype=np.int32), integrality)
    hs.addRows(
        len(rows.lower),
        np.array(rows.lower),
        np.array(rows.upper),
        len(rows.index),
        np.array(rows.starts, dtype=np.int32),
        np.array(rows.index, dtype=np.int32),
        np.array(rows.value, dtype=np.float64),
    )
    hs.changeObjectiveOffset(offset)


def window_model(
    current: np.ndarray, layout_in: np.ndarray, window: np.ndarray, rules: Rules, *, connectivity: bool = True
) -> tuple[highspy.Highs, _Graph, np.ndarray] | None:
    """The window's model loaded into a silent HiGHS (no options set), its graph and the
    integrality of its columns; None for an empty window or an outside region it cannot reach.

    ``connectivity=False`` leaves out the flow (its columns and rows): the tiles, the domain's
    adjacency and count rules only. Its optimum bounds the repair's distance from below, and a
    caller may impose connectivity another way (``benchmarks/repair_bounds.py`` adds separator
    cuts: what bounds a stronger formulation than the flow could prove)."""
    window = window & ~rules.fixed
    g = _window_graph(current, window, rules) if window.any() else None
    if g is None:
        return None
    columns = _columns(g, layout_in, rules)
    rows = _Rows()
    if connectivity:
        _tile_and_flow_rows(g, rows)
    else:
        columns = (*(a[: g.n_x] for a in columns[:4]), columns[4])
        for i in range(g.n):
            rows.add([g.xcol(i, k) for k in range(g.K)], [1.0] * g.K, 1.0, 1.0)
    _rule_rows(g, current, window, rules, rows)
    hs = quiet_highs()
    _load(hs, columns, rows)
    return hs, g, columns[3]


def solve_window(
    current: np.ndarray,
    layout_in: np.ndarray,
    window: np.ndarray,
    rules: Rules,
    *,
    time_limit: float = 60.0,
    threads: int = 1,
    seed: int = 0,
    warm_start: bool = True,
    max_nodes: int | None = None,
    relaxation: bool = False,
    iteration_limit: int | None = None,
    check_limit: int | None = None,
    lp_solver: str = "simplex",
) -> WindowResult:
    """Best layout that equals ``current`` outside ``window`` (bool ``[h, w]``) and satisfies ``rules``.

    ``warm_start`` passes ``current`` (with a flow routed along a BFS tree) as the incumbent; the
    caller sets it only when ``current`` is valid. ``max_nodes`` caps HiGHS's branch-and-bound
    nodes: a work limit, unlike ``time_limit``, gives the same answer on a loaded machine.

    ``relaxation`` solves the LP relaxation only, by primal simplex from ``current`` (about 0.2 s
    at 33x36 from a valid start, against seconds for the MIP's own root): its optimum bounds
    the distance, and when it is integral it is the MIP's optimum (``optimal``; otherwise
    ``fractional`` with the bound, and as ``layout`` the LP's largest tile per cell, which need
    not be valid). ``iteration_limit`` caps its simplex
    iterations (a work limit: ``timeout`` when reached). ``lp_solver="ipm"`` solves it by
    interior point with crossover instead (at 101x102 it was slower: docs/benchmarks.md).

    ``check_limit`` stops the MIP after that many of HiGHS's interrupt checks (its callbacks
    between the LPs of the root's cut rounds and between nodes): a work limit where the node
    count is none, at the root, whose cut rounds took 13 s on a 302-cell window with no
    solution in sight. The checks come at the same points of the same search on every
    machine, so the result does not depend on the load.
    """
    t0 = time.perf_counter()
    window = window & ~rules.fixed
    model = window_model(current, layout_in, window, rules)
    if model is None:  # an empty window, or an outside region the window cannot reach
        return WindowResult("infeasible", None, None, time.perf_counter() - t0, int(window.sum()))
    hs, g, integrality = model
    n = g.n
    _options(hs, time_limit, threads, seed, max_nodes, check_limit, relaxation, iteration_limit, lp_solver)
    n_x, K = g.n_x, g.K
    if warm_start:
        start = _warm_start(
            current,
            g.cells,
            g.cid,
            g.edges,
            n,
            g.n_nodes,
            g.source,
            g.free,
            rules,
            K,
            g.n_cols,
            g.f0,
            g.y0,
            g.s0,
        )
        if start is not None:
            sol = highspy.HighsSolution()
            sol.col_value = list(start)
            hs.setSolution(sol)
    hs.run()
    status = hs.getModelStatus()
    info = hs.getInfo()
    seconds = time.perf_counter() - t0
    has_solution = info.primal_solution_status == 2  # kSolutionStatusFeasible
    if relaxation:
        return _relaxed(hs, status, current, g.cells, layout_in, rules, n_x, K, integrality, t0)
    bound = distance_bound(info.mip_dual_bound, rules.tie_costs is not None)
    nodes = int(info.mip_node_count)
    if status == highspy.HighsModelStatus.kInfeasible:
        return WindowResult("infeasible", None, None, seconds, n, None, nodes)
    if not has_solution:
        return WindowResult("timeout", None, None, seconds, n, bound, nodes)
    values = np.asarray(hs.getSolution().col_value)
    new, distance = _layout_of(values, current, g.cells, layout_in, rules, n_x, K)
    label = "optimal" if status == highspy.HighsModelStatus.kOptimal else "feasible"
    return WindowResult(label, new, distance, seconds, n, bound, nodes)


def _stop_after_checks(hs: highspy.Highs, limit: int) -> None:
    """Interrupt the MIP at its ``limit``-th interrupt check."""
    checks = [0]

    def on_check(event, *_):
        checks[0] += 1
        if checks[0] >= limit:
            event.user_interrupt = True

    hs.cbMipInterrupt.subscribe(on_check)


def _layout_of(values, current, cells, layout_in, rules, n_x, K) -> tuple[np.ndarray, float]:
    """``current`` with each window cell set to its largest tile column in ``values``, and the
    window's weighted Hamming distance to ``layout_in`` (the solver's objective less any tie
    costs)."""
    x = values[:n_x].reshape(len(cells), K)
    new = current.copy()
    free = rules.free_tiles
    for i, (r, c) in enumerate(cells):
        new[r, c] = free[int(np.argmax(x[i]))]
    p = rules.cell_weights(layout_in)
    return new, float(sum(p[r, c] for r, c in cells if new[r, c] != layout_in[r, c]))


def _relaxed(hs, status, current, cells, layout_in, rules, n_x, K, integrality, t0) -> WindowResult:
    """The LP relaxation's outcome: its bound, and its solution when every integer column is
    integral there (then no integer solution is better)."""
    n = len(cells)
    seconds = time.perf_counter() - t0
    its = int(hs.getInfo().simplex_iteration_count)
    if status == highspy.HighsModelStatus.kInfeasible:
        return WindowResult("infeasible", None, None, seconds, n, iterations=its)
    if status != highspy.HighsModelStatus.kOptimal:
        return WindowResult("timeout", None, None, seconds, n, iterations=its)
    bound = distance_bound(hs.getInfo().objective_function_value, rules.tie_costs is not None)
    values = np.asarray(hs.getSolution().col_value)
    ints = values[integrality.astype(bool)]
    new, distance = _layout_of(values, current, cells, layout_in, rules, n_x, K)
    if np.abs(ints - np.round(ints)).max(initial=0.0) > 1e-6:
        # not a layout: the LP's largest tile per cell, where the next search should look
        x = values[:n_x].reshape(n, K)
        frac = np.zeros(current.shape, dtype=bool)
        for i in np.flatnonzero(np.abs(x - np.round(x)).max(axis=1) > 1e-6):
            frac[cells[i]] = True
        return WindowResult("fractional", new, None, seconds, n, bound, fractional=frac, iterations=its)
    return WindowResult("optimal", new, distance, seconds, n, distance, iterations=its)


def distance_bound(dual_bound: float, tie_costs: bool) -> float | None:
    """The least integer weighted distance HiGHS's dual bound allows. With tie costs (summing
    to less than 1) the objective is distance + ties, so distance > dual bound - 1."""
    if not np.isfinite(dual_bound):
        return None
    if tie_costs:
        return float(max(0.0, np.ceil(dual_bound - 1.0 + 1e-9)))
    return float(max(0.0, np.ceil(dual_bound - 1e-6)))


def _warm_start(current, cells, cid, edges, n, n_nodes, source, free, rules, K, n_cols, f0, y0, s0):
    """Column values of ``current`` with flows along a BFS tree from the source (None if unroutable)."""
    k_of = {t: k for k, t in enumerate(free)}
    vals = np.zeros(n_cols)
    passable = np.zeros(n_nodes, dtype=bool)
    passable[n:] = True
    for i, (r, c) in enumerate(cells):
        k = k_of.get(int(current[r, c]))
        if k is None:
            return None
        vals[i * K + k] = 1.0
        passable[i] = int(current[r, c]) in rules.passable
    if source is None:
        cand = np.flatnonzero(passable[:n])
        if len(cand) == 0:
            return None
        src = int(cand[0])
    else:
        src = source
    adj: list[list[tuple[int, int]]] = [[] for _ in range(n_nodes)]
    for e, (a, b) in enumerate(edges):
        adj[a].append((b, e))
    parent_edge = -np.ones(n_nodes, dtype=np.int64)
    seen = np.zeros(n_nodes, dtype=bool)
    seen[src] = True
    order = [src]
    queue = deque([src])
    while queue:
        a = queue.popleft()
        for b, e in adj[a]:
            if not seen[b] and passable[b]:
                seen[b] = True
                parent_edge[b] = e
                order.append(b)
                queue.append(b)
    if not np.all(seen[passable]):
        return None
    sub = passable.astype(float)
    for v in reversed(order[1:]):
        e = int(parent_edge[v])
        vals[f0 + e] = sub[v]
        sub[edges[e][0]] += sub[v]
    if source is None:
        vals[y0 + src] = 1.0
        vals[s0 + src] = float(passable[:n].sum())
    return vals
