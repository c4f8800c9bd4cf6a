"""Constraint repair of generated layouts (warehouse, manufacturing) with HiGHS.

``repair(domain_name, layout, **opts)`` returns the valid layout nearest to ``layout`` in
(weighted) Hamming distance that the chosen method finds:

- ``method="neighbourhood"`` (default, scalable): exact window MILPs around the violations, a
  greedy valid construction, then window-by-window improvement (:mod:`.neighbourhood`).
- ``method="full"``: the paper's monolithic flow MILP over the whole map (:mod:`.milp`),
  warm-started with the greedy layout; exact, but minutes to hours beyond 33x36.
- ``method="hybrid"``: the neighbourhood repair, then the monolithic MILP warm-started with its
  result for at most ``milp_time_s`` seconds, keeping
  whichever is nearer. At size S it proves near-valid layouts optimal in about a second (on
  the paper's unrepaired layout and on perturbations of the paper's layout the neighbourhood's
  result was already optimal) and costs at most ``milp_time_s`` on the rest; the repair's
  distance drives alpha * Delta, so it matters there.
  With ``improve_windows`` (work limits instead of time, so that the result does not depend on
  the machine's load) hybrid runs no MILP over the whole map (its root has no work limit):
  the neighbourhood's greedy and violation windows, then the whole map's LP relaxation
  (iteration-limited) and its exact rounding (:mod:`.rounding`: the MILP over the cells the LP
  leaves fractional, node-limited), then at most ``improve_windows`` node-limited windows while
  the distance is above the LP's bound. At S this proves most layouts optimal in a fraction of
  a second (docs/benchmarks.md). ``connectivity="lazy"`` first solves that LP without the
  connectivity flow and rounds it (:mod:`.lazy`): on manufacturing's 101x102 layouts 17 times
  faster than the flow's LP, to the same bound, and the rounded layout was connected; where it
  is not, the flow's LP follows as before.

Ties: many valid layouts are often equally near (a generator that leaves every shelf to the
repair has thousands). ``tie_break="none"`` takes the one the solvers' own order reaches first:
deterministic and regular (the greedy fills rows in order), so a search can learn to leave the
pattern to the repair. ``tie_break="random"`` prefers among equally near layouts by small
random costs drawn per layout (seeded by ``seed`` and the layout's bytes: the same input gets
the same repair), the paper's "MILP solver arbitrarily selects an optimal solution when
multiple solutions exist"; distances, ``optimal`` and Delta are unchanged by it.

Aisles (warehouses, beyond the paper): ``keep_aisles=True`` holds the storage rows the input
leaves without shelves exactly as drawn, so the repair meets the shelf count and the
adjacency rules elsewhere. The paper's repair is indifferent to where a shelf goes and may
close a corridor at its end with one; what that costs a layout's throughput, and where it does
not matter, is measured in docs/benchmarks.md (140x500). Off by default: the paper's
protocol. The distance is to the same input, so Delta stays comparable; a repair that must
cross an aisle to be valid gets a larger distance or no layout.

Statuses: ``optimal`` (proven), ``feasible`` (valid, optimality not proven: time limit or
neighbourhood search), ``infeasible`` (proven that no valid layout exists), ``no_solution``
(nothing valid found in time). In the QD loop a generator whose repair has no layout gets the
lowest objective and is not inserted (``EvalBatch.valid = False``); the run goes on.
"""

from __future__ import annotations

import dataclasses
import time
import zlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from nca_qd import memory
from nca_qd.errors import NcaQdError
from nca_qd.layouts import get_layout
from nca_qd.layouts.rules import Rules
from nca_qd.repair.heuristic import greedy_layout
from nca_qd.repair.lazy import lazy_repair
from nca_qd.repair.milp import solve_window
from nca_qd.repair.neighbourhood import improve, lower_bound, repair_neighbourhood, weighted_distance
from nca_qd.repair.rounding import round_relaxation
from nca_qd.repair.validator import check, is_valid

