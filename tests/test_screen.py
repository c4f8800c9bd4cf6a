"""The JAX screening simulator: every run's paths go through the independent checker."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from sim_layouts import MANUFACTURING, WAREHOUSE, bfs_distances, small_warehouses

from nca_qd.errors import NcaQdError
from nca_qd.sim import screen, screen_base, screen_pibt
from nca_qd.sim.checker import check_run, recount_tasks
from nca_qd.sim.scenario import build_scenario
from nca_qd.sim.screen import simulate, simulate_batch

# Shared settings so that most tests reuse one compiled program.
N, T = 12, 40


def run_checked(rows, scenario, n_agents=N, horizon=T, seed=0):
    res = simulate(rows, scenario, n_agents, horizon, seed, record_paths=True)
    report = check_run(res, rows)
    assert report.finished_tasks == res.finished_tasks
    assert res.throughput == pytest.approx(recount_tasks(res.paths, res.goals).sum() / horizon)
    assert res.tile_visits.sum() == n_agents * res.stop_time
    assert res.tile_visits.shape == (len(rows), len(rows[0]))
    assert res.tasks_per_step.shape == (horizon,)
    return res


def test_warehouse_and_manufacturing_runs_pass_the_checker():
    w = run_checked(WAREHOUSE, "warehouse_even")
    assert w.success and w.stop_time == T and w.finished_tasks > 0
    u = run_checked(WAREHOUSE, "warehouse_uneven", seed=3)
    assert u.finished_tasks > 0
    m = run_checked(MANUFACTURING, "manufacturing")
    assert m.finished_tasks > 0
    # dwell times are honoured: manufacturing goals carry dwell 2, 5 or 10
    assert {int(d) for g in m.goals for d in g[:, 2]} <= {2, 5, 10}


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(rows=small_warehouses(), seed=st.integers(0, 1000))
def test_random_layouts_pass_the_checker(rows, seed):
    try:
        build_scenario(rows, "warehouse_even", n_agents=N)
    except NcaQdError:
        assume(False)
    run_checked(rows, "warehouse_even", seed=seed)


def test_deterministic_per_seed():
    a = simulate(WAREHOUSE, "warehouse_even", N, T, 7, record_paths=True)
    b = simulate(WAREHOUSE, "warehouse_even", N, T, 7, record_paths=True)
    c = simulate(WAREHOUSE, "warehouse_even", N, T, 8, record_paths=True)
    assert a.throughput == b.throughput
    np.testing.assert_array_equal(a.paths, b.paths)
    np.testing.assert_array_equal(a.tile_visits, b.tile_visits)
    assert not np.array_equal(a.paths, c.paths)


def test_vmapped_batch_equals_one_at_a_time():
    other = [r.replace("@", ".") if i == 6 else r for i, r in enumerate(WAREHOUSE)]
    batch = simulate_batch([WAREHOUSE, other], "warehouse_even", N, T, [0, 1], record_paths=True)
    for rows, row in zip([WAREHOUSE, other], batch):
        for seed, res in zip([0, 1], row):
            one = simulate(rows, "warehouse_even", N, T, seed, record_paths=True)
            check_run(res, rows)
            assert res.throughput == one.throughput and res.stop_time == one.stop_time
            np.testing.assert_array_equal(res.paths, one.paths)
            np.testing.assert_array_equal(res.tasks_per_step, one.tasks_per_step)
            np.testing.assert_array_equal(res.tile_visits, one.tile_visits)
            assert all(np.array_equal(x, y) for x, y in zip(res.goals, one.goals))


def test_congestion_stops_a_jammed_run():
    corridor = ["weeeeeeeew"]  # 1-wide, every tile taken: nobody can ever move
    res = simulate(corridor, "warehouse_even", 10, 30, 0, record_paths=True)
    assert res.congested and not res.success
    assert res.stop_time == 5  # the first congestion check (h = 5)
    check_run(res, corridor)
    assert res.tasks_per_step[5:].sum() == 0
    assert res.throughput == pytest.approx(res.finished_tasks / 30)


@pytest.mark.parametrize(
    "rows, scenario, agents, horizon, message",
    [
        (WAREHOUSE, "warehouse_even", 500, 10, "traversable tiles"),
        (WAREHOUSE, "warehouse_odd", 5, 10, "unknown scenario"),
        (["w.e@.e.w"], "warehouse_even", 2, 10, "not all connected"),
        (["w.e.x..w"], "warehouse_even", 2, 10, "x"),
        (WAREHOUSE, "warehouse_even", 0, 10, "at least one agent"),
        (WAREHOUSE, "warehouse_even", 5, 0, "horizon"),
        (WAREHOUSE, "warehouse_even", 50_000, 10, "at most 46340 agents"),
        ([WAREHOUSE, WAREHOUSE[:-1]], "warehouse_even", 5, 10, "one shape"),
    ],
)
def test_bad_input_errors_before_compilation(monkeypatch, rows, scenario, agents, horizon, message):
    def no_compile(*a, **k):
        raise AssertionError("compiled despite bad input")

    monkeypatch.setattr(screen, "_batched", no_compile)
    layouts = rows if isinstance(rows[0], list) else [rows]
    with pytest.raises(NcaQdError, match=message):
        simulate_batch(layouts, scenario, agents, horizon, [0])


def test_cli_screen_prints_runs_and_summary(tmp_path):
    layout = tmp_path / "wh.json"
    layout.write_text(json.dumps({"name": "wh", "layout": WAREHOUSE}))
    out = tmp_path / "paths.npz"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "experiments.simulate",
            "domain=warehouse_even",
            f"layout={layout}",
            f"agents={N}",
            f"T={T}",
            "seeds=2",
            "seed=3",
            "simulator=screen",
            f"paths_out={out}",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    lines = [json.loads(x) for x in proc.stdout.strip().splitlines()]
    assert [r["seed"] for r in lines[:2]] == [3, 4] and lines[2]["summary"]
    for r in lines[:2]:
        assert set(r) >= {"seed", "throughput", "success", "stop_time", "cpu_seconds"}
    with np.load(out) as z:
        assert z["paths_seed3"].shape == (T + 1, N, 2)


def test_crowding_proxy_stops_a_packed_room_that_rhcrs_rule_lets_run():
    room = [
        "w.......w",
        ".eeeeeee.",
        ".........",
        ".eeeeeee.",
        "w.......w",
        ".eeeeeee.",
        ".........",
        ".eeeeeee.",
        "w.......w",
    ]
    horizon = 100  # past the first check at which the crowding rule may stop a run
    crowded = simulate(room, "warehouse_even", 60, horizon, 0, record_paths=True, congestion="crowding")
    check_run(crowded, room)
    # stops at the first check allowed (the 10th, t=50): >= 17 agents in a 5x5 block on average
    assert crowded.congested and crowded.stop_time == 5 * screen.CROWD_MIN_CHECKS
    assert crowded.crowding[: screen.CROWD_MIN_CHECKS].mean() >= screen.CROWD_MEAN
    moved = simulate(room, "warehouse_even", 60, horizon, 0, record_paths=True, congestion="moved")
    check_run(moved, room)
    assert moved.success and moved.stop_time == horizon
    stop = crowded.stop_time
    np.testing.assert_array_equal(moved.paths[: stop + 1], crowded.paths)  # same run up to the stop
    # A threshold above anything this room reaches (a domain whose traffic crowds more where it
    # flows sets its own): the crowding rule never fires and the run is RHCR's rule's run.
    lenient = simulate(
        room,
        "warehouse_even",
        60,
        horizon,
        0,
        record_paths=True,
        congestion="crowding",
        crowd_mean=float(moved.crowding.max()) + 0.5,
    )
    assert lenient.success and lenient.stop_time == horizon
    np.testing.assert_array_equal(lenient.paths, moved.paths)
    assert screen.crowd_mean_for({"simulation": {"T": 5}}) == screen.CROWD_MEAN
    assert screen.crowd_mean_for({"simulation": {"screen_crowd_mean": 19.25}}) == 19.25
    assert screen.crowd_mean_for({"simulation": {"screen_crowd_mean": 19.25}}, 21) == 21.0
    with pytest.raises(NcaQdError, match="crowding threshold"):
        screen.crowd_mean_for({"simulation": {"screen_crowd_mean": "high"}})


def _top_blocks_mean(cells: np.ndarray, shape: tuple[int, int], rank: int) -> float:
    """Independent check: the mean agent count of the ``rank`` most crowded 5x5 blocks."""
    grid = np.zeros(shape, int)
    np.add.at(grid, (cells[:, 0], cells[:, 1]), 1)
    k = screen_base.DENSITY_K
    blocks = np.lib.stride_tricks.sliding_window_view(grid, (k, k)).sum((-1, -2))
    return float(np.sort(blocks.ravel())[::-1][:rank].mean())


def test_crowding_on_a_larger_map_averages_its_most_crowded_blocks():
    """Up to a 33x36 map the rule tests the most crowded block; on a larger one the mean of its
    r most crowded blocks (r = one per 33x36 map's blocks), recomputed here from the paths."""
    assert screen.crowd_rank(33, 36) == 1 and screen.crowd_rank(9, 9) == 1
    assert screen.crowd_rank(101, 102) == 10 and screen.crowd_rank(36, 54) == 2
    room = [
        "w.......w",
        ".eeeeeee.",
        ".........",
        ".eeeeeee.",
    ] * 9
    room = [row * 6 for row in room]  # 36 x 54
    n, horizon = 400, 60
    moved = simulate(room, "warehouse_even", n, horizon, 0, record_paths=True, congestion="moved")
    check_run(moved, room)
    assert moved.success
    times = np.arange(screen.CROWD_MIN_CHECKS + 2) * 5 + 5
    expected = [_top_blocks_mean(moved.paths[t], (36, 54), 2) for t in times]
    np.testing.assert_allclose(moved.crowding[: len(times)], expected)
    # The rule on that mean: a threshold just below its running mean at the 10th check stops the
    # run there; the same run, up to then, as RHCR's rule's.
    first = float(np.mean(moved.crowding[: screen.CROWD_MIN_CHECKS]))
    stopped = simulate(
        room,
        "warehouse_even",
        n,
        horizon,
        0,
        record_paths=True,
        congestion="crowding",
        crowd_mean=first - 0.01,
    )
    assert stopped.congested and stopped.stop_time == 5 * screen.CROWD_MIN_CHECKS
    np.testing.assert_array_equal(moved.paths[: stopped.stop_time + 1], stopped.paths)
    flows = simulate(
        room, "warehouse_even", n, horizon, 0, congestion="crowding", crowd_mean=moved.crowding.max() + 0.01
    )
    assert flows.success and flows.stop_time == horizon


@pytest.mark.parametrize(
    "option, message",
    [
        ({"congestion": "jam"}, "congestion rule"),
        ({"priority": "oldest"}, "priority"),
        ({"replan": 0}, "replan"),
        ({"crowd_mean": 0}, "crowding threshold"),
        ({"crowd_mean": float("nan")}, "crowding threshold"),
        ({"crowd_mean": True}, "crowding threshold"),
    ],
)
def test_bad_options_error_before_compilation(monkeypatch, option, message):
    monkeypatch.setattr(screen, "_batched", lambda *a, **k: pytest.fail("compiled"))
    with pytest.raises(NcaQdError, match=message):
        simulate_batch([WAREHOUSE], "warehouse_even", 5, 10, [0], **option)


def test_goals_drawn_in_small_rounds_equal_one_round(monkeypatch):
    """draw_done draws the new goals of the agents that finished one in rounds of DRAW_ROUND;
    rounds of one agent (many rounds per step) must give exactly the same run."""
    one = simulate(WAREHOUSE, "warehouse_even", N, T, 5, record_paths=True)
    monkeypatch.setattr(screen_pibt, "DRAW_ROUND", 1)
    monkeypatch.setattr(screen, "_COMPILED", {})
    monkeypatch.setattr(screen, "_EXECUTABLES", {})
    small = simulate(WAREHOUSE, "warehouse_even", N, T, 5, record_paths=True)
    assert one.tasks_per_step.max() >= 2  # some step needed several rounds
    np.testing.assert_array_equal(one.paths, small.paths)
    np.testing.assert_array_equal(one.tasks_per_step, small.tasks_per_step)
    check_run(small, WAREHOUSE)


def test_big_batches_run_in_groups_with_the_same_results(monkeypatch):
    """Layouts whose distance tables would exceed MAX_TABLE entries run as several batches;
    every run's result is what one batch gives."""
    other = [r.replace(".@@@@.", ".@@.@.", 1) for r in WAREHOUSE]
    layouts = [WAREHOUSE, other, WAREHOUSE[::-1]]
    scens = [build_scenario(r, "warehouse_even", n_agents=N) for r in layouts]
    one = simulate_batch(layouts, "warehouse_even", N, T, [0, 1], record_paths=True)
    per_layout = screen._round_up(len(screen.prepare(scens[:1]).goal_cells[0])) * 9 * 12
    assert screen.layout_groups(scens) == [[0, 1, 2]]
    assert screen.layout_groups(scens, 2 * per_layout) == [[0, 1], [2]]
    monkeypatch.setattr(screen, "MAX_TABLE", per_layout)
    assert screen.layout_groups(scens) == [[0], [1], [2]]
    split = simulate_batch(layouts, "warehouse_even", N, T, [0, 1], record_paths=True)
    for a, b in zip(one, split):
        for x, y in zip(a, b):
            np.testing.assert_array_equal(x.paths, y.paths)
            assert x.finished_tasks == y.finished_tasks and x.seed == y.seed


def test_shortcuts_leave_the_pibt_plan_unchanged(monkeypatch):
    """Moves decided before PIBT's search (free best tiles, chains of followers) and the
    root lookahead only save sequential calls: plain PIBT (one root per call, nothing
    decided beforehand) must plan exactly the same paths, in a dense run where pushes,
    followers and blocked candidates all occur."""
    n = 3 * N
    fast = simulate(WAREHOUSE, "warehouse_even", n, T, 3, record_paths=True)
    monkeypatch.setattr(screen_pibt, "PREDECIDE", False)
    monkeypatch.setattr(screen_pibt, "ROOT_LOOKAHEAD", 1)
    monkeypatch.setattr(screen, "_COMPILED", {})
    monkeypatch.setattr(screen, "_EXECUTABLES", {})
    plain = simulate(WAREHOUSE, "warehouse_even", n, T, 3, record_paths=True)
    assert fast.finished_tasks > 0
    np.testing.assert_array_equal(fast.paths, plain.paths)
    np.testing.assert_array_equal(fast.tasks_per_step, plain.tasks_per_step)
    check_run(plain, WAREHOUSE)


def _bfs(grid: np.ndarray, goal: int) -> np.ndarray:
    """Independent breadth-first distances from one flat cell (INF16 where unreachable)."""
    return bfs_distances(grid, goal, screen_base.INF16)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data(), density=st.floats(0.0, 0.6), chunk=st.sampled_from([1, 3, 7, 64]))
