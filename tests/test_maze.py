"""Maze domain: layout, seed, exact start/goal, rule-based agents, evaluator."""

from __future__ import annotations

from collections import deque
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nca_qd.domains import make_domain
from nca_qd.domains.maze import (
    MazeDomain,
    double_sweep_path,
    horizon_for,
    longest_shortest_path,
    maze_key,
    run_agent,
    solve_start_goal,
)
from nca_qd.io import load_map, reference_maps_dir
from nca_qd.measures import entropy
from nca_qd.sim import maze_agent as ma

MAPS = reference_maps_dir() / "maze"


def make_cfg(names=("n_walls", "path_length"), kind="wall_follower", episodes=50):
    return {
        "name": "maze",
        "size": {"train": [16, 16], "eval": [64, 64]},
        "nca_iters": {"train": 50, "eval": 200},
        "measures": {"names": list(names), "ranges": [[0, 256], [0, 648]], "cells": [256, 162]},
        "agent": {"kind": kind, "episodes": episodes, "horizon_factor": 2},
    }


@pytest.fixture(scope="module")
def domain():
    return make_domain(make_cfg())


def grid(rows: list[str]) -> np.ndarray:
    return np.array([[1 if ch == "X" else 0 for ch in r] for r in rows], np.int32)


# --------------------------------------------------------------------------- reference BFS


def bfs(free: np.ndarray, src: tuple[int, int]) -> dict[tuple[int, int], int]:
    h, w = free.shape
    dist = {src: 0}
    q = deque([src])
    while q:
        r, c = q.popleft()
        for dr, dc in ((0, 1), (1, 0), (0, -1), (-1, 0)):
            nr, nc = r + dr, c + dc
            if 0 <= nr < h and 0 <= nc < w and free[nr, nc] and (nr, nc) not in dist:
                dist[(nr, nc)] = dist[(r, c)] + 1
                q.append((nr, nc))
    return dist


def reference_lsp(free: np.ndarray):
    """Longest shortest path; start = smallest row-major end, goal = smallest tile at L from it."""
    h, w = free.shape
    cells = [(r, c) for r in range(h) for c in range(w) if free[r, c]]
    dists = {s: bfs(free, s) for s in cells}
    length = max((max(d.values()) for d in dists.values()), default=0)
    if length == 0:
        first = cells[0] if cells else (-1, -1)
        return 0, first, first
    start = min(s for s in cells if max(dists[s].values()) == length)
    goal = min(t for t, d in dists[start].items() if d == length)
    return length, start, goal


# --------------------------------------------------------------------------- layout and seed


def test_assemble_adds_wall_border(domain):
    region = np.random.default_rng(0).integers(0, 2, (16, 16)).astype(np.int32)
    layout = domain.assemble(region)
    assert isinstance(layout, np.ndarray) and layout.shape == (18, 18)
    np.testing.assert_array_equal(layout[1:-1, 1:-1], region)
    ring = np.ones((18, 18), bool)
    ring[1:-1, 1:-1] = False
    assert (layout[ring] == 1).all()
    batch = domain.assemble(jnp.zeros((3, 64, 64), jnp.int32))
    assert isinstance(batch, jax.Array) and batch.shape == (3, 66, 66)
    assert int(batch.sum()) == 3 * (66 * 66 - 64 * 64)


@pytest.mark.parametrize("shape", [(16, 16), (64, 64)])
def test_seed_matches_shared_maps(domain, shape):
    path = MAPS / f"seed_{shape[0]}x{shape[1]}.json"
    if not path.is_file():
        pytest.skip(f"shared seed map missing: {path}")
    expected = load_map(path, domain.gen_tiles).to_array(domain.gen_tiles)
    np.testing.assert_array_equal(domain.seed(shape), expected)


def test_domain_tiles(domain):
    assert domain.name == "maze" and domain.gen_tiles == " X" and domain.layout_tiles == " X"
    assert domain.n_tiles == 2 and set(domain.palette) == {" ", "X"}


# --------------------------------------------------------------------------- start and goal


_lsp = jax.jit(longest_shortest_path)