METHODS = ("neighbourhood", "full", "hybrid")
TIE_BREAKS = ("none", "random")
# How the work-limited hybrid's whole-map LP treats connectivity: the flow (exact model), or
# lazy (:mod:`.lazy`: the rules only, the rounded layout kept when connected, else the flow).
CONNECTIVITY = ("flow", "lazy")


@dataclass
class RepairResult:
    """Outcome of one repair.

    layout: repaired full layout (None when ``status`` is ``infeasible`` or ``no_solution``).
    objective: weighted Hamming distance (the MILP objective); hamming: plain tile count changed.
    similarity: the paper's Delta in [0, 1] (0 when there is no layout).
    """

    status: str
    layout: np.ndarray | None
    objective: float | None
    hamming: int | None
    similarity: float
    seconds: float
    method: str
    details: dict[str, Any] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.layout is not None


def tiles_of(domain_name: str) -> str:
    """Layout alphabet of a repairable domain."""
    return get_layout(domain_name, "repair domain").tiles


def make_rules(
    domain_name: str, shape: tuple[int, int], *, n_shelves: int | None = None, n_agents: int = 200
) -> Rules:
    """Validity rules of ``domain_name`` for a full layout of ``shape``."""
    return get_layout(domain_name, "repair domain").rules(shape, n_shelves=n_shelves, n_agents=n_agents)


def similarity(layout_in: np.ndarray, layout_out: np.ndarray, rules: Rules) -> float:
    """Paper eq. 1: sum of p_i over unchanged tiles / (n * max p)."""
    weights = rules.cell_weights(layout_in)
    p_max = max(rules.weight_of_input) if rules.weight_of_input else 1
    return float((weights * (layout_in == layout_out)).sum() / (layout_in.size * p_max))


def _greedy_for(domain_name: str, rules: Rules, n_agents: int):
    construction = get_layout(domain_name).construction
    return lambda x: greedy_layout(x, rules, construction, n_agents)


