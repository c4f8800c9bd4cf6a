"""The screen's windowed prioritized planner (planner="windowed"): checked paths, the planner's
rules on hand-made cases, RHCR's congestion rule, determinism."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from sim_layouts import MANUFACTURING, WAREHOUSE, small_warehouses

from nca_qd.errors import NcaQdError
from nca_qd.sim import screen
from nca_qd.sim.checker import check_run, recount_tasks
from nca_qd.sim.scenario import build_scenario
from nca_qd.sim.screen import simulate, simulate_batch
from nca_qd.sim.screen_windowed import plan_window

N, T = 12, 40  # shared, so that most tests reuse one compiled program
CROWDED = [  # WAREHOUSE's shape with 30 open tiles
    "w..........w",
    "@e@@@..@@@e@",
    "@.@@@..@@@.@",
    "@e@@@..@@@e@",
    "w..........w",
    "@@@@@@@@@@@@",
    "@@@@@@@@@@@@",
    "@@@@@@@@@@@@",
    "@@@@@@@@@@@@",
]
WIN = "windowed"


def run_checked(rows, scenario, n_agents=N, horizon=T, seed=0):
    res = simulate(rows, scenario, n_agents, horizon, seed, record_paths=True, planner=WIN)
    report = check_run(res, rows)
    assert report.finished_tasks == res.finished_tasks
    assert res.throughput == pytest.approx(recount_tasks(res.paths, res.goals).sum() / horizon)
    assert res.tile_visits.sum() == n_agents * res.stop_time
    assert res.tasks_per_step.shape == (horizon,)
    return res


def test_warehouse_and_manufacturing_runs_pass_the_checker():
    w = run_checked(WAREHOUSE, "warehouse_even")
    assert w.success and w.stop_time == T and w.finished_tasks > 0
    assert run_checked(WAREHOUSE, "warehouse_uneven", seed=3).finished_tasks > 0
    m = run_checked(MANUFACTURING, "manufacturing")
    assert m.finished_tasks > 0
    assert {int(d) for g in m.goals for d in g[:, 2]} <= {2, 5, 10}
    # 12 agents on 30 open tiles (the same shape, so the same compiled program): many plans
    # are stuck, and the agents that wait stay reserved in place (the checker finds no conflict)
    dense = run_checked(CROWDED, "warehouse_even", seed=1)
    waits = (np.abs(np.diff(dense.paths, axis=0)).sum(-1) == 0).sum()
    assert dense.finished_tasks > 0 and waits >= 40, waits


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(rows=small_warehouses(), seed=st.integers(0, 1000))
def test_random_layouts_pass_the_checker(rows, seed):
    try:
        build_scenario(rows, "warehouse_even", n_agents=N)
    except NcaQdError:
        assume(False)
    run_checked(rows, "warehouse_even", seed=seed)


CORRIDOR = ["@@@@@@@@@@@", "@.........@", "@@@@@@.@@@@"]  # a pocket below column 6


def _grid(rows):
    return np.array([[ch != "@" for ch in r] for r in rows])


def _conflict_free(paths):
    cells = paths[..., 0] * 100 + paths[..., 1]  # [N, w+1]
    for t in range(cells.shape[1]):
        assert len(set(cells[:, t])) == cells.shape[0], f"vertex conflict at {t}"
        if t:
            moves = {(a, b) for a, b in zip(cells[:, t - 1], cells[:, t]) if a != b}
            assert not any((b, a) in moves for a, b in moves), f"swap at {t}"
    steps = np.abs(np.diff(paths, axis=1)).sum(-1)
    assert (steps <= 1).all()


def test_corridor_swap_the_lower_agent_waits_in_the_pocket():
    starts, goals = [(1, 1), (1, 8)], [(1, 9), (1, 1)]
    paths, stuck = plan_window(_grid(CORRIDOR), starts, goals, order=[0, 1])
    _conflict_free(paths)
    assert not stuck.any()
    # the first agent walks straight to its goal (8 steps) and stays there
    assert [tuple(p) for p in paths[0]] == [(1, c) for c in range(1, 10)] + [(1, 9)] * 2
    # the second steps into the pocket while the first passes, then heads for its goal
    assert (2, 6) in [tuple(p) for p in paths[1]]
    assert tuple(paths[1, -1]) == (1, 2)  # w + distance 1: the best reachable at step w


def test_an_agent_without_a_path_stays_and_is_reserved_in_place():
    """Reversed order: the agent at the corridor's dead end cannot get out of the way in time,
    stays where it is, and the first agent (replanned around it) stops next to it."""
    paths, stuck = plan_window(_grid(CORRIDOR), [(1, 1), (1, 8)], [(1, 9), (1, 1)], order=[1, 0])
    _conflict_free(paths)
    assert stuck.tolist() == [True, False]
    assert (paths[0] == (1, 1)).all()
    assert tuple(paths[1, -1]) == (1, 2)


@pytest.mark.parametrize("order", [[0, 1], [1, 0]])
def test_the_priority_order_decides_who_waits(order):
    """Two agents whose shortest paths cross one cell at the same time: the first in the order
    arrives in its distance (4), the other one step later."""
    starts, goals = [(0, 2), (2, 0)], [(4, 2), (2, 4)]
    paths, stuck = plan_window(np.ones((5, 5), bool), starts, goals, order=order)
    _conflict_free(paths)
    arrival = [int(np.argmax((paths[a] == goals[a]).all(-1))) for a in range(2)]
    hi, lo = order
    assert arrival[hi] == 4 and arrival[lo] == 5 and not stuck.any()


def test_goal_beyond_the_window_heads_for_it():
    # a second agent walled off in row 4 (so that the call has two agents, as the other
    # plan_window tests: one compiled program for all of them)
    grid = np.ones((5, 30), bool)
    grid[3] = False
    paths, stuck = plan_window(grid, [(1, 0), (4, 0)], [(1, 29), (4, 0)])
    assert not stuck.any() and tuple(paths[0, -1]) == (1, 10)
    assert (paths[1] == (4, 0)).all()


def test_a_goal_done_inside_the_window_leads_on_to_the_next_one():
    """As RHCR's goal sequence: an agent does not park on a goal it finishes inside the window
    (blocking the aisle for the rest of it): it stands its dwell there, then heads on."""
    grid = np.ones((3, 30), bool)
    starts, goals, nxt = [(0, 0), (2, 0)], [(0, 2), (2, 2)], [(0, 8), (2, 8)]
    paths, stuck = plan_window(grid, starts, goals, next_goals=nxt, dwell=[0, 3])
    assert not stuck.any()
    assert [tuple(x) for x in paths[0]] == [(0, c) for c in range(9)] + [(0, 8)] * 2
    assert [tuple(x) for x in paths[1]] == [(2, 0), (2, 1)] + [(2, 2)] * 4 + [(2, c) for c in range(3, 8)]


def test_congestion_stops_a_jammed_run_and_not_an_open_one():
    # 1-wide, every tile taken: nobody can ever move (WAREHOUSE's shape and N agents, so the
    # compiled program of the other runs serves)
    corridor = ["w" + "e" * (len(WAREHOUSE[0]) - 2) + "w"] + ["@" * len(WAREHOUSE[0])] * (len(WAREHOUSE) - 1)
    assert sum(r.count(".") + r.count("e") + r.count("w") for r in corridor) == N
    res = simulate(corridor, "warehouse_even", N, T, 0, record_paths=True, planner=WIN)
    assert res.congested and not res.success and res.stop_time == 5  # the first check
    check_run(res, corridor)
    assert res.tasks_per_step[5:].sum() == 0
    free = run_checked(WAREHOUSE, "warehouse_even", seed=2)
    assert free.success and not free.congested


def test_deterministic_per_seed_and_batch_equals_one_at_a_time():
    a = simulate(WAREHOUSE, "warehouse_even", N, T, 7, record_paths=True, planner=WIN)
    b = simulate(WAREHOUSE, "warehouse_even", N, T, 7, record_paths=True, planner=WIN)
    c = simulate(WAREHOUSE, "warehouse_even", N, T, 8, record_paths=True, planner=WIN)
    np.testing.assert_array_equal(a.paths, b.paths)
    assert a.throughput == b.throughput and not np.array_equal(a.paths, c.paths)
    other = [r.replace("@", ".") if i == 6 else r for i, r in enumerate(WAREHOUSE)]
    batch = simulate_batch([WAREHOUSE, other], "warehouse_even", N, T, [7, 8], record_paths=True, planner=WIN)
    np.testing.assert_array_equal(batch[0][0].paths, a.paths)
    np.testing.assert_array_equal(batch[0][1].paths, c.paths)
    one = simulate(other, "warehouse_even", N, T, 8, record_paths=True, planner=WIN)
    np.testing.assert_array_equal(batch[1][1].paths, one.paths)
    check_run(batch[1][0], other)


@pytest.mark.parametrize(
    "option, message",
    [
        ({"planner": "astar"}, "planner"),
        ({"planner": WIN, "congestion": "crowding"}, "congestion rule"),
        ({"planner": WIN, "priority": "age"}, "random order"),
        ({"planner": WIN, "replan": 11}, "window"),
    ],
)
def test_bad_options_error_before_compilation(monkeypatch, option, message):
    monkeypatch.setattr(screen, "_batched", lambda *a, **k: pytest.fail("compiled"))
    with pytest.raises(NcaQdError, match=message):
        simulate_batch([WAREHOUSE], "warehouse_even", 5, 10, [0], **option)
