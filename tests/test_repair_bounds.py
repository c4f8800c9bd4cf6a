"""The repair's other lower bounds (benchmarks/repair_bounds.py, issue 54): never above the
proven optimum of the full MILP, and the separator cuts see what the flow's LP misses."""

import numpy as np
import pytest

from benchmarks.repair_bounds import separator_lp, without_connectivity
from nca_qd.layouts import warehouse as wh
from nca_qd.repair import make_rules, repair
from nca_qd.repair.milp import solve_window
from nca_qd.repair.validator import violations


@pytest.mark.parametrize("seed", [0, 4])
def test_bounds_never_exceed_the_proven_optimum(seed):
    rng = np.random.default_rng(seed)
    lay = wh.assemble(rng.integers(0, 3, size=(7, 6)).astype(np.int32))
    rules = make_rules("warehouse_even", lay.shape, n_shelves=6)
    full = repair("warehouse_even", lay, n_shelves=6, method="full", time_limit_s=60)
    assert full.status == "optimal"
    status, optimum, bound, _ = without_connectivity(full.layout, lay, rules, 60)
    assert status == "optimal" and bound <= optimum <= full.objective
    sep, rounds, _, _ = separator_lp(full.layout, lay, rules)
    assert sep is not None and sep <= full.objective and rounds >= 1


def test_an_enclosed_endpoint_costs_what_only_the_separator_cuts_see():
    """An endpoint walled in by its four shelves satisfies every rule but connectivity: the MILP
    without connectivity keeps it (distance 0), the flow's LP bound stays below the optimum
    (fractional passable values carry its flow), and the separator cuts prove the optimum."""
    storage = np.zeros((5, 5), np.int32)
    storage[2, 2] = 2
    storage[1, 2] = storage[3, 2] = storage[2, 1] = storage[2, 3] = 1
    lay = wh.assemble(storage)
    rules = make_rules("warehouse_even", lay.shape, n_shelves=4)
    kinds = {v.constraint for v in violations(lay, rules)}
    assert kinds == {"connectivity"}, kinds
    full = repair("warehouse_even", lay, n_shelves=4, method="full", time_limit_s=60)
    assert full.status == "optimal" and full.objective == 2
    assert without_connectivity(full.layout, lay, rules, 60)[1] == 0
    flow_lp = solve_window(full.layout, lay, ~rules.fixed, rules, relaxation=True).bound
    sep, _, cuts, _ = separator_lp(full.layout, lay, rules)
    assert flow_lp < sep == full.objective and cuts > 0