def test_distance_tables_are_breadth_first_distances(data, density, chunk):
    """Chunked relaxation = BFS from every goal: walls, unreachable pockets, padding goals."""
    import jax

    rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
    grid = rng.random((6, 9)) >= density
    goals = rng.integers(-1, grid.size, 7)  # -1: a padding row
    fn = jax.jit(screen.distance_table, static_argnames="chunk")
    got = np.asarray(fn(grid, goals.astype(np.int32), chunk=chunk))
    want = np.stack([_bfs(grid, int(g)) for g in goals])
    assert got.shape == (7, grid.size)
    np.testing.assert_array_equal(got, want)


def test_distance_tables_split_over_threads_are_the_same(monkeypatch):
    """Goals split over two threads (each part padded to whole chunks) give the same tables."""
    import jax.numpy as jnp

    monkeypatch.setattr(screen_base, "DIST_CHUNK", 8)
    monkeypatch.setattr(screen, "_COMPILED", {})
    rng = np.random.default_rng(5)
    grids = rng.random((2, 7, 8)) >= 0.3
    goals = rng.integers(-1, 56, (2, 21)).astype(np.int32)
    one = np.asarray(screen._distance_tables(jnp.asarray(grids), jnp.asarray(goals), 1)())
    two = np.asarray(screen._distance_tables(jnp.asarray(grids), jnp.asarray(goals), 2)())
    assert one.shape == two.shape == (2, 21, 56)
    np.testing.assert_array_equal(one, two)
    for li in range(2):
        np.testing.assert_array_equal(one[li], np.stack([_bfs(grids[li], int(g)) for g in goals[li]]))


