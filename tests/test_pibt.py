"""The lifelong PIBT planner of the compiled core (``planner="pibt"``): every run goes through
the independent checker (nca_qd/sim/checker.py), as RHCR's do."""

from __future__ import annotations

from collections import deque

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from sim_layouts import MANUFACTURING, WAREHOUSE
from test_rhcr import manufacturing_maps, warehouse_maps

from nca_qd.errors import NcaQdError
from nca_qd.sim.checker import check_run, traversable_mask
from nca_qd.sim.rhcr import planner_options, simulate
from nca_qd.sim.scenario import build_scenario


def run_checked(rows, scenario, n_agents, T, seed=0, planner="pibt"):
    res = simulate(rows, scenario, n_agents, T, seed, record_paths=True, planner=planner)
    report = check_run(res, rows)  # no vertex or swap conflict, only moves, goals recounted
    assert report.finished_tasks == res.finished_tasks
    assert res.tile_visits.sum() == n_agents * res.stop_time
    assert res.throughput == pytest.approx(res.finished_tasks / T)
    return res


def bfs(rows, scenario, goal):
    free = traversable_mask(rows, scenario)
    dist = np.full(free.shape, -1)
    dist[goal] = 0
    todo = deque([goal])
    while todo:
        r, c = todo.popleft()
        for nr, nc in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)):
            if 0 <= nr < free.shape[0] and 0 <= nc < free.shape[1] and free[nr, nc] and dist[nr, nc] < 0:
                dist[nr, nc] = dist[r, c] + 1
                todo.append((nr, nc))
    return dist


def test_warehouse_and_manufacturing_runs_are_valid_and_productive():
    res = run_checked(WAREHOUSE, "warehouse_even", 20, 300)
    assert res.success and res.stop_time == 300 and res.finished_tasks > 100
    assert res.tile_visits[np.array([list(r) for r in WAREHOUSE]) == "@"].sum() == 0
    res = run_checked(MANUFACTURING, "manufacturing", 12, 300)
    assert res.success and res.finished_tasks > 30
    assert {int(d) for g in res.goals for d in g[:, 2]} == {2, 5, 10}  # dwells kept (the checker)


def test_a_lone_agent_takes_shortest_paths_between_its_goals():
    """Nothing in its way, PIBT moves an agent one cell nearer its goal every step: each leg
    takes exactly the BFS distance (computed here, not by the core), each dwell its dwell."""
    for rows, scenario in ((WAREHOUSE, "warehouse_even"), (MANUFACTURING, "manufacturing")):
        res = simulate(rows, scenario, 1, 200, seed=5, record_paths=True, planner="pibt")
        path = [tuple(p) for p in res.paths[:, 0].tolist()]
        t, here = 0, path[0]
        for r, c, dwell in res.goals[0][: res.finished_tasks].tolist():
            legs = bfs(rows, scenario, (r, c))[here]
            # at the goal at t + legs (or at t + 1 when it starts there: a step to "arrive")
            arrive = t + max(legs, 1)
            assert path[arrive] == (r, c) and all(p == (r, c) for p in path[arrive : arrive + dwell + 1])
            if legs > 0:
                assert path[arrive - 1] != (r, c)
            t, here = arrive + dwell, (r, c)


def test_same_seed_same_run_other_seed_other_run_and_not_rhcrs():
    a = simulate(WAREHOUSE, "warehouse_even", 15, 100, seed=3, record_paths=True, planner="pibt")
    b = simulate(WAREHOUSE, "warehouse_even", 15, 100, seed=3, record_paths=True, planner="pibt")
    c = simulate(WAREHOUSE, "warehouse_even", 15, 100, seed=4, record_paths=True, planner="pibt")
    r = simulate(WAREHOUSE, "warehouse_even", 15, 100, seed=3, record_paths=True)
    assert np.array_equal(a.paths, b.paths) and np.array_equal(a.tasks_per_step, b.tasks_per_step)
    assert not np.array_equal(a.paths, c.paths)
    assert np.array_equal(a.paths[0], r.paths[0])  # the same start cells as RHCR's run
    assert not np.array_equal(a.paths, r.paths)


