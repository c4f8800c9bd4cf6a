"""Repair: valid output or a status saying why not; exactness of the MILP; determinism."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from nca_qd.io import load_map, reference_maps_dir
from nca_qd.layouts import warehouse as wh
from nca_qd.repair import make_rules, repair
from nca_qd.repair.validator import check

MAPS = reference_maps_dir()
FAST = dict(time_limit_s=20, improve_time_s=0.3)


def assert_result_ok(res, domain, layout, **rule_opts):
    """Valid layout with consistent figures, or no layout and a status that says why."""
    if res.layout is None:
        assert res.status in ("infeasible", "no_solution")
        assert res.similarity == 0.0
        return
    assert res.status in ("optimal", "feasible")
    assert check(res.layout, make_rules(domain, layout.shape, **rule_opts)) is None
    assert res.hamming == int((res.layout != layout).sum())
    assert 0.0 <= res.similarity <= 1.0


storage = st.integers(0, 2)


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.lists(storage, min_size=6, max_size=6), min_size=9, max_size=9))
def test_warehouse_random_inputs(cells):
    layout = wh.assemble(np.array(cells, dtype=np.int32))  # 9 x 10
    res = repair("warehouse_even", layout, n_shelves=8, **FAST)
    assert_result_ok(res, "warehouse_even", layout, n_shelves=8)
    assert res.layout is not None  # 8 shelves always fit in a 9x6 storage area
    assert res.hamming >= abs(int((layout == wh.SHELF).sum()) - 8)


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.lists(st.integers(0, 4), min_size=7, max_size=7), min_size=6, max_size=6))
def test_manufacturing_random_inputs(cells):
    layout = np.array(cells, dtype=np.int32)
    res = repair("manufacturing", layout, n_agents=12, **FAST)
    assert_result_ok(res, "manufacturing", layout, n_agents=12)
    assert res.layout is not None


def test_valid_input_is_returned_unchanged():
    lay = wh.assemble(np.array([[0, 0, 2, 0, 0], [0, 2, 1, 2, 0], [0, 0, 2, 0, 0]], dtype=np.int32))
    res = repair("warehouse_even", lay, n_shelves=1)
    assert res.status == "optimal" and res.hamming == 0 and res.similarity == 1.0


def test_impossible_shelf_count_reports_instead_of_raising():
    lay = wh.assemble(np.zeros((5, 4), dtype=np.int32))
    for method in ("neighbourhood", "full"):
        res = repair("warehouse_even", lay, n_shelves=20, method=method, time_limit_s=10)
        assert res.layout is None and res.status in ("infeasible", "no_solution")
    # More shelves than storage cells: proven infeasible without a solve.
    res = repair("warehouse_even", lay, n_shelves=21)
    assert res.status == "infeasible" and res.layout is None


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_full_milp_is_optimal_and_no_worse_than_neighbourhood(seed):
    rng = np.random.default_rng(seed)
    lay = wh.assemble(rng.integers(0, 3, size=(7, 6)).astype(np.int32))
    full = repair("warehouse_even", lay, n_shelves=6, method="full", time_limit_s=60)
    fast = repair("warehouse_even", lay, n_shelves=6, **FAST)
    assert full.status == "optimal"
    assert_result_ok(full, "warehouse_even", lay, n_shelves=6)
    assert_result_ok(fast, "warehouse_even", lay, n_shelves=6)
    assert full.objective <= fast.objective
    # proven bounds: the full MILP's equals its optimum; every repair's bound is at most the
    # optimum (checked against the full MILP's, not against its own objective)
    assert full.details["bound"] == full.objective and full.details["gap"] == 0.0
    assert fast.details["bound"] <= full.objective <= fast.objective
    assert fast.details["gap"] == pytest.approx((fast.objective - fast.details["bound"]) / fast.objective)


def test_distance_bound_rounds_the_dual_bound_to_integer_distances():
    from nca_qd.repair.milp import distance_bound

    assert distance_bound(146.0000001, False) == 146.0
    assert distance_bound(145.2, False) == 146.0
    # with tie costs (< 1 in all) the objective is distance + ties: distance > bound - 1
    assert distance_bound(146.3, True) == 146.0
    assert distance_bound(146.0, True) == 146.0
    assert distance_bound(float("-inf"), True) is None


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.lists(storage, min_size=6, max_size=6), min_size=7, max_size=7))
def test_hybrid_is_valid_never_worse_than_its_start_and_optimal_with_time(cells):
    """hybrid = the neighbourhood repair, then the full MILP warm-started from it: its layout is
    valid (independent validator), no farther than the neighbourhood's, and — with time to
    finish on a small map — as near as the proven optimum."""
    lay = wh.assemble(np.array(cells, dtype=np.int32))
    opts = dict(n_shelves=6, time_limit_s=60, improve_time_s=0.1, seed=0)
    nb = repair("warehouse_even", lay, method="neighbourhood", **opts)
    hy = repair("warehouse_even", lay, method="hybrid", milp_time_s=30, **opts)
    full = repair("warehouse_even", lay, method="full", n_shelves=6, time_limit_s=60)
    assert_result_ok(hy, "warehouse_even", lay, n_shelves=6)
    assert full.status == "optimal" and hy.status == "optimal"
    assert hy.objective == full.objective <= nb.objective
    # Under work limits (improve_windows: the same repair whatever the load) hybrid is the
    # neighbourhood repair, then the whole map's LP relaxation and its exact rounding (no
    # MILP over the whole map: its only budget would be time): never farther than the
    # neighbourhood, its bound at most the proven optimum, "optimal" only when it meets that
    # bound, and the same layout on every call.
    det = dict(n_shelves=6, time_limit_s=60, improve_windows=1, seed=0)
    a = repair("warehouse_even", lay, method="hybrid", **det)
    b = repair("warehouse_even", lay, method="neighbourhood", **det)
    again = repair("warehouse_even", lay, method="hybrid", **det)
    assert_result_ok(a, "warehouse_even", lay, n_shelves=6)
    assert a.objective <= b.objective and a.details["bound"] <= full.objective
    assert (a.status == "optimal") == (a.objective <= a.details["bound"])
    assert np.array_equal(a.layout, again.layout) and a.status == again.status


def test_hybrid_per_size_options_come_from_the_domain_config():
    from nca_qd.scoring.jobs import repair_options

    cfg = {
        "repair": {
            "method": {"train": "hybrid", "eval": "neighbourhood"},
            "milp_time_s": 5,
            "n_shelves": {"train": 240, "eval": 2250},
        },
        "n_agents": {"train": 200, "eval": 1400},
    }
    train, evl = repair_options(cfg, "train"), repair_options(cfg, "eval")
    assert (train["method"], train["milp_time_s"], train["n_shelves"]) == ("hybrid", 5, 240)
    assert (evl["method"], evl["n_shelves"], evl["n_agents"]) == ("neighbourhood", 2250, 1400)


def test_manufacturing_weights_and_similarity():
    # A lone station without endpoints: moving stations costs 5, adding endpoints 1.
    lay = np.zeros((6, 6), dtype=np.int32)
    lay[2, 2], lay[2, 3], lay[3, 2] = 2, 3, 4
    full = repair("manufacturing", lay, n_agents=10, method="full", time_limit_s=60)
    assert full.status == "optimal"
    assert np.array_equal(full.layout[[2, 2, 3], [2, 3, 2]], [2, 3, 4])  # stations kept
    # Delta = sum p_i over unchanged tiles / (5 n).
    n = lay.size
    expected = (5 * 3 + (n - 3 - full.hamming)) / (5 * n)
    assert full.similarity == pytest.approx(expected)


def test_deterministic_for_a_seed():
    """With a window budget (not a time budget) the result cannot depend on the machine's load."""
    rng = np.random.default_rng(7)
    lay = rng.integers(0, 5, size=(10, 11)).astype(np.int32)
    a = repair("manufacturing", lay, n_agents=20, seed=3, time_limit_s=60, improve_windows=2)
    b = repair("manufacturing", lay, n_agents=20, seed=3, time_limit_s=60, improve_windows=2)
    assert a.status == b.status and np.array_equal(a.layout, b.layout)
    assert a.details["windows"] == b.details["windows"] <= 2