def repair(
    domain_name: str,
    layout: np.ndarray,
    *,
    method: str = "neighbourhood",
    time_limit_s: float = 60.0,
    improve_time_s: float | str | None = "auto",
    improve_windows: int | None = None,
    window: int = 8,
    window_time_s: float = 2.0,
    max_window_cells: int = 1200,
    max_violation_fraction: float = 0.25,
    threads: int = 1,
    seed: int = 0,
    n_shelves: int | None = None,
    n_agents: int = 200,
    milp_time_s: float = 2.0,
    tie_break: str = "none",
    connectivity: str = "flow",
    keep_aisles: bool = False,
) -> RepairResult:
    """Repair a full layout (indices into :func:`tiles_of`); see the module docstring."""
    t0 = time.perf_counter()
    if method not in METHODS:
        raise NcaQdError(f"unknown repair method {method!r} (known: {', '.join(METHODS)})")
    if tie_break not in TIE_BREAKS:
        raise NcaQdError(f"unknown tie_break {tie_break!r} (known: {', '.join(TIE_BREAKS)})")
    if connectivity not in CONNECTIVITY:
        raise NcaQdError(f"unknown connectivity {connectivity!r} (known: {', '.join(CONNECTIVITY)})")
    layout = np.asarray(layout, dtype=np.int32)
    memory.check(memory.repair_bytes(layout.size), f"repairing a {layout.shape[0]}x{layout.shape[1]} layout")
    rules = make_rules(domain_name, layout.shape, n_shelves=n_shelves, n_agents=n_agents)
    if keep_aisles:
        rules = hold_aisles(domain_name, layout, rules)
    if tie_break == "random":
        rules = dataclasses.replace(rules, tie_costs=tie_costs(layout, rules, seed))
    get_layout(domain_name).check_frame(layout, "layout")
    greedy = _greedy_for(domain_name, rules, n_agents)
    improve_time_s = resolve_improve_time(improve_time_s, int((~rules.fixed).sum()))
    # ``count_bound``: each changed cell moves a tile count by at most one (cheap, proven, weak);
    # ``milp_bound``: the whole-map MILP's dual bound where it ran (hybrid, full).
    details: dict[str, Any] = {"count_bound": lower_bound(layout, rules)}
    if count_shortfall(rules) is not None:
        status, best = "infeasible", None
    elif method in ("neighbourhood", "hybrid"):
        # Under work limits hybrid spends its window budget after the LP (below), where the
        # LP's bound can stop it early.
        work_hybrid = method == "hybrid" and improve_windows is not None
        out = repair_neighbourhood(
            layout,
            rules,
            greedy,
            time_limit=time_limit_s,
            improve_time=improve_time_s,
            improve_windows=0 if work_hybrid else improve_windows,
            window=window,
            window_time=window_time_s,
            max_window_cells=max_window_cells,
            max_violation_fraction=max_violation_fraction,
            threads=threads,
            seed=seed,
        )
        status, best = out.status, out.layout
        details.update(out.stages)
        # The MILP has no work limit that bounds its root (a far-from-valid 33x36 layout
        # spends > 100 s there even with 10 nodes), so under work limits (improve_windows:
        # the same answer whatever the load) hybrid solves the whole map's LP relaxation from
        # the neighbourhood's layout instead (primal simplex, iteration-limited) and rounds it
        # exactly (:mod:`.rounding`): its bound proves the layout optimal or says how far it
        # may be, and the window budget goes to what is left of the gap.
        if method == "hybrid" and status == "feasible" and not work_hybrid:
            budget = min(float(milp_time_s), time_limit_s - (time.perf_counter() - t0))
            if budget > 0:
                status, best = _polish(layout, best, rules, budget, threads, seed, details)
        elif work_hybrid and status == "feasible":
            left = time_limit_s - (time.perf_counter() - t0)
            if connectivity == "lazy":
                status, best = _lazy(layout, best, rules, left, threads, seed, details)
            if status == "feasible" and details.get("lazy_status") != "connected":
                left = time_limit_s - (time.perf_counter() - t0)
                status, best = _relax(layout, best, rules, left, threads, seed, details)
            if status == "feasible" and improve_windows:
                status, best = _improve_to_bound(
                    layout,
                    best,
                    rules,
                    improve_windows,
                    t0 + time_limit_s,
                    window,
                    window_time_s,
                    threads,
                    seed,
                    details,
                )
    else:
        status, best = _full(layout, rules, greedy, time_limit_s, threads, seed, details)
    if best is not None:
        bad = check(best, rules)
        if bad is not None:  # never expected: every path validates; keep the QD loop alive anyway
            details["invalid"] = str(bad)
            status, best = "no_solution", None
    weights = rules.cell_weights(layout)
    objective = None if best is None else weighted_distance(best, layout, weights)
    _bound_and_gap(details, status, objective)
    return RepairResult(
        status=status,
        layout=best,
        objective=objective,
        hamming=None if best is None else int((best != layout).sum()),
        similarity=0.0 if best is None else similarity(layout, best, rules),
        seconds=time.perf_counter() - t0,
        method=method,
        details=details,
    )


def _bound_and_gap(details: dict[str, Any], status: str, objective: float | None) -> None:
    """``bound``: the best proven lower bound on the weighted distance (the MILP's where it ran,
    else the count bound; the objective itself when the repair is proven optimal), and ``gap``:
    ``(objective - bound) / objective`` (0 for a layout already valid)."""
    bound = max(float(details["count_bound"]), float(details.get("milp_bound") or 0.0))
    if status == "optimal" and objective is not None and "milp_bound" not in details:
        bound = objective  # valid as given, or proven by the neighbourhood's own full solve
    details["bound"] = bound
    if objective is not None:
        details["gap"] = 0.0 if objective <= 0 else max(0.0, (objective - bound) / objective)