def test_a_one_lane_corridor_deadlocks_and_the_run_stops_as_congested():
    """Agents that must pass each other in a one-cell-wide corridor cannot: PIBT stops them all
    (its guarantee needs a biconnected graph), and RHCR's rule ends the run. (On WAREHOUSE's
    loops 91 agents on 92 free cells still flow under PIBT.)"""
    rows = ["w.e.e.e.e.e.w"]
    for seed in range(3):
        res = run_checked(rows, "warehouse_even", 4, 200, seed=seed)
        assert res.congested and not res.success
        assert res.stop_time < 50 and res.stop_time % 5 == 0
        assert not res.tasks_per_step[res.stop_time :].any()
    n_free = build_scenario(WAREHOUSE, "warehouse_even").n_traversable
    assert run_checked(WAREHOUSE, "warehouse_even", n_free - 1, 100).success


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(
    rows=warehouse_maps(),
    scenario=st.sampled_from(["warehouse_even", "warehouse_uneven"]),
    density=st.floats(0.05, 1.0),
    T=st.integers(1, 60),
    seed=st.integers(0, 2**32),
    planner=st.sampled_from(["pibt", "pibt_swap"]),
)
def test_random_warehouses_always_valid(rows, scenario, density, T, seed, planner):
    try:
        scen = build_scenario(rows, scenario)
    except NcaQdError:
        scen = None
    assume(scen is not None)
    n = max(1, int(density * scen.n_traversable))
    res = run_checked(rows, scenario, n, T, seed=seed, planner=planner)
    assert res.success == (res.stop_time == T and not res.congested)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(
    rows=manufacturing_maps(),
    density=st.floats(0.05, 1.0),
    T=st.integers(1, 60),
    seed=st.integers(0, 2**32),
    planner=st.sampled_from(["pibt", "pibt_swap"]),
)
def test_random_manufacturing_always_valid(rows, density, T, seed, planner):
    """Dwelling agents stay put whoever asks them to move (the checker recounts the dwells)."""
    try:
        scen = build_scenario(rows, "manufacturing")
    except NcaQdError:
        scen = None
    assume(scen is not None)
    n = max(1, int(density * scen.n_traversable))
    run_checked(rows, "manufacturing", n, T, seed=seed, planner=planner)


POCKETS = ["w.........w", "...........", "@e@e@e@e@e@"]  # endpoints in dead-end pockets


def test_a_dead_end_pocket_deadlocks_pibt_and_pibt_with_swap_clears_it():
    """An agent waiting at a pocket's mouth outranks the one leaving it (whose priority restarted
    with its new goal): the leaver's only move is the waiter's cell, a swap PIBT forbids, so
    both stand still for good and the corridor behind them fills. PIBT with swap backs the
    waiter up and pulls the leaver out. Every run through the independent checker."""
    for seed in range(5):
        plain = run_checked(POCKETS, "warehouse_even", 4, 500, seed=seed)
        assert plain.congested and plain.finished_tasks < 40
        res = run_checked(POCKETS, "warehouse_even", 4, 500, seed=seed, planner="pibt_swap")
        assert res.success and res.finished_tasks > 60
        assert np.array_equal(res.paths[0], plain.paths[0])  # the same start cells
    # On two-lane loops both flow, and they are different planners (LaCAM3's ties: no
    # preference for cells free now).
    for seed in range(3):
        a = run_checked(WAREHOUSE, "warehouse_even", 40, 200, seed=seed)
        b = run_checked(WAREHOUSE, "warehouse_even", 40, 200, seed=seed, planner="pibt_swap")
        assert a.success and b.success and not np.array_equal(a.paths, b.paths)


def test_the_planner_setting_is_checked_and_keys_rhcr_runs_as_before():
    assert planner_options({"planner": "pibt"}) == {"planner": "pibt"}
    assert planner_options({"planner": "pibt_swap"}) == {"planner": "pibt_swap"}
    assert planner_options({"planner": "rhcr"}) == {}  # as before the setting existed
    with pytest.raises(NcaQdError, match="exact.planner must be one of rhcr, pibt, pibt_swap"):
        planner_options({"planner": "lacam"}, "exact.")
    with pytest.raises(NcaQdError, match="planner must be one of"):
        simulate(WAREHOUSE, "warehouse_even", 5, 10, 0, planner="PIBT")


def test_an_exact_run_of_pibt_is_remembered_apart_from_rhcrs():
    from nca_qd.scoring.jobs import ExactSettings
    from nca_qd.scoring.keys import exact_run_key

    rhcr = ExactSettings(100, None, 10, 5, planner_options({"planner": "rhcr"}))
    pibt = ExactSettings(100, None, 10, 5, planner_options({"planner": "pibt"}))
    assert exact_run_key(WAREHOUSE, "warehouse_even", 10, 0, rhcr) != exact_run_key(
        WAREHOUSE, "warehouse_even", 10, 0, pibt
    )
    assert exact_run_key(WAREHOUSE, "warehouse_even", 10, 0, rhcr) == exact_run_key(
        WAREHOUSE, "warehouse_even", 10, 0, ExactSettings(100, None, 10, 5, {})
    )


def test_planners_are_titled_for_tables_and_legends():
    from nca_qd.sim.rhcr import PLANNERS, planner_title

    titles = {p: planner_title(p) for p in PLANNERS}
    assert titles == {"rhcr": "RHCR", "pibt": "PIBT", "pibt_swap": "PIBT with swap"}
