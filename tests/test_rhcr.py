"""The compiled RHCR simulator: every run goes through the independent checker."""

from __future__ import annotations

import hashlib
import threading
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from sim_layouts import MANUFACTURING, WAREHOUSE

from nca_qd.errors import NcaQdError
from nca_qd.sim.checker import check_run
from nca_qd.sim.rhcr import VERSION, simulate, simulate_many
from nca_qd.sim.scenario import build_scenario


def run_checked(rows, scenario, n_agents, T, seed=0, **kw):
    res = simulate(rows, scenario, n_agents, T, seed, record_paths=True, **kw)
    report = check_run(res, rows)
    assert report.finished_tasks == res.finished_tasks
    assert res.tile_visits.sum() == n_agents * res.stop_time
    assert res.tile_visits.shape == (len(rows), len(rows[0]))
    assert res.throughput == pytest.approx(res.finished_tasks / T)
    return res


def test_warehouse_run_is_valid_and_productive():
    res = run_checked(WAREHOUSE, "warehouse_even", 20, 200)
    assert res.success and not res.congested and not res.timed_out
    assert res.stop_time == 200 and res.paths.shape == (201, 20, 2)
    assert res.finished_tasks > 100  # 20 agents on a 9x12 map finish many tasks in 200 steps
    assert res.pbs_failures == 0
    # Agents never stand on shelves.
    assert res.tile_visits[np.array([list(r) for r in WAREHOUSE]) == "@"].sum() == 0


def test_manufacturing_agents_dwell_and_cycle():
    res = run_checked(MANUFACTURING, "manufacturing", 12, 200)
    assert res.success and res.finished_tasks > 30
    dwell_seen = {int(d) for g in res.goals for d in g[:, 2]}
    assert dwell_seen == {2, 5, 10}


def test_same_seed_same_run_other_seed_other_run():
    a = simulate(WAREHOUSE, "warehouse_even", 15, 100, seed=3, record_paths=True)
    b = simulate(WAREHOUSE, "warehouse_even", 15, 100, seed=3, record_paths=True)
    c = simulate(WAREHOUSE, "warehouse_even", 15, 100, seed=4, record_paths=True)
    assert np.array_equal(a.paths, b.paths) and np.array_equal(a.tasks_per_step, b.tasks_per_step)
    assert not np.array_equal(a.paths[0], c.paths[0])


def test_initial_positions_are_distinct_and_spread():
    res = simulate(WAREHOUSE, "warehouse_even", 60, 5, seed=1, record_paths=True)
    start = {tuple(p) for p in res.paths[0].tolist()}
    assert len(start) == 60


def test_every_agent_starts_towards_the_cycles_first_kind():
    # RHCR: each agent's first goal is an endpoint (warehouse) / a kind-0 station.
    res = simulate(WAREHOUSE, "warehouse_even", 30, 20, seed=4)
    ends = {
        r * len(WAREHOUSE[0]) + c for r, row in enumerate(WAREHOUSE) for c, ch in enumerate(row) if ch == "e"
    }
    assert all(int(g[0, 0]) * len(WAREHOUSE[0]) + int(g[0, 1]) in ends for g in res.goals)


def test_reference_starts_are_one_configuration_for_every_seed():
    runs = [
        simulate(WAREHOUSE, "warehouse_even", 40, 5, seed=s, record_paths=True, reference_starts=True)
        for s in (0, 1, 2)
    ]
    starts = [r.paths[0] for r in runs]
    assert len({tuple(p) for p in starts[0].tolist()}) == 40
    assert all((s == starts[0]).all() for s in starts)
    first = [np.array([g[0] for g in r.goals]) for r in runs]
    assert not (first[1] == first[0]).all() and not (first[2] == first[0]).all()  # goals differ
    random = simulate(WAREHOUSE, "warehouse_even", 40, 5, seed=0, record_paths=True)
    assert not (random.paths[0] == starts[0]).all()


@st.composite
def warehouse_maps(draw):
    h, w = draw(st.integers(3, 8)), draw(st.integers(3, 8))
    cells = draw(st.lists(st.sampled_from("....@@eew"), min_size=h * w, max_size=h * w))
    return ["".join(cells[r * w : (r + 1) * w]) for r in range(h)]


@st.composite
def manufacturing_maps(draw):
    h, w = draw(st.integers(4, 8)), draw(st.integers(4, 8))
    grid = [[draw(st.sampled_from("..e")) for _ in range(w)] for _ in range(h)]
    for kind in "012":
        r, c = draw(st.integers(0, h - 1)), draw(st.integers(0, w - 1))
        grid[r][c] = kind
        rr, cc = draw(st.sampled_from([(r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)]))
        if 0 <= rr < h and 0 <= cc < w and grid[rr][cc] not in "012":
            grid[rr][cc] = "e"
    return ["".join(row) for row in grid]