@settings(max_examples=25, deadline=None)
@given(shape=st.sampled_from([(5, 5), (6, 8)]), density=st.floats(0.0, 0.8), seed=st.integers(0, 2**31 - 1))
def test_longest_shortest_path_matches_python_bfs(shape, density, seed):
    walls = np.random.default_rng(seed).random(shape) < density
    free = ~walls
    length, start, goal = _lsp(jnp.asarray(free))
    ref_len, ref_start, ref_goal = reference_lsp(free)
    assert int(length) == ref_len
    assert tuple(np.asarray(start)) == ref_start
    assert tuple(np.asarray(goal)) == ref_goal


_sweep = jax.jit(double_sweep_path)


def perfect_maze(rng: np.random.Generator, cells: tuple[int, int]) -> np.ndarray:
    """A maze without cycles (a random spanning tree of a cell grid, by depth-first search):
    free [2r-1, 2c-1], cells at even coordinates, passages between them."""
    r, c = cells
    free = np.zeros((2 * r - 1, 2 * c - 1), bool)
    seen = np.zeros((r, c), bool)
    stack = [(int(rng.integers(r)), int(rng.integers(c)))]
    seen[stack[0]] = True
    free[2 * stack[0][0], 2 * stack[0][1]] = True
    while stack:
        y, x = stack[-1]
        nxt = [(y + dy, x + dx) for dy, dx in ((0, 1), (1, 0), (0, -1), (-1, 0))]
        nxt = [(a, b) for a, b in nxt if 0 <= a < r and 0 <= b < c and not seen[a, b]]
        if not nxt:
            stack.pop()
            continue
        a, b = nxt[int(rng.integers(len(nxt)))]
        seen[a, b] = True
        free[2 * a, 2 * b] = free[y + a, x + b] = True
        stack.append((a, b))
    return free


@settings(max_examples=25, deadline=None)
@given(shape=st.sampled_from([(5, 5), (6, 8)]), density=st.floats(0.0, 0.8), seed=st.integers(0, 2**31 - 1))
def test_double_sweep_gives_a_shortest_path_no_longer_than_the_longest(shape, density, seed):
    """Its ends lie on free tiles at exactly the reported BFS distance (an independent BFS),
    never beyond the exact longest shortest path."""
    free = np.random.default_rng(seed).random(shape) >= density
    length, start, goal = _sweep(jnp.asarray(free), jax.random.PRNGKey(seed % 1000))
    length, start, goal = int(length), tuple(np.asarray(start)), tuple(np.asarray(goal))
    exact, _, _ = reference_lsp(free)
    assert length <= exact
    if not free.any():
        assert length == 0 and start == goal == (-1, -1)
        return
    assert free[start] and free[goal]
    assert bfs(free, start)[goal] == length


@pytest.mark.parametrize("seed", range(4))
def test_double_sweep_is_exact_on_mazes_without_cycles(seed):
    rng = np.random.default_rng(seed)
    free = np.stack([perfect_maze(rng, (6, 7)) for _ in range(3)])
    length, _, _ = _sweep(jnp.asarray(free), jax.random.PRNGKey(seed))
    exact, _, _ = _lsp(jnp.asarray(free))
    np.testing.assert_array_equal(np.asarray(length), np.asarray(exact))
    assert (np.asarray(length) > 10).all()


def test_longest_shortest_path_batched_16x16():
    rng = np.random.default_rng(1)
    free = rng.random((12, 16, 16)) >= rng.random((12, 1, 1)) * 0.7  # many words, some disconnected
    length, start, goal = _lsp(jnp.asarray(free))
    for i in range(free.shape[0]):
        ref = reference_lsp(free[i])
        assert (int(length[i]), tuple(np.asarray(start[i])), tuple(np.asarray(goal[i]))) == ref


def test_solve_start_goal_on_bordered_paper_map(domain):
    path = MAPS / "paper_nca_16x16.json"
    if not path.is_file():
        pytest.skip("shared paper map missing")
    region = load_map(path, " X").to_array(" X")
    start, goal, length = solve_start_goal(domain.assemble(region))
    ref_len, ref_start, ref_goal = reference_lsp(region == 0)
    assert length == ref_len
    assert tuple(start) == (ref_start[0] + 1, ref_start[1] + 1)
    assert tuple(goal) == (ref_goal[0] + 1, ref_goal[1] + 1)


