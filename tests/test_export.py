"""Exports for other MAPF tools, read back by an independent reader written here from the
formats' descriptions (MovingAI benchmark, League of Robot Runners start kit); the public
generator API."""

from __future__ import annotations

import json
import subprocess
import sys
from collections import deque
from pathlib import Path

import numpy as np
import pytest

from nca_qd.errors import NcaQdError
from nca_qd.io import load_map, reference_maps_dir

MAPS = reference_maps_dir()
PAPER = MAPS / "warehouse" / "paper_cma-mae_a5_even_33x36.json"
REPO = Path(__file__).resolve().parents[1]
needs_maps = pytest.mark.skipif(not PAPER.is_file(), reason="shared reference maps not present")


def read_map(path: Path) -> np.ndarray:
    """A MovingAI .map as a bool grid (True: passable)."""
    lines = path.read_text().splitlines()
    assert lines[0] == "type octile" and lines[3] == "map"
    h, w = int(lines[1].split()[1]), int(lines[2].split()[1])
    grid = lines[4 : 4 + h]
    assert len(grid) == h and all(len(r) == w for r in grid)
    assert set("".join(grid)) <= set(".@")
    return np.array([[ch == "." for ch in r] for r in grid])


def bfs(free: np.ndarray, start: tuple[int, int]) -> dict[tuple[int, int], int]:
    seen, queue = {start: 0}, deque([start])
    while queue:
        r, c = queue.popleft()
        for nxt in ((r + 1, c), (r - 1, c), (r, c + 1), (r, c - 1)):
            if 0 <= nxt[0] < free.shape[0] and 0 <= nxt[1] < free.shape[1] and free[nxt] and nxt not in seen:
                seen[nxt] = seen[(r, c)] + 1
                queue.append(nxt)
    return seen


def export(args: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "experiments.export", *args],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=600,
        env={**__import__("os").environ, "JAX_PLATFORMS": "cpu"},
    )


@needs_maps
def test_lorr_problem_reads_back(tmp_path):
    res = export([f"layout={PAPER}", "format=lorr", f"out={tmp_path}", "agents=150", "tasks=400"])
    assert res.returncode == 0, res.stderr
    problem = json.loads((tmp_path / "paper_cma-mae_a5_even_33x36.json").read_text())
    assert problem["teamSize"] == 150 and problem["numTasksReveal"] == 1.0
    rows = load_map(PAPER).rows
    free = read_map(tmp_path / problem["mapFile"])
    assert np.array_equal(~free, np.array([[ch == "@" for ch in r] for r in rows]))  # shelves block
    w = free.shape[1]
    agents = (tmp_path / problem["agentFile"]).read_text().split()
    starts = [int(a) for a in agents[1:]]
    assert int(agents[0]) == 150 == len(starts) == len(set(starts))
    assert all(free[divmod(s, w)] for s in starts)
    lines = (tmp_path / problem["taskFile"]).read_text().splitlines()
    assert int(lines[0]) == 400 == len(lines) - 1
    for line in lines[1:]:
        endpoint, station = (divmod(int(x), w) for x in line.split())
        assert rows[endpoint[0]][endpoint[1]] == "e" and rows[station[0]][station[1]] == "w"
    again = tmp_path / "again"
    assert (
        export([f"layout={PAPER}", "format=lorr", f"out={again}", "agents=150", "tasks=400"]).returncode == 0
    )
    for f in ("json", "map", "agents", "tasks"):  # the same seed, the same files
        name = f"paper_cma-mae_a5_even_33x36.{f}"
        assert (again / name).read_text() == (tmp_path / name).read_text()


@needs_maps
def test_movingai_scenario_reads_back_with_true_path_lengths(tmp_path):
    res = export([f"layout={PAPER}", "format=movingai", f"out={tmp_path}", "agents=40", "seed=3"])
    assert res.returncode == 0, res.stderr
    rows = load_map(PAPER).rows
    free = read_map(tmp_path / "paper_cma-mae_a5_even_33x36.map")
    lines = (tmp_path / "paper_cma-mae_a5_even_33x36.scen").read_text().splitlines()
    assert lines[0] == "version 1" and len(lines) == 41
    starts = set()
    for line in lines[1:]:
        _, name, w, h, sx, sy, gx, gy, length = line.split("\t")
        assert name == "paper_cma-mae_a5_even_33x36.map" and (int(h), int(w)) == free.shape
        start, goal = (int(sy), int(sx)), (int(gy), int(gx))
        starts.add(start)
        assert free[start] and rows[goal[0]][goal[1]] == "e"  # the cycle's first goal: an endpoint
        assert bfs(free, start)[goal] == int(length)
    assert len(starts) == 40