def _valid(rows, scenario):
    try:
        return build_scenario(rows, scenario)
    except NcaQdError:
        return None


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(
    rows=warehouse_maps(),
    scenario=st.sampled_from(["warehouse_even", "warehouse_uneven"]),
    density=st.floats(0.05, 1.0),
    T=st.integers(1, 40),
    seed=st.integers(0, 2**32),
    window=st.integers(1, 12),
    data=st.data(),
)
def test_random_warehouses_always_valid(rows, scenario, density, T, seed, window, data):
    scen = _valid(rows, scenario)
    assume(scen is not None)
    n = max(1, int(density * scen.n_traversable))
    replan = data.draw(st.integers(1, window))
    res = run_checked(rows, scenario, n, T, seed, window=window, replan=replan)
    assert res.stop_time <= T
    assert res.success == (res.stop_time == T and not res.congested and not res.timed_out)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(
    rows=manufacturing_maps(), density=st.floats(0.05, 1.0), T=st.integers(1, 40), seed=st.integers(0, 2**32)
)
def test_random_manufacturing_always_valid(rows, density, T, seed):
    scen = _valid(rows, "manufacturing")
    assume(scen is not None)
    run_checked(rows, "manufacturing", max(1, int(density * scen.n_traversable)), T, seed)


def test_dense_map_congests_and_stops_early():
    n_free = build_scenario(WAREHOUSE, "warehouse_even").n_traversable
    res = run_checked(WAREHOUSE, "warehouse_even", n_free - 2, 500, seed=0, plan_time_limit_s=0.5)
    assert res.congested and not res.success
    assert res.stop_time < 500 and res.stop_time % 5 == 0
    assert res.paths.shape[0] == res.stop_time + 1
    assert not res.tasks_per_step[res.stop_time :].any()


def test_pbs_failure_fallback_stays_collision_free():
    # One high-level node per replanning forces the fallback whenever agents conflict.
    res = run_checked(WAREHOUSE, "warehouse_even", 40, 150, seed=2, pbs_max_nodes=1)
    assert res.pbs_failures > 0
    assert res.finished_tasks > 0  # prioritized planning still makes progress


def test_time_limit_is_reported_and_nothing_hangs():
    big = [row * 6 for row in WAREHOUSE] * 6  # 54 x 72
    t0 = time.perf_counter()
    res = simulate(big, "warehouse_even", 800, 100_000, seed=0, time_limit_s=0.3)
    assert time.perf_counter() - t0 < 20
    assert res.timed_out and not res.success and res.stop_time < 100_000
    assert res.throughput == pytest.approx(res.finished_tasks / 100_000)


def test_uneven_prefers_left_workstations():
    def left_share(scenario):
        res = simulate(WAREHOUSE, scenario, 20, 400, seed=0)
        goals = np.concatenate(res.goals)
        cols = goals[[WAREHOUSE[r][c] == "w" for r, c, _ in goals.tolist()], 1]
        return np.mean(cols == 0), len(cols)

    even, n_even = left_share("warehouse_even")
    uneven, n_uneven = left_share("warehouse_uneven")
    assert n_even > 200 and n_uneven > 200
    assert 0.4 < even < 0.6  # three workstations per side, equal weights
    assert 0.76 < uneven < 0.9  # weights 5:1 -> 5/6


def test_simulate_many_matches_serial_runs():
    many = simulate_many(WAREHOUSE, "warehouse_even", 15, 80, seeds=[0, 1, 2], threads=2, record_paths=True)
    for res, seed in zip(many, [0, 1, 2]):
        one = simulate(WAREHOUSE, "warehouse_even", 15, 80, seed, record_paths=True)
        assert res.seed == seed and np.array_equal(res.paths, one.paths)
        check_run(res, WAREHOUSE)


def test_core_releases_the_gil():
    big = [row * 3 for row in WAREHOUSE] * 3  # 27 x 36
    box = {}
    worker = threading.Thread(
        target=lambda: box.setdefault("r", simulate(big, "warehouse_even", 150, 400, seed=0))
    )
    worker.start()
    gaps, last = [], time.perf_counter()
    while worker.is_alive():
        now = time.perf_counter()
        gaps.append(now - last)
        last = now
        time.sleep(0.001)
    worker.join()
    wall = box["r"].wall_seconds
    assert wall > 0.05
    # With the GIL held for the whole simulation this loop would stall for `wall` seconds.
    assert max(gaps) < 0.5 * wall + 0.02


@pytest.mark.parametrize(
    "rows, scenario, n, T, message",
    [
        (WAREHOUSE, "warehouse_even", 1000, 10, "traversable tiles"),
        (WAREHOUSE, "warehouse_even", 5, 0, "positive"),
        (WAREHOUSE, "warehouse_fancy", 5, 10, "unknown scenario"),
        (["e.@w", "..@."], "warehouse_even", 2, 10, "not all connected"),
        (["w.e", "@@@", "..."], "warehouse_even", 2, 10, "not all connected"),
        (["e0e1e"], "manufacturing", 1, 10, "kind-2"),
        (["x..w"], "warehouse_even", 1, 10, "unknown tile"),
    ],
)
def test_bad_input_is_a_clear_error(rows, scenario, n, T, message):
    with pytest.raises(NcaQdError, match=message):
        simulate(rows, scenario, n, T, seed=0)