# --------------------------------------------------------------------------- agents


def test_dynamics_turns_and_blocked_forward():
    layout = grid(["XXXX", "X  X", "XXXX"])
    env = ma.make_env(jnp.asarray(layout), jnp.array([1, 2]))

    @jax.jit
    def outcomes(env):  # every action from (1, 1) facing east, and forward facing north
        s = ma.AgentState(jnp.array([1, 1]), jnp.array(ma.EAST))
        north = s._replace(dir=jnp.array(ma.NORTH))
        steps = [ma.step(env, s, a) for a in (ma.LEFT, ma.RIGHT, ma.FORWARD, ma.STAY)]
        steps.append(ma.step(env, north, ma.FORWARD))
        return [(x.pos, x.dir) for x in steps], ma.observe(env, s)

    (left, right, fwd, stay, blocked), view = jax.device_get(outcomes(env))
    assert tuple(left[0]) == (1, 1) and left[1] == ma.NORTH
    assert tuple(right[0]) == (1, 1) and right[1] == ma.SOUTH
    assert tuple(fwd[0]) == (1, 2) and fwd[1] == ma.EAST
    assert tuple(stay[0]) == (1, 1) and stay[1] == ma.EAST
    assert tuple(blocked[0]) == (1, 1) and blocked[1] == ma.NORTH  # into a wall: no-op
    # 5x5 view: agent at the bottom middle facing up; the goal one tile ahead; walls around.
    assert view.shape == (5, 5) and view[3, 2] == 2 and view[4, 2] == 0
    assert view[4, 1] == 1 and view[4, 3] == 1 and view[2, 2] == 1


def embed(rows: list[str]) -> np.ndarray:
    """A small layout in the top-left corner of an 18x18 all-wall layout (one compile for all)."""
    out = np.ones((18, 18), np.int32)
    small = grid(rows)
    out[: small.shape[0], : small.shape[1]] = small
    return out


def test_shortest_path_agent_reaches_goal_and_is_no_shorter_than_bfs():
    rng = np.random.default_rng(3)
    for _ in range(3):
        region = (rng.random((16, 16)) < 0.3).astype(np.int32)
        layout = np.pad(region, 1, constant_values=1)
        start, goal, length = solve_start_goal(layout)
        if length == 0:
            continue
        res = run_agent(layout, start, goal, jax.random.PRNGKey(0), kind="shortest_path", record_path=True)
        assert res.reached.all()
        # BFS distance plus turns: at most 2 turns before the first move, 1 before each other.
        assert (res.lengths >= length).all() and (res.lengths <= 2 * length + 1).all()
        assert tuple(res.path[0]) == tuple(start) and tuple(res.path[-1]) == tuple(goal)
        assert len(res.path) == res.lengths[0] + 1
        steps = np.abs(np.diff(res.path, axis=0)).sum(axis=1)
        assert steps.sum() == length and steps.max() <= 1


CORRIDOR = embed(["XXXXXXXXX", "X       X", "XXXXXXXXX"])
ROOM = embed(["X" * 9] + ["X       X"] * 7 + ["X" * 9])


def test_wall_follower_reaches_goal_in_corridor():
    res = run_agent(CORRIDOR, (1, 1), (1, 7), jax.random.PRNGKey(0), kind="wall_follower")
    assert res.reached.all()
    # Facing east: 6 moves; otherwise at most 3 turns first.
    assert res.lengths.min() >= 6 and res.lengths.max() <= 9
    assert res.lengths.min() == 6 and res.lengths.max() > 6  # 50 episodes: random directions


def test_wall_follower_counts_horizon_when_it_cannot_reach():
    # From a corner it walks along and then follows the outer wall, never reaching the centre.
    res = run_agent(ROOM, (1, 1), (4, 4), jax.random.PRNGKey(0), kind="wall_follower")
    assert not res.reached.any()
    assert (res.lengths == 648).all()
    # ... but from the centre row, walking straight, it passes the goal.
    res = run_agent(ROOM, (4, 1), (4, 4), jax.random.PRNGKey(0), kind="wall_follower")
    assert res.reached.any() and (res.lengths[res.reached] == 3).all()


