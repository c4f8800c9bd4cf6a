"""Golden outputs of ``experiments.evaluate``: every CSV that one tiny evaluation writes is
compared, column by column, with the copy committed under ``tests/data/evaluation_golden/``.

The evaluation covers each stage of :mod:`nca_qd.evaluation` once: ``select.by=s_eval`` (a
pool of two generators screened at S_eval, selection.csv), NCA layouts at S, S_eval and one
more size (generated, repaired), the tiling and human baselines, exact RHCR runs and screened
runs (main comparison, both agent curves, the more-sizes curve), tasks over time and tile
usage. Repairs run under a window budget (``domain.repair.improve_windows``), so they are
work-limited and give the same layouts whatever the machine's load; exact runs have a time
limit far above their cost, so none times out.

A change of these files is a change of the evaluation's behaviour. When it is intended,
regenerate the golden copies and review their diff:

    NCA_QD_REGEN_GOLDEN=1 .venv/bin/pytest -q tests/test_evaluation_golden.py
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

from experiments import evaluate as evaluate_cli
from experiments.cli import compose_config
from nca_qd.io import atomic_write_text, save_npz

GOLDEN = Path(__file__).resolve().parent / "data" / "evaluation_golden"
REGEN = os.environ.get("NCA_QD_REGEN_GOLDEN") == "1"

# Columns that hold wall-clock seconds: they differ from one run to the next (two runs of the
# same code on the same machine disagree in every one of them), so they are left out. Every
# other column, integers, flags, throughputs, statistics, similarities, is compared exactly
# as text: two runs of the same code write the same text there.
TIMING_COLUMNS = {
    "gen_seconds",  # summary.csv, layouts.csv: NCA generation time
    "repair_seconds",  # summary.csv, layouts.csv: repair time
    "seconds",  # runs.csv: one simulation's time
    "sim_seconds_mean",  # summary.csv and the curves: mean simulation time of a cell
}

# Storage 9x10 (9x14 with the workstation columns) at S, 13x14 (13x18) at S_eval; repairs
# under a budget of improvement windows (work limits, not time: deterministic).
TINY_RUN = [
    "domain=warehouse_even",
    "domain.size.train=[9,10]",
    "domain.size.eval=[13,14]",
    "domain.repair.n_shelves.train=12",
    "domain.repair.n_shelves.eval=24",
    "domain.repair.improve_windows=4",
    "domain.n_agents.train=8",
    "domain.n_agents.eval=12",
]
# A valid 9x14 human-designed warehouse (7 shelves), found through $NCA_QD_MAPS.
HUMAN_9x14 = [
    "..............",
    "w...e@@e.....w",
    "..............",
    "..e@e..e@e....",
    "w............w",
    "....e@@e......",
    "..............",
    "w....e@e.....w",
    "..............",
]
SETTINGS = [
    "T=40",
    "elites=1",
    "select.by=s_eval",
    "select.pool=2",
    "select.runs=2",
    "select.T=40",
    "runs.train=3",
    "runs.eval=2",
    "exact.train=2",
    "exact.eval=1",
    "exact.time_limit_s=600",
    "sweep.train.agents=[8]",
    "sweep.train.runs=2",
    "sweep.eval.agents=[12]",
    "sweep.eval.runs=2",
    "sizes.shapes=[[11,15]]",
    "sizes.n_shelves={11x15: 14}",
    "sizes.agents={9x14: [8], 13x18: [12], 11x15: [8]}",
    "sizes.runs=2",
    "eval.workers=0",
    "progress=false",
    "tasks_smooth=5",
]


def make_run(run_dir: Path, overrides=TINY_RUN, elites=(3, 7)) -> Path:
    """A run directory with config.yaml and a result archive of random generators."""
    from nca_qd.domains import make_domain
    from nca_qd.pipeline import make_generator

    cfg = compose_config("run", list(overrides))
    n_params = make_generator(make_domain(cfg.domain)).n_params
    cells = 12
    rng = np.random.default_rng(0)
    genotypes = np.zeros((cells, n_params), np.float32)
    objective = np.full(cells, -np.inf, np.float32)
    for rank, c in enumerate(elites):
        genotypes[c] = 0.3 * rng.standard_normal(n_params)
        objective[c] = 5.0 - rank
    run_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_text(run_dir / "config.yaml", OmegaConf.to_yaml(cfg))
    save_npz(
        run_dir / "archive_result.npz",
        {
            "genotypes": genotypes,
            "objective": objective,
            "measures": np.zeros((cells, 2), np.float32),
            "centroids": np.zeros((cells, 2), np.float32),
        },
    )
    return run_dir


def run_evaluation(root: Path) -> Path:
    """The tiny evaluation under ``root``; returns its output directory."""
    maps = root / "maps"
    (maps / "warehouse").mkdir(parents=True)
    (maps / "warehouse" / "human_9x14.json").write_text(
        json.dumps({"name": "human_9x14", "layout": HUMAN_9x14, "n_row": 9, "n_col": 14})
    )
    run_dir = make_run(root / "run")
    out = root / "evaluation"
    with pytest.MonkeyPatch.context() as mp, contextlib.redirect_stdout(io.StringIO()):
        mp.setenv("NCA_QD_MAPS", str(maps))
        assert evaluate_cli.main([f"run_dir={run_dir}", f"out={out}", *SETTINGS]) == 0
    return out


def csv_files(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*.csv"))


def read(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with path.open(newline="") as fh:
        reader = csv.DictReader(fh)
        return list(reader.fieldnames or []), list(reader)


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory) -> Path:
    out = run_evaluation(tmp_path_factory.mktemp("golden"))
    if REGEN:
        shutil.rmtree(GOLDEN, ignore_errors=True)
        for name in csv_files(out):
            (GOLDEN / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(out / name, GOLDEN / name)
    return out


def test_the_same_csv_files_are_written(evaluated):
    assert csv_files(evaluated) == csv_files(GOLDEN)
    assert "summary.csv" in csv_files(GOLDEN) and "selection.csv" in csv_files(GOLDEN)


@pytest.mark.parametrize("name", csv_files(GOLDEN) or ["summary.csv"])
def test_every_csv_matches_its_golden_copy(evaluated, name):
    want_cols, want = read(GOLDEN / name)
    got_cols, got = read(evaluated / name)
    assert got_cols == want_cols, name
    assert len(got) == len(want), name
    compared = [c for c in want_cols if c not in TIMING_COLUMNS]
    for i, (g, w) in enumerate(zip(got, want)):
        diff = {c: (g[c], w[c]) for c in compared if g[c] != w[c]}
        assert not diff, f"{name} row {i + 2}: column: (got, golden) {diff}"
