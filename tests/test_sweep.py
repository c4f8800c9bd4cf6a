"""`python -m experiments.sweep`: throughput against agents for several layouts, resumable."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from sim_layouts import WAREHOUSE

from experiments.cli import main_guard
from experiments.sweep import by_tenth, main, read_records
from nca_qd.errors import NcaQdError
from nca_qd.sim.rhcr import simulate_scenario
from nca_qd.sim.scenario import build_scenario

OPEN = [r.replace("@", ".") if i == 2 else r for i, r in enumerate(WAREHOUSE)]
REPO = Path(__file__).resolve().parents[1]


def write_map(path: Path, rows: list[str]) -> str:
    path.write_text(json.dumps({"name": path.stem, "layout": rows}))
    return str(path)


@pytest.fixture
def maps(tmp_path):
    return write_map(tmp_path / "shelves.json", WAREHOUSE), write_map(tmp_path / "open.json", OPEN)


def sweep(out, layouts, *extra):
    argv = [f"layouts=[{','.join(layouts)}]", "agents=[4,8]", "T=40", "planner=pibt", f"out={out}"]
    return main([*argv, *extra])


def test_every_point_is_recorded_and_summarised(tmp_path, maps):
    out = tmp_path / "sweep"
    assert sweep(out, maps, "seeds=2") == 0
    rows = list(csv.DictReader(open(out / "summary.csv")))
    assert [(r["layout"], r["agents"]) for r in rows] == [
        ("shelves", "4"),
        ("shelves", "8"),
        ("open", "4"),
        ("open", "8"),
    ]
    for r in rows:
        runs = read_records(out / f"{r['layout']}_{r['agents']}.jsonl")
        assert sorted(runs) == [0, 1]
        thr = [runs[s]["throughput"] for s in (0, 1)]
        assert float(r["throughput_mean"]) == pytest.approx(np.mean(thr), abs=1e-6)
        assert float(r["throughput_se"]) == pytest.approx(np.std(thr, ddof=1) / np.sqrt(2), abs=1e-6)
        assert float(r["success_rate"]) == np.mean([runs[s]["success"] for s in (0, 1)])
        for s in (0, 1):  # the tenths of the horizon add up to the run's throughput
            assert np.mean(runs[s]["throughput_by_tenth"]) == pytest.approx(runs[s]["throughput"], abs=1e-3)
        late = np.mean([runs[s]["throughput_by_tenth"][-1] for s in (0, 1)])
        assert float(r["throughput_last_tenth"]) == pytest.approx(late, abs=1e-6)
    # each record is the run the simulator gives for that seed, not something the sweep made up
    scen = build_scenario(OPEN, "warehouse_even", n_agents=8)
    direct = simulate_scenario(scen, 8, 40, seed=1, planner="pibt").summary()
    assert read_records(out / "open_8.jsonl")[1]["throughput"] == direct["throughput"]
    md = (out / "summary.md").read_text()
    assert "| agents | shelves | open |" in md and "2 of 2" in md
    assert (out / "throughput_vs_agents.png").stat().st_size > 1000


def test_a_second_call_runs_only_the_missing_seeds(tmp_path, maps, capsys):
    out = tmp_path / "sweep"
    sweep(out, maps[:1], "seeds=1")
    first = (out / "shelves_4.jsonl").read_text()
    # a kill during a write leaves a line cut short: it is skipped, and the next run starts anew
    with open(out / "shelves_8.jsonl", "a") as f:
        f.write('{"seed": 1, "throughp')
    capsys.readouterr()
    sweep(out, maps[:1], "seeds=2")
    printed = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert sorted((p["agents"], p["seed"]) for p in printed) == [(4, 1), (8, 1)]
    assert (out / "shelves_4.jsonl").read_text().startswith(first)
    assert sorted(read_records(out / "shelves_8.jsonl")) == [0, 1]
    rows = list(csv.DictReader(open(out / "summary.csv")))
    assert [r["runs"] for r in rows] == ["2", "2"]


def test_runs_of_other_settings_or_another_layout_are_not_mixed(tmp_path, maps):
    out = tmp_path / "sweep"
    sweep(out, maps[:1], "seeds=1")
    with pytest.raises(NcaQdError, match="holds runs with T=40, this call asks T=50"):
        sweep(out, maps[:1], "seeds=1", "T=50")
    write_map(Path(maps[0]), OPEN)  # same name, other layout
    with pytest.raises(NcaQdError, match="another layout named shelves"):
        sweep(out, maps[:1], "seeds=1")


@pytest.mark.parametrize(
    "args, message",
    [
        (["agents=5"], "agents must be a non-empty list"),
        (["agents=[4,-1]"], "agents must be a list of positive integers"),
        (["simulator=screen"], "a sweep runs the exact simulators"),
        (["planner=astar"], "planner must be one of rhcr, pibt, pibt_swap"),
    ],
)
def test_bad_input_is_one_line_exit_2(tmp_path, maps, args, message, monkeypatch, capsys):
    """Through the command's own entry point (main_guard), in this process; the SIGTERM case
    below runs the real `python -m experiments.sweep`."""
    argv = [f"layouts=[{maps[0]}]", "agents=[4]", "T=10", f"out={tmp_path / 'o'}", *args]
    monkeypatch.setattr(sys, "argv", ["prog", *argv])
    with pytest.raises(SystemExit) as exc:
        main_guard(main)()
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and len(err) == 1 and message in err[0], err


def test_two_layouts_with_one_name_are_refused(tmp_path, maps):
    (tmp_path / "b").mkdir()
    other = write_map(tmp_path / "b" / "shelves.json", OPEN)
    with pytest.raises(NcaQdError, match="layout file names must differ"):
        sweep(tmp_path / "o", [maps[0], other], "seeds=1")


def test_the_summary_covers_every_point_the_folder_holds(tmp_path, maps):
    out = tmp_path / "sweep"
    base = [f"layouts=[{maps[0]}]", "T=30", "planner=pibt", f"out={out}", "seeds=1"]
    main([*base, "agents=[8]"])
    main([*base, "agents=[4]", "seed=1"])  # another count, another seed: a later stage
    rows = list(csv.DictReader(open(out / "summary.csv")))
    assert [(r["agents"], r["runs"]) for r in rows] == [("4", "1"), ("8", "1")]
    assert sorted(read_records(out / "shelves_4.jsonl")) == [1]
    main([f"layouts=[{maps[1]}]", "T=30", "planner=pibt", f"out={out}", "seeds=1", "agents=[4]"])
    md = (out / "summary.md").read_text()
    assert "| agents | shelves | open |" in md
    assert [line.split(" | ")[2] for line in md.splitlines() if line.startswith("| 8 |")] == ["not run |"]


def test_a_run_stopped_as_congested_finishes_nothing_after_its_stop():
    tasks = np.ones(37)  # one task a step, stopped at t = 37 of T = 100
    tenths = by_tenth(tasks, 100)
    assert tenths[:3] == [1.0, 1.0, 1.0] and tenths[3] == pytest.approx(0.7) and tenths[4:] == [0.0] * 6
    assert np.mean(tenths) == pytest.approx(37 / 100)


def test_sigterm_keeps_every_run_that_ended_and_cancels_the_rest(tmp_path):
    import signal

    from nca_qd.io import array_to_rows
    from nca_qd.layouts import get_layout
    from nca_qd.layouts.warehouse import human_layout

    rows = array_to_rows(human_layout((33, 36)), get_layout("warehouse_even").tiles)
    layout = write_map(tmp_path / "human.json", rows)
    out = tmp_path / "sweep"
    argv = [f"layouts=[{layout}]", "agents=[100]", "T=3000", "seeds=40", "threads=2", f"out={out}"]
    # stdout is read through its own buffer to the end (communicate() would read the pipe
    # beneath it and lose a line that readline had already buffered); stderr goes to a file.
    with open(tmp_path / "err.txt", "w") as err_file:
        proc = subprocess.Popen(
            [sys.executable, "-m", "experiments.sweep", *argv],
            cwd=REPO,
            stdout=subprocess.PIPE,
            stderr=err_file,
            text=True,
        )
        first = proc.stdout.readline()  # one run has ended; another is under way in the other thread
        proc.send_signal(signal.SIGTERM)
        rest = proc.stdout.read()
        proc.wait(timeout=300)
    err = (tmp_path / "err.txt").read_text()
    printed = [json.loads(line) for line in [first, *rest.splitlines()]]
    kept = read_records(out / "human_100.jsonl")
    assert proc.returncode == 130 and "finished runs are kept" in err, err
    assert sorted(kept) == sorted(p["seed"] for p in printed)  # every run that ended is on disk
    assert 2 <= len(kept) < 40  # the run under way was kept, the ones not started were cancelled
    summary = list(csv.DictReader(open(out / "summary.csv")))  # and the summary counts them
    assert [(r["agents"], r["runs"]) for r in summary] == [("100", str(len(kept)))]


def test_a_second_interrupt_drops_the_runs_under_way(monkeypatch, capsys):
    """The first interrupt waits for the runs under way; a second one ends the process at once
    (the core's threads cannot be stopped), the finished runs kept. In this process: the core's
    run is a stand-in that blocks, the signals are this process's own SIGINTs."""
    import os
    import signal
    import threading
    import types

    import experiments.sweep as sweep

    release = threading.Event()

    def fake_run(scen, settings, seed):
        if seed > 0:
            release.wait(60)
        return types.SimpleNamespace(seed=seed)

    def fake_abandon(code):
        release.set()
        raise SystemExit(code)

    kept = []

    def keep(res):
        kept.append(res.seed)
        for delay in (0.3, 1.0):  # the first lands while the point waits, the second while draining
            threading.Timer(delay, os.kill, (os.getpid(), signal.SIGINT)).start()

    monkeypatch.setattr(sweep, "exact_run", fake_run)
    monkeypatch.setattr(sweep, "abandon", fake_abandon)
    with pytest.raises(SystemExit) as stop:
        sweep.run_point(None, None, [0, 1, 2, 3], 2, keep)
    err = capsys.readouterr().err
    assert stop.value.code == 130 and kept == [0]
    assert "waiting for the 2 run(s) under way" in err and "the runs under way are dropped" in err


def test_an_interrupt_inside_keep_neither_splits_a_run_nor_loses_a_finished_one(monkeypatch):
    """The interrupt lands inside ``keep``, between the run's line on disk and its printed
    line. It is held until the run is whole, then stops the point: every run that started (the
    one being kept, one that had ended beside it, any under way) is kept once, on disk and
    printed alike, and the ones not started are cancelled. Seeds 0 and 1 end at once; the
    others are held until the point waits for its runs under way, so none can end before the
    interruption is handled, on any machine load."""
    import signal
    import threading
    import types
    from concurrent.futures import wait as real_wait

    import experiments.sweep as sweep

    release, started = threading.Event(), []

    def fake_run(scen, settings, seed):
        started.append(seed)
        if seed > 1:
            assert release.wait(60)
        return types.SimpleNamespace(seed=seed)

    def waiting(fs):
        release.set()
        return real_wait(fs)

    monkeypatch.setattr(sweep, "exact_run", fake_run)
    monkeypatch.setattr(sweep, "wait", waiting)
    disk, printed = [], []

    def keep(res):
        disk.append(res.seed)
        if len(disk) == 1:
            signal.raise_signal(signal.SIGINT)  # Python acts on it at the next instruction
        printed.append(res.seed)

    with pytest.raises(KeyboardInterrupt):
        sweep.run_point(None, None, list(range(40)), 2, keep)
    assert disk == printed  # no run split between disk and print
    assert len(set(disk)) == len(disk)  # each kept once
    assert sorted(disk) == sorted(started)  # every run that started was kept
    assert 1 <= len(disk) <= 4  # the runs not started were cancelled


@pytest.mark.parametrize("missing", ["layouts", "agents", "out"])
def test_a_required_setting_left_out_is_one_line_exit_2(tmp_path, maps, monkeypatch, capsys, missing):
    """The YAML's ``???`` settings: leaving one out names it, exit 2, no traceback."""
    given = {"layouts": f"layouts=[{maps[0]}]", "agents": "agents=[4]", "out": f"out={tmp_path / 'o'}"}
    argv = [v for k, v in given.items() if k != missing] + ["T=10"]
    monkeypatch.setattr(sys, "argv", ["prog", *argv])
    with pytest.raises(SystemExit) as exc:
        main_guard(main)()
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2
    assert len(err) == 1 and err[0].startswith("error: ") and f"{missing}=" in err[0], err
    assert not (tmp_path / "o").exists()