def test_uneven_tasks_favour_the_left_workstations():
    """The uneven warehouse's task assigner: a left workstation is 5 times as likely."""
    from nca_qd.export import lorr_files
    from nca_qd.sim.scenario import build_scenario

    rows = ["w.e@e.w", "w.e@e.w", "w.....w"]
    scen = build_scenario(rows, "warehouse_uneven", n_agents=4)
    tasks = lorr_files(scen, "t", 4, 3000, seed=1)["t.tasks"].splitlines()[1:]
    left = np.mean([int(t.split()[1]) % 7 == 0 for t in tasks])
    assert left == pytest.approx(5 / 6, abs=0.03)


@pytest.mark.parametrize(
    "args, message",
    [
        (["format=lorr", "out=x"], "give one of layout=<file.json>, run=<run dir> or human=true"),
        (["layout=a.json", "run=b", "out=x"], "give one of layout=<file.json>, run=<run dir> or human=true"),
        (["layout=a.json", "format=gif", "out=x"], "unknown format 'gif' (known: movingai, lorr, json)"),
        (["human=true", "rows=40", "out=x"], "human=true needs rows=<R> cols=<C>"),
        (["human=true", "domain=manufacturing", "rows=9", "cols=9", "out=x"], "draws warehouses"),
        (["human=true", "rows=3", "cols=20", "out=x"], "needs at least 5 rows"),
        (["layout=missing.json", "out=x"], "missing.json"),
        (["human=true", "rows=2000000", "cols=2000000", "out=x"], "too large for memory"),  # 4 TB of map
        # 10^10 cells: numpy's allocation of it succeeded, and the command ran on for minutes
        (["human=true", "rows=100000", "cols=100000", "out=x"], "too large for memory"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(args, message):
    res = export(args)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], res.stderr


def test_a_shipped_generator_in_five_lines():
    """nca_qd.load_generator: the best elite's layout at S, valid (independent validator), and
    the same generator grown to the whole 101x102 map unrepaired."""
    from nca_qd import load_generator
    from nca_qd.errors import NcaQdError
    from nca_qd.repair import make_rules
    from nca_qd.repair.validator import check

    run = REPO / "results" / "warehouse_even_qd" / "cma_mae_a5_s0"
    g = load_generator(run)
    layout = g.layout()
    assert layout.shape == (33, 36) and check(layout, make_rules("warehouse_even", layout.shape)) is None
    assert g.layout(101, 102, repair=False).shape == (101, 102) and g.n_iters(101, 102) == 200
    assert len(g.rows(layout)) == 33 and set("".join(g.rows(layout))) <= set(g.tiles)
    with pytest.raises(NcaQdError, match="no elite in archive cell"):
        load_generator(run, cell=-1)


def test_the_human_warehouse_of_any_size_is_drawn_by_a_command(tmp_path):
    """human=true draws the human-designed warehouse (the paper's seven sizes cell for cell, where
    the reference maps are here; their shelf counts, the paper's N_s, always); its json file is
    what experiments.simulate reads; and where the paper has no N_s, the error names its count."""
    from nca_qd.layouts import warehouse as wh
    from nca_qd.repair.validator import violations

    for (h, w), n_shelves in wh.SHELVES_BY_SIZE.items():
        lay = wh.human_layout((h, w))
        assert int((lay == wh.SHELF).sum()) == n_shelves
        ref = MAPS / "warehouse" / f"human_{h}x{w}.json"
        if ref.is_file():
            assert ["".join(".@ew"[t] for t in row) for row in lay] == load_map(ref).rows
        assert violations(lay, wh.rules((h, w))) == []  # the layout validator: a valid warehouse
    big = wh.human_layout((140, 500))
    assert int((big == wh.SHELF).sum()) == 15_334
    with pytest.raises(
        NcaQdError, match="give n_shelves=<N>; the human-designed layout of that size holds 15334"
    ):
        wh.default_shelves((140, 500))  # the caller names N_s where the paper has none
    assert violations(big, wh.rules((140, 500), 15_334)) == []
    args = ["human=true", "domain=warehouse_uneven", "rows=41", "cols=60", "format=json", f"out={tmp_path}"]
    res = export(args)
    assert res.returncode == 0, res.stderr
    line = json.loads(res.stdout)
    assert line["domain"] == "warehouse_uneven" and line["size"] == "41x60"
    mapfile = load_map(tmp_path / "human_41x60.json")
    assert (
        line["shelves"]
        == "".join(mapfile.rows).count("@")
        == int((wh.human_layout((41, 60)) == wh.SHELF).sum())
    )
    sim = subprocess.run(
        [sys.executable, "-m", "experiments.simulate", "domain=warehouse_uneven",
         f"layout={tmp_path / 'human_41x60.json'}", "agents=50", "T=50", "seeds=1", "planner=pibt"],
        cwd=REPO, capture_output=True, text=True, timeout=600,
        env={**__import__("os").environ, "JAX_PLATFORMS": "cpu"},
    )  # fmt: skip
    assert sim.returncode == 0 and json.loads(sim.stdout.splitlines()[-1])["runs"] == 1, sim.stderr