@pytest.mark.skipif(not MAPS.is_dir(), reason="shared reference maps not present")
def test_paper_example_matches_the_papers_repair():
    lay = load_map(MAPS / "warehouse/paper_cma-mae_a5_even_33x36_unrepaired.json").to_array(wh.TILES)
    res = repair("warehouse_even", lay)
    assert_result_ok(res, "warehouse_even", lay)
    assert res.hamming <= 32  # the paper's CPLEX repair moved 32 tiles
    assert res.seconds < 10


def _stage_two_windows(monkeypatch, status):
    """Run a repair whose window solves all answer ``status``; return the cell counts of the
    violation-neighbourhood solves (the cold-started ones) and the bound they had to meet."""
    from nca_qd.repair import neighbourhood
    from nca_qd.repair.milp import WindowResult

    sizes = []

    def fake(current, layout_in, window, rules, *, warm_start, **kw):
        if not warm_start:
            sizes.append(int(window.sum()))
        return WindowResult(status, None, None, 0.0, int(window.sum()))

    monkeypatch.setattr(neighbourhood, "solve_window", fake)
    storage = np.zeros((9, 6), dtype=np.int32)
    storage[4, 3] = 2  # one endpoint (tile 2) without a shelf beside it: one violation
    layout = wh.assemble(storage)
    res = repair("warehouse_even", layout, n_shelves=20, **FAST)
    assert_result_ok(res, "warehouse_even", layout, n_shelves=20)  # the greedy still delivers
    return sizes, res.details["count_bound"]


