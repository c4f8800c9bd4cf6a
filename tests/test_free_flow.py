"""Free-flow throughput (nca_qd.sim.free_flow) against an independent breadth-first search, a
corridor whose answer is known by hand, the simulators it bounds, and the screen's estimate."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from sim_layouts import MANUFACTURING, WAREHOUSE, bfs_distances, small_warehouses

from nca_qd.errors import NcaQdError
from nca_qd.sim.free_flow import free_flow_throughput, mean_leg_cost, rhcr_estimate
from nca_qd.sim.scenario import build_scenario


def _leg_cost_by_hand(scen) -> float:
    """mean_leg_cost by a plain double loop over weighted goal pairs."""
    cycle = list(scen.cycle)
    total = 0.0
    for a, b in zip(cycle, cycle[1:] + cycle[:1]):
        ca, cb = scen.classes[a], scen.classes[b]
        leg = 0.0
        for cell, wa in zip(ca.cells, ca.weights):
            d = bfs_distances(scen.traversable, int(cell), -1)
            assert (d[cb.cells] >= 0).all()  # build_scenario checked that every goal is reachable
            leg += (
                wa
                / ca.weights.sum()
                * sum(wb / cb.weights.sum() * d[int(g)] for g, wb in zip(cb.cells, cb.weights))
            )
        total += leg + cb.dwell
    return total / len(cycle)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(rows=small_warehouses())
def test_mean_leg_cost_matches_an_independent_search(rows):
    try:
        scen = build_scenario(rows, "warehouse_even", n_agents=4)
    except NcaQdError:
        assume(False)
    assert mean_leg_cost(scen) == pytest.approx(_leg_cost_by_hand(scen), rel=1e-9)


def test_a_corridor_by_hand():
    """Endpoint at one end, workstation at the other, 10 cells apart: every leg is 10 steps, no
    dwell (warehouse), so n agents finish n/10 tasks per step."""
    rows = ["e.........w"]
    scen = build_scenario(rows, "warehouse_even", n_agents=3)
    assert mean_leg_cost(scen) == pytest.approx(10.0)
    assert free_flow_throughput(scen, 3) == pytest.approx(0.3)


def test_manufacturing_dwell_times_add_to_the_legs():
    scen = build_scenario(MANUFACTURING, "manufacturing", n_agents=4)
    dwell = np.mean([scen.classes[c].dwell for c in scen.cycle])
    moving = mean_leg_cost(scen) - dwell
    assert dwell > 0 and moving > 0
    assert _leg_cost_by_hand(scen) == pytest.approx(mean_leg_cost(scen))


def test_free_flow_bounds_exact_rhcr():
    """No agent is faster than free flow: exact RHCR's long-run throughput stays below it."""
    from nca_qd.sim.rhcr import simulate

    n = 8
    bound = free_flow_throughput(build_scenario(WAREHOUSE, "warehouse_even", n_agents=n), n)
    for seed in (0, 1):
        res = simulate(WAREHOUSE, "warehouse_even", n_agents=n, T=400, seed=seed)
        assert 0 < res.throughput <= bound * 1.02  # the first legs start anywhere: 2 % slack
        assert res.throughput > 0.5 * bound  # 8 agents on this map flow


def test_rhcr_estimate_takes_free_flow_where_all_runs_flow_and_the_fitted_share_elsewhere():
    thr = [[4.0, 4.5, 5.0], [1.0, 2.0, 0.5], [4.0, 4.0, 4.0]]
    ok = [[True, True, True], [True, False, False], [True, True, False]]
    stop = [[1.0, 1.0, 1.0], [1.0, 0.2, 0.3], [1.0, 1.0, 0.9]]
    est = rhcr_estimate(thr, ok, stop, free_flow=[7.0, 6.0, 8.0], efficiency=0.9, congested=(0.3, 2.0, -1.0))
    share = 0.3 + 2.0 * (3.5 / 3) / 6.0 - 1.0 * 0.5  # 0.1889
    # the third: 0.3 + 2 * 4 / 8 - 0.9667 = 0.333
    np.testing.assert_allclose(est, [0.9 * 7.0, share * 6.0, (0.3 + 1.0 - 2.9 / 3) * 8.0])
    # the share stays within [0, efficiency]
    high = rhcr_estimate([[6.0, 7.0]], [[True, False]], [[1.0, 0.99]], [7.0], 0.9, congested=(0.3, 2.0, -1.0))
    low = rhcr_estimate([[0.0, 0.0]], [[False, False]], [[0.1, 0.1]], [7.0], 0.9, congested=(0.0, 1.0, -1.0))
    np.testing.assert_allclose([high[0], low[0]], [0.9 * 7.0, 0.0])
    with pytest.raises(ValueError, match="runs on the last axis"):
        rhcr_estimate(np.zeros((2, 0)), np.zeros((2, 0), bool), np.zeros((2, 0)), [7.0, 6.0], 0.9)