def hold_aisles(domain_name: str, layout: np.ndarray, rules: Rules) -> Rules:
    """``rules`` with the cells of ``layout``'s aisles (:meth:`LayoutKind.aisles`) fixed as drawn."""
    mask = get_layout(domain_name).aisles(layout)
    if mask is None:
        raise NcaQdError(f"keep_aisles: {domain_name} layouts have no aisles to keep (warehouses only)")
    base = rules.fixed_layout if rules.fixed_layout is not None else np.zeros(layout.shape, np.int32)
    return dataclasses.replace(
        rules, fixed=rules.fixed | mask, fixed_layout=np.where(mask, layout, base).astype(np.int32)
    )


def tie_costs(layout: np.ndarray, rules: Rules, seed: int) -> np.ndarray:
    """Random costs of changing each free cell, summing to less than 1 (so below any difference
    in the integer weighted distance), drawn from ``seed`` and the layout's bytes."""
    layout = np.ascontiguousarray(layout, dtype=np.int32)
    rng = np.random.default_rng([int(seed), zlib.crc32(layout.tobytes()), *layout.shape])
    free = ~rules.fixed
    return np.where(free, rng.random(layout.shape), 0.0) / (int(free.sum()) + 1)


def resolve_improve_time(value: float | str | None, n_free: int) -> float:
    """Seconds of window improvement; ``auto``: 0.5 s at 33x36, growing with the square of the map.

    The number of windows to visit grows with the map and so does what an improvement is worth
    (a large layout is repaired once, not once per QD evaluation): 0.5 s at 1,056 free cells,
    1.7 s at 45x47, 6.4 s at 57x58, ... at most 20 s (81x80 and larger).
    """
    if value is None or value == "auto":
        return float(min(20.0, 0.5 * (n_free / 1056.0) ** 2))
    try:
        return float(value)
    except (TypeError, ValueError):
        raise NcaQdError(f"improve_time_s must be a number or 'auto', got {value!r}") from None


def count_shortfall(rules: Rules) -> tuple[Any, int] | None:
    """A count rule no layout can meet, and the room the map has for its tiles (fixed cells of
    those tiles plus the free cells): more tiles required than that; None if every rule fits."""
    free_n = int((~rules.fixed).sum())
    for rule in rules.counts:
        fixed_n = (
            0
            if rules.fixed_layout is None
            else int((rules.fixed & np.isin(rules.fixed_layout, list(rule.tiles))).sum())
        )
        room = fixed_n + (free_n if set(rule.tiles) & set(rules.free_tiles) else 0)
        if rule.value > room:
            return rule, room
    return None


def _polish(layout, start, rules, time_limit, threads, seed, details):
    """The whole-map MILP warm-started with the valid ``start``: a nearer layout if it finds one
    in its budget, ``optimal`` if it proves one; ``start`` (``feasible``) otherwise."""
    weights = rules.cell_weights(layout)
    before = weighted_distance(start, layout, weights)
    res = solve_window(
        start, layout, ~rules.fixed, rules, time_limit=time_limit, threads=threads, seed=seed, warm_start=True
    )
    details["milp_s"] = res.seconds
    details["milp_nodes"] = res.nodes
    if res.bound is not None:
        details["milp_bound"] = res.bound
    if res.layout is None or not is_valid(res.layout, rules):
        return "feasible", start
    after = weighted_distance(res.layout, layout, weights)
    details["milp_gain"] = before - after
    if after > before:
        return "feasible", start
    return ("optimal" if res.status == "optimal" else "feasible"), res.layout


# Simplex iterations of the whole map's LP relaxation (a work limit): 33x36 layouts of the
# searches took 0.05-2.3 s from the neighbourhood's layout (docs/benchmarks.md).
LP_ITERATIONS = 200_000


