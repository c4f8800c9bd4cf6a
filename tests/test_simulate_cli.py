"""`python -m experiments.simulate`: output lines, paths file, and one-line errors for bad input."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from nca_qd.sim.checker import check_run, recount_tasks

WAREHOUSE = [
    "............",
    "w.eeee.eeeew",
    "..@@@@.@@@@.",
    "..eeee.eeee.",
    "w..........w",
    "..eeee.eeee.",
    "..@@@@.@@@@.",
    "w.eeee.eeeew",
    "............",
]


def write_map(path: Path, rows: list[str]) -> str:
    path.write_text(
        json.dumps({"name": path.stem, "n_row": len(rows), "n_col": len(rows[0]), "layout": rows})
    )
    return str(path)


def run_cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "experiments.simulate", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_prints_one_line_per_run_and_a_summary(tmp_path):
    layout = write_map(tmp_path / "wh.json", WAREHOUSE)
    out = tmp_path / "paths.npz"
    proc = run_cli(
        "domain=warehouse_even",
        f"layout={layout}",
        "agents=12",
        "T=60",
        "seeds=3",
        "seed=5",
        "threads=2",
        f"paths_out={out}",
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr
    lines = [json.loads(line) for line in proc.stdout.strip().splitlines()]
    assert len(lines) == 4
    assert [r["seed"] for r in lines[:3]] == [5, 6, 7]
    for r in lines[:3]:
        assert {"seed", "throughput", "success", "stop_time", "cpu_seconds"} <= set(r)
        assert r["success"] and r["stop_time"] == 60 and r["throughput"] > 0
    summary = lines[3]
    thr = np.array([r["throughput"] for r in lines[:3]])
    assert summary["runs"] == 3 and summary["success_rate"] == 1.0
    assert summary["throughput_mean"] == pytest.approx(thr.mean())
    assert summary["throughput_se"] == pytest.approx(thr.std(ddof=1) / np.sqrt(3))

    # The paths file replays cleanly through the checker and matches the printed throughput.
    data = np.load(out)
    for r in lines[:3]:
        s = r["seed"]
        off, flat = data[f"goal_offsets_seed{s}"], data[f"goals_seed{s}"]
        goals = [flat[a:b] for a, b in zip(off[:-1], off[1:])]
        paths = data[f"paths_seed{s}"]
        done = recount_tasks(paths, goals)
        res = SimpleNamespace(
            paths=paths,
            goals=goals,
            stop_time=60,
            T=60,
            scenario="warehouse_even",
            tasks_per_step=done,
            throughput=done.sum() / 60,
        )
        check_run(res, WAREHOUSE)
        assert done.sum() / 60 == pytest.approx(r["throughput"])


def test_usage_map_is_the_share_of_timesteps_each_tile_was_held(tmp_path):
    # Recounted from the executed paths of the same runs (paths_out), not from the simulator's
    # own visit counts: per run, agents on the tile at times 1..stop_time over stop_time.
    layout = write_map(tmp_path / "wh.json", WAREHOUSE)
    png, paths = tmp_path / "usage.png", tmp_path / "paths.npz"
    args = ("agents=12", "T=40", "seeds=2", f"usage_out={png}", f"paths_out={paths}")
    proc = run_cli(f"layout={layout}", *args, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert png.stat().st_size > 0
    data = np.load(paths)
    expect = np.zeros((len(WAREHOUSE), len(WAREHOUSE[0])))
    for seed in (0, 1):
        steps = data[f"paths_seed{seed}"][1:]
        held = np.zeros_like(expect)
        np.add.at(held, (steps[..., 0].ravel(), steps[..., 1].ravel()), 1)
        expect += held / len(steps) / 2
    lines = (tmp_path / "usage.csv").read_text().splitlines()
    assert lines[0] == "row,col,tile,occupancy"
    got = np.zeros_like(expect)
    for line in lines[1:]:
        r, c, tile, occ = line.split(",")
        assert tile == WAREHOUSE[int(r)][int(c)]
        got[int(r), int(c)] = float(occ)
    np.testing.assert_allclose(got, expect, atol=1e-6)
    assert got.sum() == pytest.approx(12)  # every agent somewhere at every step
    assert (got[np.array([list(row) for row in WAREHOUSE]) == "@"] == 0).all()


@pytest.mark.parametrize(
    "rows, args, message",
    [
        (WAREHOUSE, ["agents=500"], "traversable tiles"),
        (["e.@w", "..@."], [], "not all connected"),
        (WAREHOUSE, ["domain=warehouse_mixed"], "unknown scenario"),
        (WAREHOUSE, ["T=0"], "T must be >= 1"),
        (WAREHOUSE, ["T=-5"], "T must be >= 1"),
        (WAREHOUSE, ["simulator=quantum"], "unknown simulator 'quantum'"),
        (WAREHOUSE, ["domain=manufacturing"], "unknown tile"),
        (WAREHOUSE, ["pbs_max_nodes=-3"], "pbs_max_nodes must be a positive integer, auto or null"),
        (WAREHOUSE, ["plan_time_limit_s=0"], "plan_time_limit_s must be a positive number"),
        (WAREHOUSE, ["prioritize_start=maybe"], "prioritize_start must be true or false"),
        (WAREHOUSE, ["starts=fixed"], "starts must be one of random, reference, got 'fixed'"),
        (WAREHOUSE, ["simulator=screen", "screen_crowd_mean=-1"], "crowding threshold"),
        (WAREHOUSE, ["usage_out=usage.txt"], "usage_out=usage.txt: must name a .png file"),
        (WAREHOUSE, ["usage_out=nowhere/usage.png"], "folder nowhere does not exist"),
    ],
)
def test_bad_input_is_one_line_exit_2(tmp_path, rows, args, message):
    layout = write_map(tmp_path / "m.json", rows)
    proc = run_cli(f"layout={layout}", "agents=2", "T=10", "seeds=1", *args, cwd=tmp_path)
    assert proc.returncode == 2
    err = proc.stderr.strip().splitlines()
    assert len(err) == 1 and message in err[0] and "Traceback" not in proc.stderr
    assert proc.stdout == ""


def test_a_map_too_large_for_memory_is_one_line_exit_2(tmp_path):
    # 490,000 goal cells, each with a distance table of 490,000 cells: about 450 GiB
    rows = ["w" + "e" * 698 + "w"] * 700
    layout = write_map(tmp_path / "big.json", rows)
    proc = run_cli(f"layout={layout}", "agents=2", "T=10", "seeds=1", cwd=tmp_path)
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(err) == 1, proc.stderr
    assert "700x700 map" in err[0] and "too large for memory" in err[0] and "GiB needed" in err[0]
    assert proc.stdout == ""


def test_time_limit_says_timed_out(tmp_path):
    big = [row * 6 for row in WAREHOUSE] * 6
    layout = write_map(tmp_path / "big.json", big)
    proc = run_cli(
        "domain=warehouse_even",
        f"layout={layout}",
        "agents=800",
        "T=100000",
        "seeds=1",
        "time_limit_s=0.2",
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr
    run = json.loads(proc.stdout.splitlines()[0])
    assert run["timed_out"] and not run["success"] and run["stop_time"] < 100000


def test_reference_starts_are_one_configuration_for_every_seed(tmp_path):
    layout = write_map(tmp_path / "wh.json", WAREHOUSE)
    starts = {}
    for mode in ("reference", "random"):
        out = tmp_path / f"{mode}.npz"
        proc = run_cli(
            f"layout={layout}",
            "agents=12",
            "T=10",
            "seeds=3",
            f"starts={mode}",
            f"paths_out={out}",
            cwd=tmp_path,
        )
        assert proc.returncode == 0, proc.stderr
        data = np.load(out)
        starts[mode] = [data[f"paths_seed{s}"][0] for s in range(3)]
    assert all((s == starts["reference"][0]).all() for s in starts["reference"])
    assert not all((s == starts["random"][0]).all() for s in starts["random"])


def test_default_starts_leave_the_planner_knobs_and_run_keys_unchanged():
    from nca_qd.sim.rhcr import planner_options

    assert planner_options({"starts": "random"}) == {}
    assert planner_options({"starts": "reference", "pbs_max_nodes": 10}) == {
        "reference_starts": True,
        "pbs_max_nodes": 10,
    }


def test_the_screen_takes_the_domains_crowding_threshold_unless_given_one():
    from omegaconf import OmegaConf

    from experiments.simulate import screen_crowd_mean

    def cfg(domain, value=None):
        return OmegaConf.create({"domain": domain, "screen_crowd_mean": value})

    assert screen_crowd_mean(cfg("warehouse_even")) == 17.0
    assert screen_crowd_mean(cfg("warehouse_uneven")) == 21.0  # its traffic's own
    assert screen_crowd_mean(cfg("manufacturing")) == 22.0
    assert screen_crowd_mean(cfg("warehouse_uneven", 18)) == 18.0
