"""benchmarks.maze_paths: shortest paths of grown mazes (against a BFS), the band table, the shipped CSV."""

from __future__ import annotations

import csv
from collections import deque
from pathlib import Path

import numpy as np
import pytest

from benchmarks.maze_paths import CSV_NAME, band_table, main, shortest_paths
from nca_qd.domains import make_domain
from nca_qd.pipeline import generate, make_generator

ROOT = Path(__file__).resolve().parents[1]
ENTROPY_RUN = ROOT / "results" / "maze_qd" / "cma_mae_maze_entropy_s0"


def diameter(free: np.ndarray) -> int:
    """Longest shortest path over all pairs of free tiles (4-connected), by BFS from each tile."""
    h, w = free.shape
    best = 0
    for sr in range(h):
        for sc in range(w):
            if not free[sr, sc]:
                continue
            dist = {(sr, sc): 0}
            q = deque([(sr, sc)])
            while q:
                r, c = q.popleft()
                for nr, nc in ((r + 1, c), (r - 1, c), (r, c + 1), (r, c - 1)):
                    if 0 <= nr < h and 0 <= nc < w and free[nr, nc] and (nr, nc) not in dist:
                        dist[(nr, nc)] = dist[(r, c)] + 1
                        q.append((nr, nc))
            best = max(best, max(dist.values()))
    return best


def test_shortest_paths_match_a_bfs_over_the_grown_mazes():
    cfg = {
        "name": "maze",
        "size": {"train": [16, 16], "eval": [64, 64]},
        "nca_iters": {"train": 50, "eval": 200},
        "measures": {"names": ["entropy", "path_length"], "ranges": [[0, 1], [0, 648]], "cells": [100, 162]},
        "agent": {"kind": "wall_follower", "episodes": 4, "horizon_factor": 2},
    }
    domain = make_domain(cfg)
    nca = make_generator(domain)
    rng = np.random.default_rng(3)
    genotypes = rng.normal(0, 0.5, (3, nca.n_params)).astype(np.float32)
    got = shortest_paths(domain, nca, genotypes)  # one chunk: one compiled batch shape
    regions = generate(domain, nca, genotypes)
    want = [diameter(np.asarray(r) == 0) for r in regions]
    assert got.tolist() == want
    assert max(want) > 0  # the mazes are not all walls


def test_band_table_counts_paths_and_fill():
    # 4 x 162 archive over [0, 1] x [0, 648]: 4 steps per path cell, 0.25 per entropy row
    rows = [
        {"cell": 0 * 162 + 12, "m0": 0.1, "path_length": 50.0, "shortest": 25, "objective": 1.0},
        {"cell": 1 * 162 + 112, "m0": 0.3, "path_length": 450.0, "shortest": 30, "objective": 1.0},
        {"cell": 3 * 162 + 30, "m0": 0.9, "path_length": 120.0, "shortest": 40, "objective": 0.0},
    ]
    lines = band_table(rows, [4, 162], [[0, 1], [0, 648]], [0, 0.5, 1])
    low = lines[2].strip("|").split("|")
    high = lines[3].strip("|").split("|")
    cols = [c.strip() for c in low]
    assert cols[0] == "0-0.5" and cols[1] == "2"
    assert cols[2] == "250"  # median of 50 and 450
    assert cols[5] == "30"  # longest shortest path
    assert cols[6] == f"{np.median([50 / 25, 450 / 30]):.2f}"
    # rows 0-1, path 0-100 = columns 0-24: 1 of 50 cells; path 400-648 = columns 100-161: 1 of 124
    assert cols[7] == f"{1 / 50:.2f}" and cols[10] == f"{1 / 124:.2f}"
    cols = [c.strip() for c in high]
    assert cols[1] == "1" and cols[8] == f"{1 / 50:.2f}"  # path 100-200 = columns 25-49


def test_shipped_csv_agrees_with_the_runs_metrics(capsys):
    path = ENTROPY_RUN / CSV_NAME
    if not path.is_file():
        pytest.skip("no maze_paths.csv shipped")
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    with open(ENTROPY_RUN / "metrics.csv", newline="") as f:
        last = list(csv.DictReader(f))[-1]
    assert len(rows) == int(float(last["n_elites"]))
    assert sum(float(r["objective"]) for r in rows) == pytest.approx(float(last["qd_score"]))
    # the grown maze's shortest path never exceeds the agent's mean episode length, which is at
    # least the shortest path for every solvable maze (a miss counts the 648-step horizon)
    solvable = [r for r in rows if float(r["objective"]) > 0]
    assert all(float(r["path_length"]) >= int(r["shortest"]) for r in solvable)
    assert main([str(ENTROPY_RUN), "--bands", "0,0.45,1"]) == 0
    out = capsys.readouterr().out
    assert f"{len(rows)} elites" in out and "| 0.45-1 |" in out


@pytest.mark.parametrize(
    "args, needle",
    [
        (["results/no_such_run"], "no such run directory"),
        (["results/warehouse_even_qd/cma_mae_a5_s0"], "not a maze run"),
        ([str(ENTROPY_RUN), "--bands", "0.5,0.2"], "increasing"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(args, needle, capsys, monkeypatch):
    monkeypatch.chdir(ROOT)
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0]