# The digest of reference runs per screen VERSION: a change to the screen that alters any of
# them must bump nca_qd.sim.screen.VERSION (recorded evaluation runs of the old version are
# then not reused) and add the new digest here.
SCREEN_DIGESTS = {1: "5cdee9f36383286f", 2: "5cdee9f36383286f"}  # 2: larger maps only


def _screen_digest() -> str:
    import hashlib

    room = ["w.......w", ".eeeeeee.", ".........", ".eeeeeee."] * 2 + ["w.......w"]
    runs = [
        simulate(WAREHOUSE, "warehouse_even", N, T, 0, record_paths=True),
        simulate(WAREHOUSE, "warehouse_uneven", N, T, 3, record_paths=True),
        simulate(MANUFACTURING, "manufacturing", N, T, 0, record_paths=True),
        simulate(room, "warehouse_even", 60, 100, 0, record_paths=True, congestion="crowding"),
    ]
    h = hashlib.sha256()
    for r in runs:
        h.update(np.asarray([r.stop_time, r.success, r.finished_tasks], np.int64).tobytes())
        for a in (r.paths, *r.goals, r.tasks_per_step, r.tile_visits):
            h.update(np.ascontiguousarray(a, dtype=np.int64).tobytes())
    return h.hexdigest()[:16]


def test_the_screen_version_names_its_decisions():
    """Reference runs (three scenarios, and a run the crowding rule stops) hash to the digest
    recorded for the screen's VERSION: a change of decisions without a new version fails."""
    digest = _screen_digest()
    assert SCREEN_DIGESTS.get(screen.VERSION) == digest, (
        f"the screen's runs changed (digest {digest}): bump nca_qd.sim.screen.VERSION and record it"
    )