# --------------------------------------------------------------------------- evaluator


@pytest.fixture(scope="module")
def batch():
    rng = np.random.default_rng(7)
    regions = rng.random((6, 16, 16)) < np.array([0.0, 0.2, 0.35, 0.5, 0.9, 1.0])[:, None, None]
    return regions.astype(np.int32)


@pytest.fixture(scope="module")
def evaluated(domain, batch):
    ev = domain.make_evaluator()
    return ev, ev(batch, jax.random.PRNGKey(42))


def test_evaluator_outputs(domain, batch, evaluated):
    _, out = evaluated
    b = batch.shape[0]
    assert out.objective.shape == (b,) and out.measures.shape == (b, 2)
    assert out.extras["start"].shape == (b, 2) and out.extras["success_rate"].shape == (b,)
    np.testing.assert_array_equal(np.asarray(out.measures[:, 0]), (batch == 1).sum(axis=(1, 2)))
    horizon = horizon_for((18, 18))
    assert horizon == 648
    pl = np.asarray(out.measures[:, 1])
    assert ((pl >= 0) & (pl <= horizon)).all()
    for i in range(b):
        ref_len, ref_start, ref_goal = reference_lsp(batch[i] == 0)
        assert float(out.objective[i]) == float(ref_len > 0)
        if ref_len > 0:
            assert tuple(np.asarray(out.extras["start"][i])) == (ref_start[0] + 1, ref_start[1] + 1)
            assert tuple(np.asarray(out.extras["goal"][i])) == (ref_goal[0] + 1, ref_goal[1] + 1)
            assert pl[i] >= ref_len


def test_evaluator_all_walls_is_unsolvable(evaluated, batch):
    _, out = evaluated
    assert (batch[-1] == 1).all()
    assert float(out.objective[-1]) == 0.0
    assert float(out.measures[-1, 0]) == 256.0
    assert float(out.measures[-1, 1]) == 648.0 and float(out.extras["success_rate"][-1]) == 0.0
    assert tuple(np.asarray(out.extras["start"][-1])) == (-1, -1)


def test_evaluator_is_deterministic_and_matches_run_agent(domain, batch, evaluated):
    ev, out = evaluated
    again = ev(batch, jax.random.PRNGKey(42))
    np.testing.assert_array_equal(np.asarray(out.measures), np.asarray(again.measures))
    np.testing.assert_array_equal(
        np.asarray(out.extras["episode_lengths"]), np.asarray(again.extras["episode_lengths"])
    )
    i = 2
    key_i = maze_key(jax.random.PRNGKey(42), i)
    res = run_agent(
        domain.assemble(batch[i]),
        out.extras["start"][i],
        out.extras["goal"][i],
        key_i,
        kind="wall_follower",
        episodes=50,
    )
    np.testing.assert_array_equal(res.lengths, np.asarray(out.extras["episode_lengths"][i]))


def test_a_mazes_score_does_not_depend_on_the_batch_size(evaluated, batch):
    ev, out = evaluated
    head = ev(batch[:3], jax.random.PRNGKey(42))
    for name in ("episode_lengths", "success_rate"):
        np.testing.assert_array_equal(np.asarray(head.extras[name]), np.asarray(out.extras[name][:3]))
    np.testing.assert_array_equal(np.asarray(head.measures), np.asarray(out.measures[:3]))


def test_entropy_variant_and_shortest_path_kind(batch):
    dom = MazeDomain(make_cfg(names=("entropy", "path_length"), kind="shortest_path"))
    out = dom.make_evaluator()(batch[:3], jax.random.PRNGKey(0))
    expected = [float(entropy(jnp.asarray(r), 2)) for r in batch[:3]]
    np.testing.assert_allclose(np.asarray(out.measures[:, 0]), expected, rtol=1e-6)
    assert (np.asarray(out.extras["success_rate"]) == np.asarray(out.objective)).all()


def test_unknown_measure_or_agent_is_an_error():
    from nca_qd.errors import NcaQdError

    with pytest.raises(NcaQdError):
        MazeDomain(make_cfg(names=("n_walls", "bogus")))
    with pytest.raises(NcaQdError):
        MazeDomain(make_cfg(kind="bogus"))


