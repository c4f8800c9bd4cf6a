"""Rounding the whole map's LP relaxation: the exact MILP over the cells it leaves fractional.

At 33x36 the LP relaxation of the repair MILP is nearly tight on the searches' layouts: its
bound met the proven optimum on 22 of 24 layouts, and its solution is integral on all but a few
dozen to a few hundred cells. So the integral cells are fixed at the LP's tiles and the
window MILP (:func:`nca_qd.repair.milp.solve_window`) re-solves the fractional ones — a
relaxation-enforced neighbourhood, RENS in the MIP literature. Its solution, when there is
one, is a valid layout and often the optimum itself: then it meets the LP's bound, which proves
it. Otherwise the window grows by one cell, then two, while it is proven infeasible (the fixed
part may cut a region off or miss a tile count) or its layout stays above the bound (each
wider solve warm-started from the best so far).

The work is bounded without a clock: at most ``max_cells`` cells (by default about 30 % of the
map's free cells: the LP of a far-from-valid 33x36 layout leaves hundreds fractional, and one root of
579 cells took over a minute),
``max_nodes`` branch-and-bound nodes and ``max_checks`` of HiGHS's interrupt checks per solve;
so the result does not depend on the machine's load.
"""

from __future__ import annotations

import numpy as np

from nca_qd.layouts.rules import Rules, dilate
from nca_qd.repair.milp import WindowResult, solve_window
from nca_qd.repair.neighbourhood import weighted_distance
from nca_qd.repair.validator import is_valid

# Largest set of fractional cells (widened) re-solved: 320 at 33x36 (1,056 free cells), in
# proportion to the free cells elsewhere (2,999 at 101x102); a larger one is left to the windows.
ROUNDING_CELLS, ROUNDING_FREE_CELLS = 320, 1056
# Branch-and-bound nodes per solve: the sub-MILPs of the searches' layouts that succeed close at
# their root; one of 302 cells without a solution spent 15 s on 200 nodes.
ROUNDING_NODES = 20
# HiGHS's interrupt checks per solve (:func:`nca_qd.repair.milp.solve_window`'s
# ``check_limit``): the root of that 302-cell window ran 13 s within its 20 nodes (7.7 s with
# 100 checks); the roundings that succeed on the searches' layouts need about 10.
ROUNDING_CHECKS = 30


def round_relaxation(
    lp: WindowResult,
    layout_in: np.ndarray,
    rules: Rules,
    *,
    max_cells: int | None = None,
    max_nodes: int = ROUNDING_NODES,
    max_checks: int = ROUNDING_CHECKS,
    time_limit: float = 60.0,
    threads: int = 1,
    seed: int = 0,
) -> tuple[np.ndarray | None, int]:
    """A valid layout that agrees with the fractional LP solution ``lp`` (``lp.layout``: its
    largest tile per cell; ``lp.fractional``: the cells where it is fractional) wherever the LP
    is integral, optimal among those (within ``max_nodes``); None if none was found. Also
    returns the cells of the last window solved (0 when none was)."""
    if lp.fractional is None or lp.layout is None or not lp.fractional.any():
        return None, 0
    free = ~rules.fixed
    if max_cells is None:
        max_cells = int(round(ROUNDING_CELLS * int(free.sum()) / ROUNDING_FREE_CELLS))
    weights = rules.cell_weights(layout_in)
    best: np.ndarray | None = None
    cells = 0
    for radius in (0, 1, 2):
        window = (dilate(lp.fractional, radius) if radius else lp.fractional) & free
        if int(window.sum()) > max_cells:
            break
        cells = int(window.sum())
        res = solve_window(
            lp.layout if best is None else best,
            layout_in,
            window,
            rules,
            time_limit=time_limit,  # a safety net: nodes and cells bound the work
            threads=threads,
            seed=seed,
            warm_start=best is not None,
            max_nodes=max_nodes,
            check_limit=max_checks,
        )
        if res.layout is not None and is_valid(res.layout, rules):
            if best is None or weighted_distance(res.layout, layout_in, weights) < weighted_distance(
                best, layout_in, weights
            ):
                best = res.layout
            if lp.bound is not None and weighted_distance(best, layout_in, weights) <= lp.bound:
                break  # proven optimal
        elif res.status != "infeasible" or best is not None:
            break
    return best, cells
