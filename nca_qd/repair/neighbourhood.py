"""Scalable repair: exact MILPs over small windows instead of one MILP over the whole map.

1. *Greedy construction* (:mod:`nca_qd.repair.heuristic`): valid by construction.
2. *Violation neighbourhood*, for inputs with at most ``max_violation_fraction`` violating cells:
   the cells of local violations (an endpoint without a shelf, a cut-off pocket, ...) dilated by
   r = 1, 2, 4, ... cells are re-solved by the window MILP
   (:func:`nca_qd.repair.milp.solve_window`) with the rest of the unrepaired layout fixed,
   widening while the window is proven infeasible (a window smaller than the tile-count gap is
   skipped unsolved) and no larger than ``max_window_cells``; kept if better than (1).
3. *Large-neighbourhood improvement.* Square windows centred on cells that still differ from
   the unrepaired layout are re-solved exactly, warm-started with the current layout, and kept
   when they lower the distance, until every differing cell has been in a window that found no
   improvement, or the improvement budget is spent.

Every layout returned is valid (each window MILP is exact for its window and the greedy is valid
by construction); what is given up is the proof of global optimality. The result is reported
``optimal`` only when its distance meets a count-based lower bound (or the input was valid).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from nca_qd.layouts.rules import Rules, dilate
from nca_qd.repair.milp import solve_window
from nca_qd.repair.validator import is_valid, violation_mask

Heuristic = Callable[[np.ndarray], "np.ndarray | None"]


@dataclass
class SearchOutcome:
    """Layout (None if nothing valid was found), status and how it was reached."""

    status: str
    layout: np.ndarray | None
    objective: float | None
    stages: dict[str, float] = field(default_factory=dict)


def weighted_distance(a: np.ndarray, b: np.ndarray, weights: np.ndarray) -> float:
    return float((weights * (a != b)).sum())


def lower_bound(layout_in: np.ndarray, rules: Rules) -> float:
    """A cheap lower bound on the distance: each changed cell moves each tile count by at most 1."""
    best = 0
    for rule in rules.counts:
        n = int(np.isin(layout_in, list(rule.tiles)).sum())
        gap = abs(n - rule.value) if rule.op == "==" else max(0, rule.value - n)
        best = max(best, gap)
    return float(best)


def _square(shape: tuple[int, int], r: int, c: int, side: int) -> np.ndarray:
    h, w = shape
    r0 = min(max(0, r - side // 2), max(0, h - side))
    c0 = min(max(0, c - side // 2), max(0, w - side))
    box = np.zeros(shape, dtype=bool)
    box[r0 : r0 + side, c0 : c0 + side] = True
    return box


# Branch-and-bound nodes per improvement window under a window budget (``improve_windows``).
WINDOW_NODES = 200
# Largest violation window solved under a window budget (cells).
WORK_WINDOW_CELLS = 256


def repair_neighbourhood(
    layout_in: np.ndarray,
    rules: Rules,
    heuristic: Heuristic,
    *,
    time_limit: float = 60.0,
    improve_time: float = 30.0,
    improve_windows: int | None = None,
    window: int = 8,
    window_time: float = 2.0,
    max_window_cells: int = 1200,
    max_violation_fraction: float = 0.25,
    threads: int = 1,
    seed: int = 0,
) -> SearchOutcome:
    """Valid layout near ``layout_in`` by windows + greedy + window improvement (module docstring).

    The improvement phase stops after ``improve_time`` seconds, or — when ``improve_windows`` is
    given — after that many window solves of at most ``WINDOW_NODES`` branch-and-bound nodes
    each, with ``time_limit`` only as a safety cap. A time budget that binds makes the result
    depend on the machine's speed; a window budget makes the repair deterministic for a seed
    whatever the load.
    """
    t0 = time.perf_counter()
    deadline = t0 + time_limit
    stages: dict[str, float] = {}
    weights = rules.cell_weights(layout_in)
    if is_valid(layout_in, rules):
        return SearchOutcome("optimal", layout_in.copy(), 0.0, stages)
    bound = lower_bound(layout_in, rules)
    free = ~rules.fixed

    def left() -> float:
        return deadline - time.perf_counter()

    # 1. Greedy construction (always valid when it returns a layout).
    candidates: list[np.ndarray] = []
    greedy = heuristic(layout_in)
    if greedy is not None and is_valid(greedy, rules):
        candidates.append(greedy)
    stages["greedy_s"] = time.perf_counter() - t0

    # 2. Neighbourhood of the violations, widened until feasible; only for mostly-valid inputs
    #    (a generator far from valid leaves nothing small to re-solve).
    t1 = time.perf_counter()
    viol = violation_mask(layout_in, rules) & free
    greedy_cost = weighted_distance(greedy, layout_in, weights) if candidates else np.inf
    if viol.any() and greedy_cost > bound and viol.sum() <= max_violation_fraction * free.sum():
        radius = 1
        # Under a window budget the solves are bounded by nodes, and one node of a large
        # window can take tens of seconds (a 352-cell window of an even-search layout: 22 s
        # at its root): such windows are left to the greedy construction.
        cap = max_window_cells if improve_windows is None else min(max_window_cells, WORK_WINDOW_CELLS)
        while left() > 0:
            win = dilate(viol, radius) & free
            if win.sum() > cap:
                break
            whole = bool((win == free).all())
            # A window with fewer cells than the count gap (``bound``) cannot fix the tile
            # counts: it is infeasible without a solve (search layouts: a near-empty storage
            # area has 1-3 local violations but needs 240 shelves).
            if win.sum() >= bound or whole:
                # Under a window budget, nodes bound the solve (time only as a safety net)
                res = solve_window(
                    layout_in,
                    layout_in,
                    win,
                    rules,
                    time_limit=left() if improve_windows is not None else min(left(), window_time),
                    threads=threads,
                    seed=seed,
                    warm_start=False,
                    max_nodes=WINDOW_NODES if improve_windows is not None else None,
                )
                if res.layout is not None and is_valid(res.layout, rules):
                    candidates.append(res.layout)
                    break
                # Widen only a window proven infeasible; one that ran out of time would
                # only be harder wider (measured on a search batch: 4-9 s per such layout
                # spent on widening, for the greedy's result in the end).
                if res.status != "infeasible":
                    break
            if whole:
                break
            radius *= 2
    stages["neighbourhood_s"] = time.perf_counter() - t1
    if not candidates:
        return SearchOutcome("no_solution", None, None, stages)
    best = min(candidates, key=lambda lay: weighted_distance(lay, layout_in, weights))
    cost = weighted_distance(best, layout_in, weights)

    # 3. Window improvement around the cells that differ.
    t2 = time.perf_counter()
    stop = deadline if improve_windows is not None else min(deadline, t2 + improve_time)
    best, cost, n_windows = improve(
        best,
        layout_in,
        rules,
        bound=bound,
        windows=improve_windows,
        stop=stop,
        window=window,
        window_time=window_time,
        threads=threads,
        seed=seed,
    )
    stages["improve_s"] = time.perf_counter() - t2
    stages["windows"] = float(n_windows)
    status = "optimal" if cost <= bound else "feasible"
    return SearchOutcome(status, best, cost, stages)


def improve(
    best: np.ndarray,
    layout_in: np.ndarray,
    rules: Rules,
    *,
    bound: float,
    windows: int | None,
    stop: float,
    window: int,
    window_time: float,
    threads: int,
    seed: int,
) -> tuple[np.ndarray, float, int]:
    """Re-solve ``window``-sided squares of the valid ``best`` centred on free cells where it
    differs from ``layout_in`` (picked at random from ``seed``), keeping each nearer layout,
    until the distance meets ``bound``, ``windows`` squares were solved (each bounded by
    branch-and-bound nodes: the same answer whatever the load) or, without a window count, the
    clock reaches ``stop``. A square that brings nothing is not visited again."""
    free = ~rules.fixed
    weights = rules.cell_weights(layout_in)
    cost = weighted_distance(best, layout_in, weights)
    max_windows = windows if windows is not None else np.inf
    rng = np.random.default_rng(seed)
    done = np.zeros(layout_in.shape, dtype=bool)
    n_windows = 0
    while cost > bound and n_windows < max_windows and time.perf_counter() < stop:
        todo = np.argwhere((best != layout_in) & free & ~done)
        if len(todo) == 0:
            break
        r, c = todo[rng.integers(len(todo))]
        box = _square(layout_in.shape, int(r), int(c), window) & free
        before = weighted_distance(best[box], layout_in[box], weights[box])
        if windows is not None:  # work limits: the same answer whatever the load
            budget, nodes = max(0.05, stop - time.perf_counter()), WINDOW_NODES
        else:
            budget, nodes = max(0.05, min(window_time / 4, stop - time.perf_counter())), None
        res = solve_window(
            best,
            layout_in,
            box,
            rules,
            time_limit=budget,
            threads=threads,
            seed=seed,
            warm_start=True,
            max_nodes=nodes,
        )
        n_windows += 1
        if (
            res.layout is not None
            and res.objective is not None
            and res.objective < before - 0.5
            and is_valid(res.layout, rules)
        ):
            best = res.layout
            cost = weighted_distance(best, layout_in, weights)
        else:
            done |= box
    return best, cost, n_windows
