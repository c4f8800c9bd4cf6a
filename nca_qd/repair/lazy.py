"""Connectivity checked, not imposed: the repair MILP relaxed to its tile, adjacency and count
rules (no connectivity flow), its LP solved and rounded exactly, the result kept when it is
connected anyway (``connectivity: lazy``).

Why: the flow carries the model's bulk (a continuous variable per directed edge and its big-M
rows) and adds nothing to the LP bound on the layouts measured, where it costs the time. At
101x102 the whole-map LP of a manufacturing layout takes 127 s with the flow and 5-8 s without,
to the same bound (cell 4616: 1,166), and on manufacturing's open floor the rules alone rarely
wall a region off: rounded exactly (the MILP over the cells the LP leaves fractional, the
integral ones fixed: RENS), its layouts were connected and within 0.7-0.9 % of that bound
(docs/benchmarks.md). The relaxation's optimum is a lower bound of the repair's, so the LP bound
proves the gap either way. Where the rounded layout is not connected (a warehouse's pockets
walled in by shelves) it is discarded, and the caller falls back to the flow model.

The work is bounded without a clock (simplex iterations, branch-and-bound nodes), so the result
does not depend on the machine's load; the time limit is a safety net only.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import highspy
import numpy as np

from nca_qd.layouts.rules import Rules, dilate
from nca_qd.repair.milp import _layout_of, _options, distance_bound, window_model
from nca_qd.repair.validator import is_valid

# Simplex iterations of the rules-only LP (101x102 manufacturing: 12,900).
LAZY_LP_ITERATIONS = 200_000
# Branch-and-bound nodes of its rounding (101x102 manufacturing: optimal after 21-34).
LAZY_ROUNDING_NODES = 100


@dataclass
class LazyResult:
    """``layout``: a valid layout (None when the rounding found none or it is not connected);
    ``bound``: the rules-only LP's proven bound on the repair's distance (None when the LP did
    not finish); ``status``: what happened (``connected``, ``not_connected``, ``no_rounding``,
    ``lp_limit``); the seconds of the LP and of the rounding; fractional cells of the LP."""

    status: str
    layout: np.ndarray | None
    bound: float | None
    lp_s: float
    rounding_s: float
    fractional: int


def lazy_repair(
    layout_in: np.ndarray,
    rules: Rules,
    *,
    time_limit: float = 110.0,
    threads: int = 1,
    seed: int = 0,
    iteration_limit: int = LAZY_LP_ITERATIONS,
    max_nodes: int = LAZY_ROUNDING_NODES,
) -> LazyResult:
    """The rules-only LP over every free cell, its exact rounding, and the validator's verdict
    (module docstring)."""
    t0 = time.perf_counter()
    model = window_model(layout_in, layout_in, ~rules.fixed, rules, connectivity=False)
    if model is None:
        return LazyResult("lp_limit", None, None, time.perf_counter() - t0, 0.0, 0)
    hs, g, integrality = model
    # the window solver's limits, but HiGHS's own (dual) simplex: there is no valid layout to
    # start a primal simplex from, as the flow's relaxation does
    _options(hs, time_limit, threads, seed, None, None, False, iteration_limit, "simplex")
    hs.setOptionValue("solve_relaxation", True)
    hs.run()
    lp_s = time.perf_counter() - t0
    if hs.getModelStatus() != highspy.HighsModelStatus.kOptimal:
        return LazyResult("lp_limit", None, None, lp_s, 0.0, 0)
    ties = rules.tie_costs is not None
    bound = distance_bound(hs.getInfo().objective_function_value, ties)
    values = np.asarray(hs.getSolution().col_value)
    integral = np.abs(values - np.round(values)) < 1e-6
    n_frac = int((~integral[: g.n_x].reshape(g.n, g.K)).any(axis=1).sum())
    t1 = time.perf_counter()
    if n_frac:
        # RENS: the cells the LP left integral fixed at their tiles, the MILP over the rest;
        # when that has no solution (the fixed part leaves the others no valid choice), the
        # cells next to them are freed too, then those two steps away (as :mod:`.rounding`)
        hs.setOptionValue("solve_relaxation", False)
        hs.setOptionValue("mip_max_nodes", int(max_nodes))
        hs.changeColsIntegrality(g.n_x, np.arange(g.n_x, dtype=np.int32), integrality[: g.n_x])
        frac_cells = np.zeros(rules.shape, dtype=bool)
        for i in np.flatnonzero((~integral[: g.n_x].reshape(g.n, g.K)).any(axis=1)):
            frac_cells[g.cells[i]] = True
        lp_values = np.round(values)
        found = False
        for radius in (0, 1, 2):
            free_cells = dilate(frac_cells, radius) if radius else frac_cells
            free_cols = np.repeat([free_cells[r, c] for r, c in g.cells], g.K)
            hs.changeColsBounds(
                g.n_x,
                np.arange(g.n_x, dtype=np.int32),
                np.where(free_cols, 0.0, lp_values[: g.n_x]),
                np.where(free_cols, 1.0, lp_values[: g.n_x]),
            )
            hs.setOptionValue("time_limit", max(0.05, float(time_limit) - (time.perf_counter() - t0)))
            hs.run()
            if hs.getInfo().primal_solution_status == 2:  # kSolutionStatusFeasible
                found = True
                break
            if hs.getModelStatus() != highspy.HighsModelStatus.kInfeasible:
                break  # out of nodes or time without a solution: wider would only be harder
        if not found:
            return LazyResult("no_rounding", None, bound, lp_s, time.perf_counter() - t1, n_frac)
        values = np.asarray(hs.getSolution().col_value)
    layout, _ = _layout_of(values, layout_in, g.cells, layout_in, rules, g.n_x, g.K)
    rounding_s = time.perf_counter() - t1
    if not is_valid(layout, rules):
        return LazyResult("not_connected", None, bound, lp_s, rounding_s, n_frac)
    return LazyResult("connected", layout, bound, lp_s, rounding_s, n_frac)