def test_the_violation_neighbourhood_skips_windows_too_small_for_the_count_gap(monkeypatch):
    sizes, bound = _stage_two_windows(monkeypatch, "infeasible")
    assert bound == 20 and len(sizes) >= 1
    assert min(sizes) >= bound  # radius 1 (9 cells) could not add 20 shelves: never solved
    assert sizes == sorted(sizes) and len(set(sizes)) == len(sizes)  # widened while infeasible


def test_a_timed_out_violation_window_is_not_widened(monkeypatch):
    sizes, _ = _stage_two_windows(monkeypatch, "timeout")
    assert len(sizes) == 1


def test_highs_prints_no_banner_into_run_logs():
    """A process's first HiGHS instance prints a banner on the C-level stdout before options
    can be set; quiet_highs keeps it out (one per worker used to fill every run log)."""
    import subprocess
    import sys

    code = "from nca_qd.repair.milp import quiet_highs; quiet_highs(); quiet_highs(); print('ok')"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout == "ok\n" and "HiGHS" not in out.stderr


def _rows_of_endpoints(n_rows: int = 9, n_cols: int = 8) -> np.ndarray:
    """A storage area of endpoint rows and no shelves: every valid repair places all N_s shelves,
    on many equally near sets of cells (the case where the tie-break decides the pattern)."""
    region = np.zeros((n_rows, n_cols), dtype=np.int32)
    region[::2] = wh.ENDPOINT
    return wh.assemble(region)


def test_random_tie_break_keeps_the_distance_and_changes_only_the_choice():
    """tie_break=random: the same proven-optimal distance and Delta as tie_break=none (valid by
    the independent validator), a different layout among the equally near ones for another seed
    or input, and the same layout again for the same seed and input."""
    lay = _rows_of_endpoints()
    opts = dict(n_shelves=10, method="full", time_limit_s=60)
    plain = repair("warehouse_even", lay, **opts)
    runs = [repair("warehouse_even", lay, tie_break="random", seed=s, **opts) for s in (0, 1, 0)]
    for res in [plain, *runs]:
        assert_result_ok(res, "warehouse_even", lay, n_shelves=10)
        assert res.status == "optimal"
        assert res.hamming == plain.hamming and res.similarity == plain.similarity
    assert np.array_equal(runs[0].layout, runs[2].layout)
    layouts = {r.layout.tobytes() for r in [plain, *runs]}
    assert len(layouts) >= 2
    # The costs that break ties sum to less than one changed cell, so never outweigh distance.
    from nca_qd.repair import tie_costs

    costs = tie_costs(lay, make_rules("warehouse_even", lay.shape, n_shelves=10), seed=0)
    assert 0 < costs.sum() < 1 and (costs >= 0).all()


@pytest.mark.parametrize("method", ["neighbourhood", "hybrid"])
def test_random_tie_break_neighbourhood_methods_stay_valid_and_near(method):
    lay = _rows_of_endpoints(11, 10)
    opts = dict(n_shelves=14, method=method, time_limit_s=30, improve_time_s=0.2, seed=2)
    plain = repair("warehouse_even", lay, **opts)
    rnd = repair("warehouse_even", lay, tie_break="random", **opts)
    assert_result_ok(rnd, "warehouse_even", lay, n_shelves=14)
    assert rnd.layout is not None and rnd.hamming <= plain.hamming + 2


def test_unknown_tie_break_is_refused():
    with pytest.raises(Exception, match="unknown tie_break 'maybe'"):
        repair("warehouse_even", _rows_of_endpoints(), n_shelves=4, tie_break="maybe")


