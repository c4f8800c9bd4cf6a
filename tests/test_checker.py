"""The independent path checker: it must accept legal runs and catch every kind of violation."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from nca_qd.sim.checker import (
    CheckError,
    check_goals,
    check_moves,
    check_run,
    recount_tasks,
    traversable_mask,
)

ROWS = [
    "w...e",
    ".@@.e",
    "w...e",
]
MASK = traversable_mask(ROWS, "warehouse_even")


def paths_of(*tracks):
    """Build [S+1, N, 2] from per-agent lists of (row, col)."""
    return np.array(tracks, dtype=np.int32).transpose(1, 0, 2)


def test_legal_moves_pass():
    check_moves(paths_of([(0, 0), (0, 1), (0, 2), (0, 2)], [(2, 0), (2, 0), (2, 1), (2, 2)]), MASK)


@pytest.mark.parametrize(
    "tracks, message",
    [
        (([(0, 0), (0, 1)], [(0, 2), (0, 1)]), "vertex conflict"),
        (([(0, 0), (0, 1)], [(0, 1), (0, 0)]), "swap conflict"),
        (([(0, 0), (0, 2)], [(2, 0), (2, 0)]), "jumps"),
        (([(0, 2), (1, 3)], [(2, 0), (2, 0)]), "jumps"),  # diagonal
        (([(0, 3), (1, 3), (1, 2)], [(2, 0), (2, 0), (2, 0)]), "non-traversable"),
        (([(0, 4), (0, 5)], [(2, 0), (2, 0)]), "off the map"),
        (([(0, 0)], [(0, 0)]), "vertex conflict"),  # already at time 0
    ],
)
def test_violations_are_caught(tracks, message):
    with pytest.raises(CheckError, match=message):
        check_moves(paths_of(*tracks), MASK)


def test_manufacturing_stations_are_not_traversable():
    mask = traversable_mask(["e0.", "e1.", "e2."], "manufacturing")
    assert mask.tolist() == [[True, False, True]] * 3


def test_recount_dwell_rules():
    goal = np.array([[0, 1, 2], [0, 3, 0]])  # stay 2 extra steps on (0,1), then (0,3)
    stays = paths_of([(0, 0), (0, 1), (0, 1), (0, 1), (0, 2), (0, 3)])
    assert recount_tasks(stays, [goal]).tolist() == [0, 0, 1, 0, 1]
    leaves = paths_of([(0, 0), (0, 1), (0, 1), (0, 2), (0, 1), (0, 1)])
    assert recount_tasks(leaves, [goal]).tolist() == [0, 0, 0, 0, 0]  # left before dwell done
    order = paths_of([(0, 2), (0, 3), (0, 2), (0, 1), (0, 1), (0, 1)])
    assert recount_tasks(order, [goal]).tolist() == [0, 0, 0, 0, 1]  # (0,3) before (0,1): no


def test_goal_rules():
    check_goals([np.array([[0, 4, 0], [0, 0, 0], [1, 4, 0]])], ROWS, "warehouse_even")
    with pytest.raises(CheckError, match="may not follow"):
        check_goals([np.array([[0, 4, 0], [1, 4, 0]])], ROWS, "warehouse_even")
    with pytest.raises(CheckError, match="dwell"):
        check_goals([np.array([[0, 4, 3]])], ROWS, "warehouse_even")
    man = ["e0e1e2e"]
    check_goals([np.array([[0, 2, 2], [0, 4, 5], [0, 6, 10], [0, 0, 2]])], man, "manufacturing")
    with pytest.raises(CheckError, match="matching kind"):
        check_goals([np.array([[0, 6, 2]])], man, "manufacturing")
    with pytest.raises(CheckError, match="may not follow"):
        check_goals([np.array([[0, 2, 5], [0, 4, 10], [0, 2, 5]])], man, "manufacturing")


def test_check_run_compares_counts():
    paths = paths_of([(0, 3), (0, 4), (1, 4), (2, 4)], [(2, 1), (2, 0), (2, 0), (2, 1)])
    goals = [np.array([[0, 4, 0], [0, 0, 0]]), np.array([[2, 0, 0], [2, 4, 0]])]
    res = SimpleNamespace(
        paths=paths,
        goals=goals,
        tasks_per_step=np.array([2, 0, 0, 0]),
        stop_time=3,
        T=4,
        throughput=0.5,
        scenario="warehouse_even",
    )
    report = check_run(res, ROWS)
    assert report.finished_tasks == 2 and report.n_steps == 3
    res.tasks_per_step = np.array([1, 1, 0, 0])
    with pytest.raises(CheckError, match="differ at time 1"):
        check_run(res, ROWS)
    res.tasks_per_step = np.array([2, 0, 0, 0])
    res.throughput = 0.75
    with pytest.raises(CheckError, match="throughput"):
        check_run(res, ROWS)
