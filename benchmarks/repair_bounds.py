"""Lower bounds on a repair's distance beside the one HiGHS proves (issue 54: a far-from-valid
33x36 layout's repair stays 21-37 % above the bound; is the bound or the layout to blame?).

Both bounds relax the repair MILP of :mod:`nca_qd.repair.milp` (the whole free area as one
window) in a different way from its LP relaxation:

- :func:`without_connectivity`: the MILP with the domain's tile, adjacency and count rules but no
  connectivity at all. Its optimum is a valid lower bound; it shows how much of the distance the
  connectivity requirement costs.
- :func:`separator_lp`: the LP relaxation with connectivity imposed by vertex-separator cuts
  instead of the single-commodity flow and its big-M capacities. For a passable cell ``v`` and a
  set ``S`` of window cells that separates ``v`` from the fixed passable cells (every path
  between them crosses ``S``), ``sum_{u in S} passable_u >= passable_v`` holds for every valid
  layout. Each round solves the LP and, for every cell with a positive passable value, finds a
  minimum separator by max-flow on the node-split grid (capacities = the LP's passable values)
  and adds the cut nearest the fixed cells and the one nearest the cell when the flow falls short;
  it stops when no cut is violated. Its bound is the LP bound of the strongest formulation of
  connectivity by node cuts (the connected-subgraph polytope's separator inequalities): if it
  stays near the flow's LP bound, no reformulation of connectivity closes the gap, and the gap
  is the problem's integrality gap.

Used by ``python -m benchmarks.bench_repair --probe CELLS`` (docs/benchmarks.md, "Repair").
"""

from __future__ import annotations

import time

import highspy
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order, maximum_flow

from nca_qd.layouts.rules import Rules
from nca_qd.repair.milp import _options, distance_bound, window_model

_SCALE = 10_000  # max-flow capacities are integers: passable values in units of 1e-4
_BIG = 2**30


def without_connectivity(
    current: np.ndarray, layout_in: np.ndarray, rules: Rules, time_limit: float = 300.0
) -> tuple[str, float | None, float | None, float]:
    """The repair MILP without connectivity over the whole free area: status, optimum, bound,
    seconds (its optimum bounds the repair's distance from below)."""
    t0 = time.perf_counter()
    model = window_model(current, layout_in, ~rules.fixed, rules, connectivity=False)
    assert model is not None
    hs, _, _ = model
    _options(hs, time_limit, 1, 0, None, None, False, None, "simplex")  # the window solver's
    hs.run()
    info = hs.getInfo()
    ties = rules.tie_costs is not None
    optimal = hs.getModelStatus() == highspy.HighsModelStatus.kOptimal
    obj = distance_bound(info.objective_function_value, ties) if info.primal_solution_status == 2 else None
    bound = distance_bound(info.mip_dual_bound, ties)
    return ("optimal" if optimal else "limit"), obj, bound, time.perf_counter() - t0


def _split_grid(window: np.ndarray, fixed_pass: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Edges of the node-split grid over the cells that can be passable: cell ``v`` is ``v``
    (in) and ``N + v`` (out), an edge ``v -> N + v`` carries the cell's capacity, neighbours are
    joined ``N + u -> v`` without limit, and a root ``2N`` feeds every fixed passable cell."""
    h, w = window.shape
    n = h * w
    can = window | fixed_pass
    idx = np.arange(n).reshape(h, w)
    src, dst = [], []
    for dr, dc in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        a = (slice(max(0, -dr), h - max(0, dr)), slice(max(0, -dc), w - max(0, dc)))
        b = (slice(max(0, dr), h - max(0, -dr)), slice(max(0, dc), w - max(0, -dc)))
        both = can[a] & can[b]
        src.append(n + idx[a][both])
        dst.append(idx[b][both])
    fp = idx[fixed_pass]
    src.append(np.full(fp.size, 2 * n))
    dst.append(fp)
    return np.concatenate(src), np.concatenate(dst), n


def separator_lp(
    current: np.ndarray, layout_in: np.ndarray, rules: Rules, max_rounds: int = 100
) -> tuple[float | None, int, int, float]:
    """The LP bound with connectivity as separator cuts (module docstring): bound, rounds, cuts
    added, seconds. Needs fixed passable cells (the warehouses' workstation columns); the bound
    is None without any."""
    t0 = time.perf_counter()
    window = ~rules.fixed
    fixed_pass = rules.passable_mask(current) & rules.fixed
    if not fixed_pass.any():
        return None, 0, 0, time.perf_counter() - t0
    model = window_model(current, layout_in, window, rules, connectivity=False)
    assert model is not None
    hs, g, _ = model
    hs.changeColsIntegrality(g.n_x, np.arange(g.n_x, dtype=np.int32), np.zeros(g.n_x, dtype=np.int32))
    hs.setOptionValue("threads", 1)
    src, dst, n = _split_grid(window, fixed_pass)
    h, w = window.shape
    rounds = cuts = 0
    obj = float("nan")
    for rounds in range(1, max_rounds + 1):
        hs.run()
        if hs.getModelStatus() != highspy.HighsModelStatus.kOptimal:
            return None, rounds, cuts, time.perf_counter() - t0
        obj = hs.getInfo().objective_function_value
        x = np.asarray(hs.getSolution().col_value)[: g.n_x].reshape(g.n, g.K)
        p = np.zeros(h * w)
        p[fixed_pass.ravel()] = 1.0
        for i, (r, c) in enumerate(g.cells):
            p[r * w + c] = x[i, g.pass_k].sum()
        split = np.round(p * _SCALE).astype(np.int64)
        split[fixed_pass.ravel()] = _BIG
        caps = np.concatenate([split, np.full(src.size, _BIG, dtype=np.int64)]).astype(np.int32)
        graph = sp.csr_matrix(
            (caps, (np.concatenate([np.arange(n), src]), np.concatenate([np.arange(n) + n, dst]))),
            shape=(2 * n + 1, 2 * n + 1),
        )
        graph.sum_duplicates()
        added = 0
        for i, (r, c) in enumerate(g.cells):
            v = r * w + c
            if p[v] <= 1e-3:
                continue
            res = maximum_flow(graph, 2 * n, v)
            if res.flow_value >= p[v] * _SCALE - 5:
                continue
            residual = (graph - res.flow).tocsr()
            residual.data[residual.data < 0] = 0
            residual.eliminate_zeros()
            near_root = np.zeros(2 * n + 1, dtype=bool)
            near_root[breadth_first_order(residual, 2 * n, directed=True, return_predecessors=False)] = True
            near_cell = np.zeros(2 * n + 1, dtype=bool)
            back = residual.T.tocsr()
            near_cell[breadth_first_order(back, v, directed=True, return_predecessors=False)] = True
            for sep in (
                np.flatnonzero(near_root[:n] & ~near_root[n : 2 * n]),
                np.flatnonzero(near_cell[n : 2 * n] & ~near_cell[:n]),
            ):
                cells = [int(g.cid[divmod(int(u), w)]) for u in sep[sep != v]]
                assert min(cells, default=0) >= 0, "a separator holds a fixed cell"
                cols = [g.xcol(j, k) for j in cells for k in g.pass_k]
                cols += [g.xcol(i, k) for k in g.pass_k]
                vals = [1.0] * (len(cols) - len(g.pass_k)) + [-1.0] * len(g.pass_k)
                hs.addRow(0.0, highspy.kHighsInf, len(cols), np.array(cols, dtype=np.int32), np.array(vals))
                added += 1
        cuts += added
        if added == 0:
            break
    return distance_bound(obj, rules.tie_costs is not None), rounds, cuts, time.perf_counter() - t0