def test_work_limits_give_the_same_repair_on_a_slow_clock(slow_clock):
    """improve_windows bounds the repair by work: a clock that runs 100 ms per reading (a loaded
    machine, to the code) changes nothing; the time-bounded default stops early on it."""
    from nca_qd.repair import neighbourhood

    rng = np.random.default_rng(1)
    lay = wh.assemble(rng.integers(0, 3, size=(21, 20)).astype(np.int32))
    det = dict(method="hybrid", n_shelves=90, improve_windows=30, time_limit_s=110, seed=0)
    timed = dict(method="neighbourhood", n_shelves=90, improve_time_s=0.3, time_limit_s=110, seed=0)
    idle, idle_timed = repair("warehouse_even", lay, **det), repair("warehouse_even", lay, **timed)

    slow_clock(neighbourhood)
    loaded, loaded_timed = repair("warehouse_even", lay, **det), repair("warehouse_even", lay, **timed)
    assert np.array_equal(idle.layout, loaded.layout) and idle.status == loaded.status
    assert (
        idle.details["windows"] == loaded.details["windows"]
        and idle.details["bound"] == loaded.details["bound"]
    )
    assert loaded_timed.details["windows"] < idle_timed.details["windows"]  # time stopped it


def _paper_unrepaired():
    return load_map(MAPS / "warehouse/paper_cma-mae_a5_even_33x36_unrepaired.json").to_array(wh.TILES)


@pytest.mark.skipif(not MAPS.is_dir(), reason="shared reference maps not present")
def test_lp_rounding_keeps_the_lps_integral_cells_and_is_valid_and_bounded():
    """The rounding of a fractional LP solution: a valid layout (independent validator) that
    equals the LP's tiles away from its fractional cells (it widens by at most two cells),
    never nearer than the LP's bound."""
    import dataclasses

    from nca_qd.repair import tie_costs
    from nca_qd.repair.heuristic import greedy_layout
    from nca_qd.repair.milp import solve_window
    from nca_qd.repair.neighbourhood import weighted_distance
    from nca_qd.repair.rounding import round_relaxation

    lay = _paper_unrepaired()
    rules = make_rules("warehouse_even", lay.shape)
    rng = np.random.default_rng(5)  # 6 % of the storage cells redrawn: this LP is fractional
    free = np.argwhere(~rules.fixed)
    for r, c in free[rng.choice(len(free), size=int(0.06 * len(free)), replace=False)]:
        lay[r, c] = rng.integers(0, 3)
    rules = dataclasses.replace(rules, tie_costs=tie_costs(lay, rules, 0))
    start = greedy_layout(lay, rules, wh.Warehouse.construction, 200)
    assert check(start, rules) is None
    lp = solve_window(start, lay, ~rules.fixed, rules, relaxation=True, warm_start=True)
    assert lp.status == "fractional" and lp.fractional.any() and lp.iterations > 0
    rounded, cells = round_relaxation(lp, lay, rules)
    assert rounded is not None and check(rounded, rules) is None
    assert cells >= int(lp.fractional.sum())
    far = ~dilate_mask(lp.fractional, 2)
    assert np.array_equal(rounded[far], lp.layout[far])
    distance = weighted_distance(rounded, lay, rules.cell_weights(lay))
    assert lp.bound <= distance <= weighted_distance(start, lay, rules.cell_weights(lay))
    # the same LP by interior point (with crossover): the same optimum, so the same bound (its
    # vertex may differ: this LP has integral optima beside fractional ones)
    ipm = solve_window(start, lay, ~rules.fixed, rules, relaxation=True, warm_start=True, lp_solver="ipm")
    assert ipm.status in ("fractional", "optimal") and ipm.bound == lp.bound


def dilate_mask(mask, radius):
    from nca_qd.layouts.rules import dilate

    return dilate(mask, radius)


@pytest.mark.skipif(not MAPS.is_dir(), reason="shared reference maps not present")
def test_work_limited_hybrid_proves_the_papers_repair_optimal():
    """The search's repair at S (work limits): the paper's unrepaired layout gets the 32 tile
    changes of the paper's CPLEX repair, proven optimal by the LP's bound."""
    lay = _paper_unrepaired()
    res = repair("warehouse_even", lay, method="hybrid", improve_windows=10, tie_break="random")
    assert_result_ok(res, "warehouse_even", lay)
    assert res.status == "optimal" and res.hamming == 32
    assert res.details["bound"] == res.objective and res.details["gap"] == 0.0


