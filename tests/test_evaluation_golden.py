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

import pytest
from test_evaluate import TINY_RUN as TINY_EVALUATE_RUN
from test_evaluate import HUMAN_9x14, make_run

from experiments import evaluate as evaluate_cli

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

# test_evaluate's tiny warehouse run, with repairs under a budget of improvement windows
# (work limits, not time: deterministic).
TINY_RUN = [*TINY_EVALUATE_RUN, "domain.repair.improve_windows=4"]
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


def run_evaluation(root: Path) -> Path:
    """The tiny evaluation under ``root``; returns its output directory."""
    maps = root / "maps"
    (maps / "warehouse").mkdir(parents=True)
    (maps / "warehouse" / "human_9x14.json").write_text(
        json.dumps({"name": "human_9x14", "layout": HUMAN_9x14, "n_row": 9, "n_col": 14})
    )
    run_dir = make_run(root / "run", TINY_RUN)
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
