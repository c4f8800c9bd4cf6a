"""Single windowed-PBS calls on hand-made cases whose outcome RHCR's planner decides.

Each case runs one planning call through ``_core.plan`` and checks the paths with the
independent checker's movement rules (no two agents on a tile, no swaps, legal moves).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nca_qd.sim.checker import check_moves
from nca_qd.sim.rhcr import _core

W, H = 10, 5  # window, executed steps


def grid(rows: list[str]) -> np.ndarray:
    return np.array([[ch != "@" for ch in r] for r in rows], dtype=np.uint8)


def cell(rows: list[str], r: int, c: int) -> int:
    return r * len(rows[0]) + c


def plan(rows, starts, goals, **kw):
    out = _core.plan(
        grid(rows),
        [cell(rows, *s) for s in starts],
        [[cell(rows, *g) for g in gs] for gs in goals],
        **{"window": W, "executed_steps": H, **kw},
    )
    return out["solved"], out["nodes"], out["paths"]


def as_rc(paths: np.ndarray, width: int, steps: int) -> np.ndarray:
    """Planned cells of times 0..steps as [steps + 1, agents, 2] (the checker's layout)."""
    p = paths[:, : steps + 1].T
    assert (p >= 0).all(), "a path ends inside the executed steps"
    return np.stack([p // width, p % width], axis=-1)


def planned_prefix(paths: np.ndarray) -> int:
    """Last time at which every agent still has a planned cell."""
    present = (paths >= 0).all(axis=0)
    return int(np.argmin(present)) - 1 if not present.all() else paths.shape[1] - 1


# A corridor with one side pocket: two agents must pass each other.
CORRIDOR = ["@@@@@@@@@", "@.......@", "@@@@.@@@@", "@@@@@@@@@"]


def test_corridor_swap_needs_a_branch_and_stays_collision_free():
    # Head-on in a corridor: the shortest paths collide, so PBS must branch on the pair; the
    # solution it settles for is collision-free within the window.
    solved, nodes, paths = plan(CORRIDOR, [(1, 1), (1, 7)], [[(1, 7)], [(1, 1)]])
    assert solved and nodes >= 1
    check_moves(as_rc(paths, len(CORRIDOR[0]), planned_prefix(paths)), grid(CORRIDOR).astype(bool))


OPEN = ["......"] * 6  # 6 x 6, no obstacles: many equally short routes between corners


@pytest.mark.parametrize(
    "start, goal, first, then",
    [
        ((5, 5), (0, 0), (0, -1), (-1, 0)),  # up-left: west first, then north
        ((0, 0), (5, 5), (1, 0), (0, 1)),  # down-right: south first, then east
        ((5, 0), (0, 5), (-1, 0), (0, 1)),  # up-right: north first, then east
        ((0, 5), (5, 0), (1, 0), (0, -1)),  # down-left: south first, then west
    ],
)
def test_an_agent_keeps_to_rhcrs_last_direction_among_equal_routes(start, goal, first, then):
    # RHCR's SIPP generates moves east, north, west, south and expands the newest of equally
    # good nodes, so among equally short routes an agent keeps going in the last of these
    # directions that still leads closer: an L-shaped route. (Breaking ties the other way
    # picks other routes, and agents meet more often: 10 % more root conflicts in a 340-agent
    # planning call of the paper's warehouse.)
    solved, _, paths = plan(OPEN, [start], [[goal]])
    assert solved
    rc = np.stack([paths[0] // 6, paths[0] % 6], axis=1)
    steps = np.diff(rc, axis=0)
    expected = [first] * 5 + [then] * 5
    assert [tuple(s) for s in steps] == expected


def test_pocket_lets_the_lower_agent_give_way():
    # With the pocket next to agent 0, one child of the root conflict sends it into the
    # pocket while agent 1 passes; PBS finds that plan and agent 1 reaches its goal.
    rows = ["@@@@@@@@@", "@.......@", "@@.@@@@@@", "@@@@@@@@@"]
    solved, _, paths = plan(rows, [(1, 1), (1, 7)], [[(1, 7)], [(1, 1)]], prioritize_start=False)
    assert solved
    check_moves(as_rc(paths, len(rows[0]), planned_prefix(paths)), grid(rows).astype(bool))
    assert (paths[0] == cell(rows, 2, 2)).any()
    assert cell(rows, 1, 1) in paths[1]


def test_a_waiting_agent_keeps_its_start_cell():
    # Agent 1 stands on its goal at the end of a dead end; agent 0 wants the same cell. With
    # prioritize_start agent 1 keeps its cell until its path ends and agent 0 waits in front
    # of it; without, PBS pushes agent 1 off its cell and back.
    rows = ["@@@@@@", "@....@", "@@@@@@"]
    starts, goals = [(1, 1), (1, 4)], [[(1, 4)], [(1, 4)]]
    end = cell(rows, 1, 4)
    solved, _, paths = plan(rows, starts, goals)
    assert solved
    check_moves(as_rc(paths, len(rows[0]), planned_prefix(paths)), grid(rows).astype(bool))
    left = int(np.argmax(paths[1] != end))  # agent 1's path ends (-1) here
    assert left >= H and (paths[1, :left] == end).all() and paths[1, left] == -1
    assert paths[0, left] == end  # agent 0 enters the moment agent 1 is done
    solved, _, paths = plan(rows, starts, goals, prioritize_start=False)
    assert solved and (paths[1, : H + 1] != end).any()


def test_a_call_out_of_budget_is_repaired_collision_free():
    solved, _, paths = plan(
        CORRIDOR, [(1, 1), (1, 7)], [[(1, 7)], [(1, 1)]], max_nodes=1, prioritize_start=False
    )
    assert not solved
    assert (paths >= 0).all()  # the repair gives every agent a cell at every time
    check_moves(as_rc(paths, len(CORRIDOR[0]), H), grid(CORRIDOR).astype(bool))


def test_the_last_goals_dwell_wins_over_a_passing_agent():
    # Agent 0 steps out of a pocket onto its only goal and dwells there 5 steps; agent 1 must
    # cross that cell. RHCR's SIPP does not check the dwell of an agent's last goal, so the
    # child that puts agent 0 below agent 1 keeps replanning the same colliding path and fails:
    # agent 1 waits for the dwell instead of agent 0 waiting in its pocket.
    rows = ["@@@@@@@", "@.....@", "@@@.@@@", "@@@@@@@"]
    goal = cell(rows, 1, 3)
    solved, _, paths = plan(rows, [(2, 3), (1, 1)], [[(1, 3)], [(1, 5)]], dwells=[[5], [0]])
    assert solved
    check_moves(as_rc(paths, len(rows[0]), planned_prefix(paths)), grid(rows).astype(bool))
    assert (paths[0, 1:7] == goal).all()  # arrives at once and dwells 5 steps
    assert goal not in paths[1, :7] and goal in paths[1]  # agent 1 crosses after the dwell


@settings(max_examples=60, deadline=None)
@given(data=st.data(), n=st.integers(2, 8), seed=st.integers(0, 2**32 - 1))
def test_arriving_on_a_goal_starts_its_dwell(data, n, seed):
    """As in RHCR's SIPP, an agent that steps onto its current goal dwells there at once for
    the goal's whole dwell (within the window): it never passes through or leaves early."""
    rows = ["@@@@@@@", "@.....@", "@.@.@.@", "@.....@", "@@@@@@@"]
    free = [(r, c) for r in range(len(rows)) for c in range(len(rows[0])) if rows[r][c] != "@"]
    starts = data.draw(st.permutations(free))[:n]
    goals = [data.draw(st.lists(st.sampled_from(free), min_size=2, max_size=3)) for _ in range(n)]
    dwells = [[data.draw(st.integers(0, 4)) for _ in g] for g in goals]
    solved, _, paths = plan(rows, starts, goals, dwells=dwells, seed=seed)
    if not solved:  # a repaired call follows the best node only partly
        return
    check_moves(as_rc(paths, len(rows[0]), H), grid(rows).astype(bool))
    for a in range(n):
        target, dwell = cell(rows, *goals[a][0]), dwells[a][0]
        if dwell == 0 or cell(rows, *starts[a]) == target:
            continue
        hits = np.flatnonzero(paths[a] == target)
        if hits.size:
            arrive = int(hits[0])
            stay = paths[a, arrive : min(arrive + dwell, W) + 1]
            assert (stay == target).all(), (a, arrive, paths[a])


def test_bad_plan_input_is_refused():
    with pytest.raises(ValueError, match="goal off"):
        _core.plan(grid(CORRIDOR), [cell(CORRIDOR, 1, 1)], [[0]])
    with pytest.raises(ValueError, match="executed_steps"):
        _core.plan(
            grid(CORRIDOR), [cell(CORRIDOR, 1, 1)], [[cell(CORRIDOR, 1, 2)]], window=3, executed_steps=4
        )
    with pytest.raises(ValueError, match="one dwell per goal"):
        _core.plan(grid(CORRIDOR), [cell(CORRIDOR, 1, 1)], [[cell(CORRIDOR, 1, 2)]], dwells=[[1, 2]])


@settings(max_examples=40, deadline=None)
@given(
    data=st.data(),
    n=st.integers(2, 12),
    max_nodes=st.sampled_from([0, 1, 3]),
    prioritize=st.booleans(),
    seed=st.integers(0, 2**32 - 1),
)
def test_every_call_executes_collision_free(data, n, max_nodes, prioritize, seed):
    """Solved or repaired, the executed steps of a call obey the movement rules."""
    rows = ["@@@@@@@", "@.....@", "@.@.@.@", "@.....@", "@@@@@@@"]
    free = [(r, c) for r in range(len(rows)) for c in range(len(rows[0])) if rows[r][c] != "@"]
    starts = data.draw(st.permutations(free))[:n]
    goals = [data.draw(st.lists(st.sampled_from(free), min_size=1, max_size=3)) for _ in range(n)]
    solved, _, paths = plan(rows, starts, goals, max_nodes=max_nodes, prioritize_start=prioritize, seed=seed)
    assert (paths[:, 0] == [cell(rows, *s) for s in starts]).all()
    check_moves(as_rc(paths, len(rows[0]), H), grid(rows).astype(bool))