def _relax(layout, start, rules, time_limit, threads, seed, details):
    """The whole map's LP relaxation from the valid ``start``: ``optimal`` with its integral
    optimum, or with ``start`` or the LP's exact rounding (:mod:`.rounding`) when the bound
    meets it; otherwise ``feasible`` with the nearer of those two."""
    weights = rules.cell_weights(layout)
    res = solve_window(
        start,
        layout,
        ~rules.fixed,
        rules,
        time_limit=max(1.0, float(time_limit)),  # a safety net: the iterations bound the work
        threads=threads,
        seed=seed,
        warm_start=True,
        relaxation=True,
        iteration_limit=LP_ITERATIONS,
    )
    details["lp_s"] = res.seconds
    details["lp_status"] = res.status
    details["lp_iterations"] = res.iterations
    if res.bound is not None:
        details["milp_bound"] = res.bound
    cost = weighted_distance(start, layout, weights)
    if res.status == "optimal" and res.layout is not None and is_valid(res.layout, rules):
        if weighted_distance(res.layout, layout, weights) <= cost:
            return "optimal", res.layout
    if res.status == "fractional":
        t = time.perf_counter()
        rounded, cells = round_relaxation(res, layout, rules, threads=threads, seed=seed)
        details["rounding_s"] = time.perf_counter() - t
        details["rounding_cells"] = cells
        rounded_cost = np.inf if rounded is None else weighted_distance(rounded, layout, weights)
        if rounded_cost < cost:
            details["rounding_gain"] = cost - rounded_cost
            start, cost = rounded, rounded_cost
    if res.bound is not None and cost <= res.bound:
        return "optimal", start
    return "feasible", start


def _lazy(layout, start, rules, time_limit, threads, seed, details):
    """The rules-only LP and its exact rounding (:mod:`.lazy`): its layout when connected and
    nearer than ``start``; ``optimal`` when the distance meets the LP's bound."""
    weights = rules.cell_weights(layout)
    res = lazy_repair(layout, rules, time_limit=max(1.0, float(time_limit)), threads=threads, seed=seed)
    details.update(lazy_status=res.status, lazy_lp_s=res.lp_s, lazy_rounding_s=res.rounding_s)
    details["lazy_fractional"] = res.fractional
    if res.bound is not None:
        details["milp_bound"] = max(res.bound, float(details.get("milp_bound") or 0.0))
    cost = weighted_distance(start, layout, weights)
    if res.layout is not None and weighted_distance(res.layout, layout, weights) < cost:
        start, cost = res.layout, weighted_distance(res.layout, layout, weights)
    if res.bound is not None and cost <= res.bound:
        return "optimal", start
    return "feasible", start


def _improve_to_bound(layout, start, rules, windows, deadline, window, window_time, threads, seed, details):
    """At most ``windows`` node-bounded improvement windows (:func:`.neighbourhood.improve`),
    stopping once the distance meets the best proven bound."""
    bound = max(float(details["count_bound"]), float(details.get("milp_bound") or 0.0))
    t = time.perf_counter()
    best, cost, n = improve(
        start,
        layout,
        rules,
        bound=bound,
        windows=windows,
        stop=deadline,
        window=window,
        window_time=window_time,
        threads=threads,
        seed=seed,
    )
    details["improve_s"] = details.get("improve_s", 0.0) + time.perf_counter() - t
    details["windows"] = float(n)
    return ("optimal" if cost <= bound else "feasible"), best


def _full(layout, rules, greedy, time_limit, threads, seed, details):
    """The monolithic MILP over every free cell, warm-started with the greedy layout if valid."""
    if is_valid(layout, rules):
        return "optimal", layout.copy()
    start = greedy(layout)
    warm = start is not None and is_valid(start, rules)
    current = start if warm else layout
    res = solve_window(
        current,
        layout,
        ~rules.fixed,
        rules,
        time_limit=time_limit,
        threads=threads,
        seed=seed,
        warm_start=warm,
    )
    details["milp_s"] = res.seconds
    details["milp_nodes"] = res.nodes
    if res.bound is not None:
        details["milp_bound"] = res.bound
    if res.status == "infeasible":
        return "infeasible", None
    if res.layout is None:
        return ("feasible", start) if warm else ("no_solution", None)
    return res.status, res.layout