def test_replan_longer_than_window_is_refused():
    with pytest.raises(NcaQdError, match="replan"):
        simulate(WAREHOUSE, "warehouse_even", 5, 10, seed=0, window=3, replan=4)


def shelf_blocks(n_rows: int, n_cols: int) -> list[str]:
    """A regular warehouse: rows of shelf blocks between endpoint rows, workstations on the sides."""
    rows = []
    for r in range(n_rows):
        if r % 4 == 0:
            rows.append("." * n_cols)
            continue
        kind = "@" if r % 4 == 2 else "e"
        inner = "".join(kind if c % 6 not in (0, 5) else "." for c in range(n_cols - 4))
        side = "w." if r % 2 else ".."
        rows.append(side + inner + side[::-1])
    return rows


# Every decision of the planner, pinned: tasks done, PBS nodes, A* expansions and a digest of
# every agent's path. A speed-up of the core must leave all of these unchanged; a change that
# alters them alters simulated outcomes, so it must bump the core's VERSION (bindings.cpp) and
# update these figures together.
@pytest.mark.parametrize(
    "case, rows, scenario, n, T, kw, expected",
    [
        ("flows", shelf_blocks(17, 22), "warehouse_even", 40, 300, {},
         (739, 300, 0, 1414, 66111, "224a28423607a7d4")),
        ("failed calls", shelf_blocks(17, 22), "warehouse_uneven", 70, 300, {"pbs_max_nodes": 100},
         (1210, 300, 29, 5731, 359019, "e1714905445f6ef1")),
        ("dwell", MANUFACTURING, "manufacturing", 14, 200, {},
         (185, 200, 0, 346, 35768, "265586f0a21ddc21")),
        # more than 64 agents above others in one search (the closure's rows widen)
        ("deep priority order", shelf_blocks(21, 28), "warehouse_uneven", 120, 150, {"pbs_max_nodes": 300},
         (791, 150, 0, 5844, 652790, "c6441840156b9705")),
    ],
)  # fmt: skip
def test_planner_decisions_are_pinned(case, rows, scenario, n, T, kw, expected):
    assert VERSION == 4, "the pinned figures are version 4's: update them with the version"
    res = run_checked(rows, scenario, n, T, plan_time_limit_s=None, **kw)
    digest = hashlib.sha256(np.ascontiguousarray(res.paths, dtype=np.int32).tobytes()).hexdigest()[:16]
    work = (res.pbs_failures, res.pbs_nodes, res.low_level_expansions)
    assert (res.finished_tasks, res.stop_time, *work, digest) == expected, case


def test_a_work_cap_stops_planning_calls_at_the_same_point_every_time():
    # The "failed calls" case above: 70 agents, a node budget generous enough that calls search
    # far. A cap on A* expansions well below what the largest calls use makes those calls fail
    # (and be repaired, collision-free); two runs with the same cap are the same run, and a cap
    # above every call's expansions is no cap at all.
    rows, kw = shelf_blocks(17, 22), {"pbs_max_nodes": 2000, "plan_time_limit_s": None}
    free = run_checked(rows, "warehouse_uneven", 70, 300, **kw)
    per_call = free.call_expansions
    assert per_call is not None and per_call.sum() == free.low_level_expansions
    cap = int(np.percentile(per_call, 90))
    capped = [run_checked(rows, "warehouse_uneven", 70, 300, plan_max_expansions=cap, **kw) for _ in range(2)]
    assert capped[0].pbs_failures > free.pbs_failures
    # a call stops at the first node expansion after reaching the cap
    assert (capped[0].call_expansions[capped[0].call_failed] >= cap).any()
    a, b = capped
    assert (a.finished_tasks, a.pbs_nodes, a.low_level_expansions) == (
        b.finished_tasks,
        b.pbs_nodes,
        b.low_level_expansions,
    )
    assert np.array_equal(a.paths, b.paths)
    loose = run_checked(rows, "warehouse_uneven", 70, 300, plan_max_expansions=int(per_call.max()) + 1, **kw)
    assert (loose.pbs_failures, loose.low_level_expansions) == (free.pbs_failures, free.low_level_expansions)
    assert np.array_equal(loose.paths, free.paths)


@pytest.mark.parametrize("bad", [0, -5, True, 2.5, "many"])
def test_a_bad_work_cap_is_a_clear_error(bad):
    from nca_qd.sim.rhcr import planner_options

    with pytest.raises(NcaQdError, match="plan_max_expansions"):
        simulate(WAREHOUSE, "warehouse_even", 5, 20, 0, plan_max_expansions=bad)
    with pytest.raises(NcaQdError, match="eval.plan_max_expansions"):
        planner_options({"plan_max_expansions": bad}, "eval.")
    assert planner_options({"plan_max_expansions": None}) == {}