WORK_LAZY = dict(method="hybrid", improve_windows=0, tie_break="random", connectivity="lazy")


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_lazy_connectivity_is_valid_and_its_bound_holds(seed):
    """connectivity=lazy (the rules-only LP, rounded, kept when connected): a valid layout
    (independent validator), no nearer than the full MILP's proven optimum, and a bound no
    higher than it; on a manufacturing floor too (its full MILP is too slow to compare)."""
    rng = np.random.default_rng(seed)
    lay = wh.assemble(rng.integers(0, 3, size=(7, 6)).astype(np.int32))
    full = repair("warehouse_even", lay, n_shelves=6, method="full", time_limit_s=60, tie_break="random")
    lazy = repair("warehouse_even", lay, n_shelves=6, **WORK_LAZY)
    assert full.status == "optimal"
    assert_result_ok(lazy, "warehouse_even", lay, n_shelves=6)
    assert lazy.details["lazy_status"] in ("connected", "not_connected", "no_rounding")
    assert lazy.details["bound"] <= full.objective <= lazy.objective
    floor = rng.integers(0, 5, size=(6, 7)).astype(np.int32)
    res = repair("manufacturing", floor, n_agents=8, **WORK_LAZY)
    assert_result_ok(res, "manufacturing", floor, n_agents=8)
    assert res.layout is not None and res.details["bound"] <= res.objective


def test_lazy_connectivity_falls_back_to_the_flow_where_the_rules_wall_a_cell_in():
    """An endpoint walled in by its four shelves meets every rule but connectivity: the
    rules-only rounding keeps it (not connected, discarded) and the flow's LP and its rounding
    repair it, to the full MILP's proven optimum (2 changes)."""
    storage = np.zeros((5, 5), np.int32)
    storage[2, 2] = 2
    storage[1, 2] = storage[3, 2] = storage[2, 1] = storage[2, 3] = 1
    lay = wh.assemble(storage)
    res = repair("warehouse_even", lay, n_shelves=4, **WORK_LAZY)
    assert_result_ok(res, "warehouse_even", lay, n_shelves=4)
    assert res.details["lazy_status"] == "not_connected" and "lp_status" in res.details
    full = repair("warehouse_even", lay, n_shelves=4, method="full", time_limit_s=60)
    assert full.status == "optimal" and res.objective == full.objective == 2


def test_connectivity_option_is_checked_and_absent_from_keys_at_its_default():
    from nca_qd.errors import NcaQdError
    from nca_qd.scoring.keys import repair_key

    lay = wh.assemble(np.zeros((3, 4), np.int32))
    with pytest.raises(NcaQdError, match="unknown connectivity 'none'"):
        repair("warehouse_even", lay, n_shelves=1, connectivity="none")
    opts = {"method": "hybrid", "n_shelves": 1}
    assert repair_key("warehouse_even", lay, opts) == repair_key(
        "warehouse_even", lay, {**opts, "connectivity": "flow"}
    )
    assert repair_key("warehouse_even", lay, opts) != repair_key(
        "warehouse_even", lay, {**opts, "connectivity": "lazy"}
    )


def test_keep_aisles_holds_the_shelf_free_rows_at_the_same_distance():
    """keep_aisles: the shelf the count asks for goes into the shelf row, never into the rows
    the input leaves without shelves (held as drawn), at the plain repair's proven distance;
    without it the equally near repairs include shelves in those rows."""
    region = np.array([[0] * 6, [1, 2, 1, 2, 0, 0], [0] * 6], dtype=np.int32)
    lay = wh.assemble(region)
    opts = dict(n_shelves=3, method="full", time_limit_s=30, tie_break="random")
    plain = [repair("warehouse_even", lay, seed=s, **opts) for s in range(8)]
    kept = [repair("warehouse_even", lay, seed=s, keep_aisles=True, **opts) for s in range(8)]
    for res in plain + kept:
        assert_result_ok(res, "warehouse_even", lay, n_shelves=3)
        assert res.status == "optimal" and res.hamming == 1
    aisle = wh.aisle_rows(lay)
    assert aisle[[0, 2]][:, wh.FRAME : -wh.FRAME].all() and not aisle[1].any()
    assert all(np.array_equal(r.layout[aisle], lay[aisle]) for r in kept)
    assert any((r.layout[aisle] == wh.SHELF).any() for r in plain)


def test_keep_aisles_is_refused_where_a_family_has_none_and_absent_from_keys_off():
    from nca_qd.errors import NcaQdError
    from nca_qd.scoring.keys import repair_key

    with pytest.raises(NcaQdError, match="manufacturing layouts have no aisles"):
        repair("manufacturing", np.zeros((6, 7), np.int32), n_agents=12, keep_aisles=True)
    lay = wh.assemble(np.zeros((3, 4), np.int32))
    opts = {"method": "hybrid", "n_shelves": 1}
    assert repair_key("warehouse_even", lay, opts) == repair_key(
        "warehouse_even", lay, {**opts, "keep_aisles": False}
    )
    assert repair_key("warehouse_even", lay, opts) != repair_key(
        "warehouse_even", lay, {**opts, "keep_aisles": True}
    )
