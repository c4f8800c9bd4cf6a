"""The learned maze agent: view and dynamics details, the PPO training environment, learning on a
trivial maze, the shipped checkpoint, determinism, and the two entry points."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from omegaconf import OmegaConf

from nca_qd.agent.levels import Levels, solve
from nca_qd.agent.network import AgentNet
from nca_qd.agent.ppo import Trainer
from nca_qd.domains.maze import run_agent, solve_start_goal
from nca_qd.errors import NcaQdError
from nca_qd.sim import maze_agent as ma


def tiny_cfg(**over):
    cfg = OmegaConf.create(
        {
            "n_envs": 8,
            "horizon": 16,
            "interior": [2, 2],
            "ppo": {
                "gamma": 0.99,
                "gae_lambda": 0.95,
                "clip": 0.2,
                "vf_coef": 0.5,
                "ent_coef": 0.0,
                "lr": 3e-3,
                "max_grad_norm": 0.5,
                "epochs": 2,
                "minibatches": 2,
            },
            "levels": {
                "method": "dr",
                "buffer_size": 8,
                "min_fill": 2,
                "replay_prob": 0.5,
                "edit_prob": 0.5,
                "max_edits": 2,
                "temperature": 0.3,
                "staleness": 0.3,
                "density": [0.0, 0.0],
                "tries": 1,
                "nca_prob": 0.0,
                "nca_sigma": [0.2, 1.0],
                "nca_iters": 3,
            },
        }
    )
    return OmegaConf.merge(cfg, OmegaConf.create(over))


NET = AgentNet(hidden=16, head_hidden=16)
FAST_COMPILE = {"xla_backend_optimization_level": 0}  # tiny programs: compile time dominates


# --------------------------------------------------------------------------- view and dynamics


def reference_view(layout, goal, pos, d):
    """The 5x5 egocentric view from its definition, with plain Python loops."""
    vec = [(0, 1), (1, 0), (0, -1), (-1, 0)]
    fwd, right = vec[d], vec[(d + 1) % 4]
    h, w = layout.shape
    out = np.zeros((5, 5), int)
    for i in range(5):
        for j in range(5):
            f, s = 4 - i, j - 2
            r, c = pos[0] + f * fwd[0] + s * right[0], pos[1] + f * fwd[1] + s * right[1]
            inside = 0 <= r < h and 0 <= c < w
            out[i, j] = 2 if (r, c) == tuple(goal) else (layout[r, c] if inside else 1)
    return out


def test_view_matches_definition_everywhere_with_offgrid_walls_and_goal():
    # No border: the grid's edge itself must read as wall; the goal shows in every direction.
    rng = np.random.default_rng(0)
    layout = (rng.random((4, 6)) < 0.3).astype(np.int32)
    goal = np.array([1, 3])
    layout[1, 3] = 0
    env = ma.make_env(jnp.asarray(layout), jnp.asarray(goal))
    rows, cols, dirs = np.meshgrid(np.arange(4), np.arange(6), np.arange(4), indexing="ij")
    pos = np.stack([rows.ravel(), cols.ravel()], 1)
    views = jax.jit(jax.vmap(lambda p, d: ma.observe(env, ma.AgentState(p, d))))(
        jnp.asarray(pos), jnp.asarray(dirs.ravel())
    )
    views = np.asarray(views)
    for k in range(len(pos)):
        np.testing.assert_array_equal(views[k], reference_view(layout, goal, pos[k], dirs.ravel()[k]))
    # A hand-checked case: open 3x4 grid, agent at (2, 1) facing north, goal at (0, 3).
    open_env = ma.make_env(jnp.zeros((3, 4), jnp.int32), jnp.array([0, 3]))
    view = np.asarray(ma.observe(open_env, ma.AgentState(jnp.array([2, 1]), jnp.array(ma.NORTH))))
    np.testing.assert_array_equal(
        view, [[1, 1, 1, 1, 1], [1, 1, 1, 1, 1], [1, 0, 0, 0, 2], [1, 0, 0, 0, 0], [1, 0, 0, 0, 0]]
    )


def test_turns_cycle_and_forward_in_every_direction_stops_at_grid_edge():
    layout = jnp.zeros((3, 3), jnp.int32)  # no border: the array edge blocks

    @jax.jit
    def run(layout):
        env = ma.make_env(layout, jnp.array([0, 0]))
        out = []
        for d in range(4):
            s = ma.AgentState(jnp.array([1, 1]), jnp.array(d))
            one = ma.step(env, s, ma.FORWARD)
            two = ma.step(env, one, ma.FORWARD)  # off the grid: stays
            rights, lefts = s, s
            for _ in range(4):
                rights = ma.step(env, rights, ma.RIGHT)
                lefts = ma.step(env, lefts, ma.LEFT)
            out.append(
                (
                    one.pos,
                    two.pos,
                    rights.dir,
                    lefts.dir,
                    ma.step(env, s, ma.RIGHT).dir,
                    ma.step(env, s, ma.LEFT).dir,
                )
            )
        return out

    for d, (one, two, r4, l4, r1, l1) in enumerate(jax.device_get(run(layout))):
        expect = np.array([1, 1]) + np.asarray(ma.DIR_VEC[d])
        np.testing.assert_array_equal(one, expect)
        np.testing.assert_array_equal(two, expect)
        assert r4 == d and l4 == d and r1 == (d + 1) % 4 and l1 == (d + 3) % 4


# --------------------------------------------------------------------------- training environment


def level(rows):
    lay = np.array([[1 if ch == "X" else 0 for ch in r] for r in rows], np.int32)
    return lay


@pytest.fixture(scope="module")
def trainer():
    """ACCEL on a trivial maze: open 2x2 rooms (bordered 4x4), random NCA levels of that size and
    their small edits."""
    tr = Trainer(NET, tiny_cfg(levels={"method": "accel", "nca_prob": 0.3}), compiler_options=FAST_COMPILE)
    return tr, tr.init(jax.random.PRNGKey(3))


@pytest.fixture(scope="module")
def trained(trainer):
    tr, state = trainer
    returns = []
    for _ in range(30):
        state, m = tr.update(state)
        returns.append(float(m["mean_return"]))
    return state, returns, m


def test_training_rollout_rewards_auto_reset_and_horizon(trainer):
    trainer, state = trainer
    reach = level(["XXXXX", "X   X", "XXXXX", "XXXXX", "XXXXX"])  # start (1,1), goal (1,3)
    walled = level(["XXXXX", "X X X", "XXXXX", "XXXXX", "XXXXX"])  # goal cut off
    layouts = np.stack([reach] * 6 + [walled] * 2)
    starts = np.tile([1, 1], (8, 1))
    goals = np.tile([1, 3], (8, 1))
    levels = Levels(jnp.asarray(layouts), jnp.asarray(starts, jnp.int32), jnp.asarray(goals, jnp.int32))
    params = state.params
    roll = jax.jit(trainer.rollout, compiler_options=FAST_COMPILE)
    traj, last_value = jax.device_get(roll(params, levels, jax.random.PRNGKey(1)))
    h = trainer.horizon
    assert traj.reward.shape == (h, 8) and last_value.shape == (8,)
    # Unreachable goal: one episode ending at the horizon, no reward.
    assert (traj.reward[:, 6:] == 0).all() and not traj.reached[:, 6:].any()
    assert (traj.done[:, 6:].sum(0) == 1).all() and traj.done[h - 1, 6:].all()
    # Reachable: reward 1 - 0.9 t / horizon with t the episode's length, then a new episode
    # from the start (auto-reset); episodes end exactly at the goal or the horizon.
    n_reached = 0
    for e in range(6):
        t_ep = 0
        for t in range(h):
            t_ep += 1
            if traj.reached[t, e]:
                n_reached += 1
                assert traj.done[t, e]
                assert traj.reward[t, e] == pytest.approx(1 - 0.9 * t_ep / h)
                # The next step starts at the start tile: the goal is 2 tiles east of it.
                if t + 1 < h:
                    view = traj.view[t + 1, e]
                    assert (view == 2).sum() <= 1 and view[4, 2] == 0
                t_ep = 0
            else:
                assert traj.reward[t, e] == 0 and traj.done[t, e] == (t_ep == h)
    assert n_reached > 0


def test_ppo_updates_raise_return_on_trivial_maze(trained):
    _, returns, _ = trained
    assert np.isfinite(returns).all()
    assert np.mean(returns[-5:]) > np.mean(returns[:5]) + 0.05


def test_accel_level_sampler_fills_buffer_and_keeps_levels_solvable(trained):
    state, _, m = trained
    buf = jax.device_get(state.buffer)
    assert buf.valid.all() and float(m["replayed"]) + float(m["edited"]) > 0
    assert 0 <= float(m["nca"]) <= 1
    assert (buf.levels.layout[:, 1:-1, 1:-1] == 1).any()  # edits added walls to the open rooms
    length, start, goal = jax.device_get(solve(jnp.asarray(buf.levels.layout)))
    assert (length > 0).all()
    np.testing.assert_array_equal(start, buf.levels.start)
    np.testing.assert_array_equal(goal, buf.levels.goal)
    ring = np.ones(buf.levels.layout.shape[1:], bool)
    ring[1:-1, 1:-1] = False
    assert (buf.levels.layout[:, ring] == 1).all()


def test_min_interior_levels_are_smaller_mazes_inside_the_fixed_array():
    from omegaconf import OmegaConf

    from nca_qd.agent.levels import buffer_init, choose_levels

    cfg = OmegaConf.create({"method": "dr", "density": [0.0, 0.0], "tries": 1, "min_interior": 3})
    levels, _, _ = choose_levels(
        jax.random.PRNGKey(3), buffer_init(4, (10, 10)), jnp.int32(0), 64, (8, 8), cfg
    )
    lay = np.asarray(levels.layout)
    free = lay == 0
    rows, cols = free.any(2).sum(1), free.any(1).sum(1)  # the open region's height and width
    assert rows.min() >= 3 and cols.min() >= 3 and rows.max() == 8 and len(set(rows)) > 2
    for i in range(len(lay)):  # an open rectangle in the top-left corner, walls elsewhere
        np.testing.assert_array_equal(free[i, 1 : rows[i] + 1, 1 : cols[i] + 1], True)
        assert free[i].sum() == rows[i] * cols[i]
        # start and goal: opposite corners of the open rectangle (its longest shortest path)
        assert {tuple(levels.start[i].tolist()), tuple(levels.goal[i].tolist())} == {
            (1, 1),
            (int(rows[i]), int(cols[i])),
        }


def test_large_levels_get_the_sweep_and_small_ones_stay_exact():
    """levels.solver=auto: exact start/goal up to 32x32 interiors (unchanged training there),
    the double sweep beyond; a 40x40 batch of DR + NCA levels is solvable, its start and goal
    free, the goal the farthest tile from the start by an independent BFS."""
    from collections import deque

    from nca_qd.agent.levels import buffer_init, choose_levels, solver_for

    assert solver_for("auto", (32, 32)) == "exact" and solver_for(None, (16, 16)) == "exact"
    assert solver_for("auto", (33, 32)) == "sweep" and solver_for("exact", (64, 64)) == "exact"
    with pytest.raises(ValueError, match="levels.solver"):
        solver_for("bogus", (16, 16))
    cfg = OmegaConf.create(
        {
            "method": "accel",
            "density": [0.0, 0.5],
            "tries": 2,
            "nca_prob": 0.5,
            "nca_sigma": [0.2, 1.0],
            "nca_iters": 20,
            "replay_prob": 0.5,
            "edit_prob": 0.5,
            "max_edits": 5,
            "min_fill": 100,
            "temperature": 0.3,
            "staleness": 0.3,
        }
    )
    levels, _, kind = choose_levels(
        jax.random.PRNGKey(0), buffer_init(8, (42, 42)), jnp.int32(0), 8, (40, 40), cfg
    )
    lay, start, goal = (np.asarray(x) for x in (levels.layout, levels.start, levels.goal))
    assert set(np.asarray(kind).tolist()) <= {2, 3}
    for i in range(len(lay)):
        free = lay[i] == 0
        s, g = tuple(start[i]), tuple(goal[i])
        assert free[s] and free[g] and s != g
        dist = {s: 0}
        todo = deque([s])
        while todo:
            y, x = todo.popleft()
            for p in ((y + 1, x), (y - 1, x), (y, x + 1), (y, x - 1)):
                if free[p] and p not in dist:
                    dist[p] = dist[(y, x)] + 1
                    todo.append(p)
        assert g in dist and dist[g] == max(dist.values())  # the goal: the farthest tile from the start


def test_heldout_set_with_nca_mazes_at_a_larger_size():
    from experiments.cli import compose_config
    from nca_qd.agent.train import heldout_levels, heldout_nca_iters

    cfg = compose_config(
        "train_agent",
        ["heldout.interior=[40,40]", "heldout.n_random=2", "heldout.n_nca=3", "heldout.paper_map=null"],
    )
    assert heldout_nca_iters(cfg) == 125  # 50 at 16x16 ... 200 at 64x64, linear in the side
    levels, names = heldout_levels(cfg)
    assert names == ["random_0", "random_1", "nca_0", "nca_1", "nca_2"]
    assert levels.layout.shape == (5, 42, 42)
    nca = np.asarray(levels.layout[2:])
    assert not np.array_equal(nca[0], nca[1])  # three different generators


def test_heldout_set_with_mazes_of_a_qd_runs_elites(tmp_path):
    """heldout.elites_from: the run's solvable elites grown at the held-out size; an unknown
    or non-maze directory is one clear error."""
    from experiments.cli import compose_config
    from nca_qd.agent.train import heldout_levels
    from nca_qd.errors import NcaQdError

    run = tmp_path / "maze_run"
    fake_maze_run(run)  # one generator in cell 0 (objective 1), cell 1 empty
    over = ["heldout.interior=[20,20]", "heldout.n_random=1", "heldout.paper_map=null", "heldout.n_elites=5"]
    cfg = compose_config("train_agent", [*over, f"heldout.elites_from={run}"])
    levels, names = heldout_levels(cfg)
    assert names == ["random_0", "elite_c0"]  # the only solvable elite, sampled once
    from nca_qd.agent.train import heldout_nca_iters
    from nca_qd.domains import make_domain
    from nca_qd.pipeline import generate, make_generator
    from nca_qd.run_dir import load_archive, load_run_config

    domain = make_domain(load_run_config(run).domain)
    genotype = load_archive(run, "result")["genotypes"][[0]]
    grown = generate(domain, make_generator(domain), genotype, shape=(20, 20), n_iters=heldout_nca_iters(cfg))
    lay = np.asarray(levels.layout[-1])
    np.testing.assert_array_equal(lay, np.pad(grown[0], 1, constant_values=1))
    start, goal = tuple(np.asarray(levels.start[-1])), tuple(np.asarray(levels.goal[-1]))
    assert lay[start] == 0 and lay[goal] == 0 and start != goal
    with pytest.raises(NcaQdError, match="not a run directory"):
        heldout_levels(compose_config("train_agent", [*over, f"heldout.elites_from={tmp_path}"]))


# --------------------------------------------------------------------------- shipped agent

OPEN_ROOM = np.pad(np.zeros((16, 16), np.int32), 1, constant_values=1)


def test_learned_is_the_maze_default_and_loads():
    from experiments.cli import compose_config
    from nca_qd.agent import load_agent
    from nca_qd.domains.maze import DEFAULT_AGENT

    assert DEFAULT_AGENT["kind"] == "learned"
    for name in ("maze", "maze_entropy"):
        assert compose_config("run", [f"domain={name}"]).domain.agent.kind == "learned"
    net, params, meta = load_agent()
    assert meta["network"]["hidden"] == net.hidden and meta["env_steps"] > 0
    assert 0 <= meta["heldout_success"] <= 1


def test_shipped_agent_solves_open_room_and_is_deterministic():
    start, goal, length = solve_start_goal(OPEN_ROOM)
    assert length == 30
    key = jax.random.PRNGKey(0)
    res = run_agent(OPEN_ROOM, start, goal, key, kind="learned", episodes=50)
    assert res.reached.mean() >= 0.9
    again = run_agent(OPEN_ROOM, start, goal, key, kind="learned", episodes=50)
    np.testing.assert_array_equal(res.lengths, again.lengths)
    other = run_agent(OPEN_ROOM, start, goal, jax.random.PRNGKey(1), kind="learned", episodes=50)
    assert not np.array_equal(res.lengths, other.lengths)  # sampled actions


def test_learned_agent_from_other_weights(tmp_path):
    """``weights=<dir>`` runs the learned kind with those parameters: a copy of the shipped ones
    plays exactly as the shipped agent, all-zero ones (a uniform random policy) wander longer;
    weights for a rule-based kind or a directory without weights: one clear error."""
    from nca_qd.agent import load_agent, save_agent
    from nca_qd.domains import make_domain

    net, params, meta = load_agent()
    save_agent(params, meta, tmp_path / "copy")
    save_agent(jax.tree.map(jnp.zeros_like, params), meta, tmp_path / "zero")
    start, goal, _ = solve_start_goal(OPEN_ROOM)
    key = jax.random.PRNGKey(0)
    shipped = run_agent(OPEN_ROOM, start, goal, key, kind="learned", episodes=50)
    copy = run_agent(OPEN_ROOM, start, goal, key, kind="learned", episodes=50, weights=str(tmp_path / "copy"))
    np.testing.assert_array_equal(shipped.lengths, copy.lengths)
    zero = run_agent(OPEN_ROOM, start, goal, key, kind="learned", episodes=50, weights=str(tmp_path / "zero"))
    assert zero.lengths.mean() > 2 * shipped.lengths.mean()
    with pytest.raises(NcaQdError, match="only, not to"):
        ma.get_policy("wall_follower", str(tmp_path / "copy"))
    cfg = {
        "name": "maze",
        "size": {"train": [16, 16], "eval": [64, 64]},
        "nca_iters": {"train": 50, "eval": 200},
        "measures": {"names": ["n_walls", "path_length"], "ranges": [[0, 256], [0, 648]], "cells": [8, 8]},
        "agent": {"kind": "learned", "weights": str(tmp_path / "nothing")},
    }
    with pytest.raises(NcaQdError, match="nothing"):
        make_domain(cfg)


# --------------------------------------------------------------------------- entry points


def run_main(module, argv, monkeypatch, capsys):
    import importlib
    import sys

    from experiments.cli import main_guard

    monkeypatch.setattr(sys, "argv", [module] + list(argv))
    with pytest.raises(SystemExit) as exc:
        main_guard(importlib.import_module(module).main)()
    out = capsys.readouterr()
    return exc.value.code, out.out, out.err


@pytest.mark.parametrize(
    "argv",
    [
        ["n_envs=0"],
        ["levels.method=bogus"],
        ["bogus_key=1"],
        ["n_envs=6", "ppo.minibatches=4"],
        ["heldout.interior=[1,5]"],
        ["levels.min_interior=0"],
        ["levels.solver=bogus"],
        ["heldout.n_nca=-1"],
    ],
)
def test_train_agent_bad_input_is_one_error_line(argv, monkeypatch, capsys, tmp_path):
    code, out, err = run_main("experiments.train_agent", argv + [f"run_dir={tmp_path}"], monkeypatch, capsys)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: ")


def test_train_agent_resumes_from_its_compressed_checkpoint_to_the_same_end(tmp_path, monkeypatch, capsys):
    """Stopped after 2 of 4 updates and resumed, training writes the metrics an uninterrupted
    run writes; its checkpoint is zlib-compressed (a level buffer of 0/1 tiles)."""
    import csv

    tiny = [
        "n_envs=8",
        "horizon=16",
        "interior=[4,4]",
        "network.hidden=8",
        "network.head_hidden=8",
        "network.conv_features=4",
        "ppo.minibatches=2",
        "heldout.n_random=2",
        "heldout.paper_map=null",
        "heldout.every_updates=2",
        "heldout.episodes=2",
        "checkpoint_every=1",
        "progress=false",
        "levels.min_fill=2",
        "levels.buffer_size=8",
    ]
    whole, part = tmp_path / "whole", tmp_path / "part"
    for argv in (
        [f"run_dir={whole}", *tiny, "total_env_steps=512"],
        [f"run_dir={part}", *tiny, "total_env_steps=256"],
        [f"resume={part}", "total_env_steps=512"],
    ):
        code, _, err = run_main("experiments.train_agent", argv, monkeypatch, capsys)
        assert code == 0, err
    assert (part / "checkpoint.msgpack").read_bytes()[:1] == b"\x78"  # zlib

    def rows(d):
        with open(d / "metrics.csv") as fh:
            return [
                {k: r[k] for k in ("update", "env_steps", "mean_return", "loss", "heldout_success")}
                for r in csv.DictReader(fh)
            ]

    assert len(rows(whole)) == 4 and rows(whole) == rows(part)

    # Shipping a run that started from a shipped agent extends that agent's training record,
    # also when it ships over the very files it started from (and ships twice).
    from nca_qd.agent.train import init_from_steps

    ship = tmp_path / "ship"
    child = tmp_path / "child"
    for argv in (
        [f"resume={part}", "ship_only=true", f"ship_dir={ship}"],
        [f"run_dir={child}", *tiny, f"init_from={ship}/maze_agent.msgpack", "total_env_steps=256"],
        [f"resume={child}", "ship=true", f"ship_dir={ship}"],
        [f"resume={child}", "ship_only=true", f"ship_dir={ship}"],
    ):
        code, _, err = run_main("experiments.train_agent", argv, monkeypatch, capsys)
        assert code == 0, err
    meta = json.loads((ship / "maze_agent.json").read_text())
    first, second = meta["lineage"]
    assert first["run"] == "part" and second["run"] == "child"
    e1, e2 = init_from_steps(part), init_from_steps(child)  # steps behind each run's best
    assert first["env_steps"] == e1 and second["env_steps"] == e2 == 256
    assert meta["init_from_env_steps"] == e1 and meta["total_env_steps"] == e1 + e2
    assert second["device"].startswith("cpu")


def fake_maze_run(path):
    """A maze QD run directory holding one random generator (what maze_transfer reads)."""
    from experiments.cli import compose_config
    from nca_qd.io import save_npz
    from nca_qd.nca import NCAGenerator

    cfg = compose_config("run", ["domain=maze", "domain.nca_iters.train=3", "domain.nca_iters.eval=3"])
    path.mkdir()
    (path / "config.yaml").write_text(OmegaConf.to_yaml(cfg))
    d = NCAGenerator(n_tiles=2).n_params
    g = np.random.default_rng(0).normal(0, 0.2, (2, d)).astype(np.float32)
    save_npz(path / "archive_result.npz", {"genotypes": g, "objective": np.array([1.0, -np.inf])})


def test_maze_transfer_end_to_end(tmp_path, monkeypatch, capsys):
    run = tmp_path / "run"
    fake_maze_run(run)
    out = tmp_path / "out"
    # episodes=50 and horizon 648: the 18x18 rollouts reuse the shipped-agent test's compile
    # (66x66 capped at 648 steps to stay quick).
    argv = [
        f"run_dir={run}",
        f"out={out}",
        "episodes=50",
        "max_horizon=648",
        "progress=false",
        "pictures=false",
        "baseline.n_mazes=1",
        "baseline.episodes=50",
        "baseline.batch=1",
        "baseline.max_tries=2",
        "baseline.path_ratio=[0.0,100.0]",
    ]
    code, stdout, err = run_main("experiments.maze_transfer", argv, monkeypatch, capsys)
    assert code == 0, err
    results = [json.loads(line) for line in stdout.splitlines() if line.startswith("{")]
    assert [r["case"] for r in results] == [
        "paper_nca_18x18",
        "paper_nca_66x66",
        "own_nca_18x18",
        "own_nca_66x66",
        "baseline_66x66",
    ]
    for r in results:
        assert {"case", "episodes", "success_rate", "stderr"} <= set(r)
        assert 0 <= r["success_rate"] <= 1 and r["stderr"] >= 0
    assert results[-1]["mazes"] == 1 and results[-1]["episodes"] == 50
    assert (out / "results.jsonl").read_text().count("\n") == 5
    code, _, err = run_main("experiments.maze_transfer", ["agent=bogus", f"out={out}"], monkeypatch, capsys)
    assert code == 2 and err.startswith("error: ") and len(err.strip().splitlines()) == 1


def test_path_picture(tmp_path):
    from nca_qd.agent.transfer import draw_path

    path = np.array([[1, 1], [1, 2], [2, 2], [3, 2]])
    draw_path(tmp_path / "p.png", OPEN_ROOM, path[0], path[-1], path, "a path")
    assert (tmp_path / "p.png").read_bytes()[:4] == b"\x89PNG"


def test_own_nca_elite_is_the_best_objective_maze_with_the_longest_path(monkeypatch):
    import nca_qd.pipeline
    from nca_qd.agent.transfer import longest_path_elite

    room = np.zeros((6, 6), np.int32)
    corridor = np.ones((6, 6), np.int32)
    corridor[0, :2] = 0  # most walls, path 1
    snake = np.ones((6, 6), np.int32)
    snake[0, :] = snake[:, 5] = snake[5, :] = 0  # path 15
    regions = np.stack([room, corridor, snake, room])
    monkeypatch.setattr(nca_qd.pipeline, "generate", lambda d, g, x, which: regions[x[:, 0]])

    class Domain:
        assemble = staticmethod(lambda r: np.pad(r, ((0, 0), (1, 1), (1, 1)), constant_values=1))

    archive = {
        "objective": np.array([1.0, 1.0, 1.0, np.nan, 0.0]),
        "genotypes": np.array([[0], [1], [2], [0], [2]]),
    }
    assert longest_path_elite(Domain(), None, archive) == 2
    assert longest_path_elite(Domain(), None, archive, chunk=2) == 2  # across chunks
    archive["objective"][2] = 0.0  # the snake no longer among the best: the room's path (10) wins
    assert longest_path_elite(Domain(), None, archive) == 0
    assert (
        longest_path_elite(
            Domain(), None, {"objective": np.full(3, np.nan), "genotypes": np.zeros((3, 1), int)}
        )
        is None
    )