def test_cycle_detection_does_not_change_results():
    rng = np.random.default_rng(5)
    regions = (rng.random((6, 16, 16)) < np.linspace(0.1, 0.6, 6)[:, None, None]).astype(np.int32)
    layouts = np.concatenate([np.pad(regions, ((0, 0), (1, 1), (1, 1)), constant_values=1), ROOM[None]])
    length, start, goal = _lsp(jnp.asarray(layouts == 0))
    start, goal = np.array(start), np.array(goal)
    start[-1], goal[-1] = (1, 1), (4, 4)  # the room: the wall follower circles forever
    keys = jax.random.split(jax.random.PRNGKey(3), layouts.shape[0])
    policy = ma.get_policy("wall_follower")
    plain = jax.jit(lambda *a: ma.rollout_batch(policy, *a, episodes=50, horizon=648, detect_cycles=False))(
        jnp.asarray(layouts), jnp.asarray(start), jnp.asarray(goal), keys
    )
    for i in range(layouts.shape[0]):  # run_agent detects cycles (same keys per maze)
        res = run_agent(layouts[i], start[i], goal[i], keys[i], kind="wall_follower")
        np.testing.assert_array_equal(res.lengths, np.asarray(plain.lengths[i]))
        np.testing.assert_array_equal(res.reached, np.asarray(plain.reached[i]))
    assert not res.reached.any() and (res.lengths == 648).all()  # the room


@pytest.mark.parametrize(("kind", "horizon"), [("learned", 40), ("wall_follower", 160)])
def test_staged_rollouts_give_the_unstaged_loops_results(kind, horizon, monkeypatch):
    """rollout_batch gathers the agents still walking into fewer rows as episodes end; the
    lengths, goals and visits are the single loop's over all rows (staging off), bit for bit,
    and episode 0 of each maze is what record_episode (a scan of that episode alone) gives."""
    rng = np.random.default_rng(11)
    regions = (rng.random((6, 16, 16)) < np.linspace(0.05, 0.7, 6)[:, None, None]).astype(np.int32)
    layouts = jnp.asarray(np.pad(regions, ((0, 0), (1, 1), (1, 1)), constant_values=1))
    length, start, goal = _lsp(layouts == 0)
    active = (length > 0) & (jnp.arange(6) != 2)  # maze 2 inactive: no episode walks
    keys = jax.random.split(jax.random.PRNGKey(7), 6)
    policy = ma.get_policy(kind)
    visits = kind == "learned"  # cycle detection (the wall follower's) cannot count visits

    def run(floor, minimum):
        monkeypatch.setattr(ma, "STAGE_FLOOR", floor)
        monkeypatch.setattr(ma, "STAGE_MIN", minimum)
        f = jax.jit(lambda *a: ma.rollout_batch(policy, *a, 20, horizon, active, count_visits=visits))
        return f(layouts, start, goal, keys)

    assert ma._stage_sizes(120) == [120]  # the defaults: too few agents to stage
    monkeypatch.setattr(ma, "STAGE_MIN", 8)
    assert ma._stage_sizes(120) == [120, 60, 30, 15, 8]
    staged, single = run(16, 8), run(1, 8)
    lengths = np.asarray(staged.lengths)
    assert 0 < (lengths < horizon).mean() < 1  # some episodes end early, some run to the horizon
    np.testing.assert_array_equal(lengths, np.asarray(single.lengths))
    np.testing.assert_array_equal(np.asarray(staged.reached), np.asarray(single.reached))
    if visits:
        np.testing.assert_array_equal(np.asarray(staged.visits), np.asarray(single.visits))
        assert np.asarray(staged.visits).sum() == np.where(np.asarray(active)[:, None], lengths, 0).sum()
    record = jax.jit(partial(ma.record_episode, policy, episodes=20, horizon=horizon))
    for i in np.flatnonzero(np.asarray(active)):
        assert int(record(layouts[i], start[i], goal[i], keys[i])[2]) == lengths[i, 0]
    assert (lengths[~np.asarray(active)] == horizon).all()
