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
from evaluate_helpers import TINY_RUN as TINY_EVALUATE_RUN
from evaluate_helpers import make_run, record_lines, write_human_maps

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


def run_evaluation(root: Path, out: Path | None = None) -> Path:
    """The tiny evaluation under ``root`` (its maps and run made once), written to ``out``
    (default ``root/evaluation``); returns the output directory."""
    maps = write_human_maps(root / "maps")
    run_dir = root / "run" if (root / "run").exists() else make_run(root / "run", TINY_RUN)
    out = out or root / "evaluation"
    with pytest.MonkeyPatch.context() as mp, contextlib.redirect_stdout(io.StringIO()):
        mp.setenv("NCA_QD_MAPS", str(maps))
        assert evaluate_cli.main([f"run_dir={run_dir}", f"out={out}", *SETTINGS]) == 0
    return out


def csv_files(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for pat in ("*.csv", "*.csv.gz") for p in root.rglob(pat))


def read(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    import gzip

    with gzip.open(path, "rt", newline="") if path.suffix == ".gz" else path.open(newline="") as fh:
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


def assert_matches_golden(out: Path, name: str) -> None:
    want_cols, want = read(GOLDEN / name)
    got_cols, got = read(out / name)
    assert got_cols == want_cols, name
    assert len(got) == len(want), name
    compared = [c for c in want_cols if c not in TIMING_COLUMNS]
    for i, (g, w) in enumerate(zip(got, want)):
        diff = {c: (g[c], w[c]) for c in compared if g[c] != w[c]}
        assert not diff, f"{name} row {i + 2}: column: (got, golden) {diff}"


@pytest.mark.parametrize("name", csv_files(GOLDEN) or ["summary.csv"])
def test_every_csv_matches_its_golden_copy(evaluated, name):
    assert_matches_golden(evaluated, name)


def test_an_interrupted_evaluation_goes_on_from_its_recorded_runs(evaluated, tmp_path, monkeypatch):
    """Every exact run is recorded as it ends (exact_runs.jsonl), every screened batch's runs
    likewise (screen_runs.jsonl). An evaluation interrupted after two exact runs keeps those
    two; the same command then runs only the others (a line cut short in the record is
    skipped), screens nothing again and writes the golden CSVs; a third runs none."""
    from nca_qd.evaluation import runs as runs_module

    recorded = [json.dumps(r) for r in record_lines(evaluated, "exact_runs")]
    _, rows = read(evaluated / "runs.csv")
    exact = {(r["layout"], r["size"], r["n_agents"], r["seed"]) for r in rows if r["simulator"] == "rhcr"}
    assert len(recorded) == len(exact) > 2
    screened = [r for r in rows if r["simulator"] == "screen"]
    # the selection's screened runs are recorded too; the chosen generator's are its S_eval
    # screened runs (the same layout, agents, T and seeds: select.T = T, select.runs =
    # runs.eval), recorded once, so the others' runs come on top
    _, selection = read(evaluated / "selection.csv")
    others = sum(int(r["screen_runs"]) for r in selection if r["selected"] != "true")
    assert len(record_lines(evaluated, "screen_runs")) == len(screened) + others
    assert len(screened) > 0 and others > 0
    assert not (evaluated / "exact_runs.jsonl").exists()  # packed when the evaluation ended
    # the main comparison's screened runs keep their tasks per step but not their tile visits
    # (their cells have exact runs, which draw the heatmaps); the exact runs keep both
    screen_recs = record_lines(evaluated, "screen_runs")
    assert any(r["detail"] for r in screen_recs) and all(r["tile_visits"] is None for r in screen_recs)
    assert all(r["tile_visits"] is not None for r in record_lines(evaluated, "exact_runs") if r["detail"])
    real, calls = runs_module.exact_job, []
    real_screen, screen_calls = runs_module.screen_group, []

    def counted_screen(*args, **kwargs):
        screen_calls.append(args)
        return real_screen(*args, **kwargs)

    monkeypatch.setattr(runs_module, "screen_group", counted_screen)

    def interrupted_after_two(*args):
        if len(calls) == 2:
            raise KeyboardInterrupt
        calls.append(args)
        return real(*args)

    def counted(*args):
        calls.append(args)
        return real(*args)

    out = tmp_path / "evaluation"
    monkeypatch.setattr(runs_module, "exact_job", interrupted_after_two)
    with pytest.raises(KeyboardInterrupt):
        run_evaluation(evaluated.parent, out)
    assert (out / "exact_runs.jsonl.gz").is_file() and not (out / "exact_runs.jsonl").exists()
    kept = [json.dumps(r) for r in record_lines(out, "exact_runs")]  # packed when it was cut
    assert [json.loads(line)["key"] for line in kept] == [json.loads(line)["key"] for line in recorded[:2]]
    with (out / "exact_runs.jsonl").open("a") as fh:  # a write cut short
        fh.write(recorded[-1][:40])
    assert screen_calls, "the interrupted evaluation screened its batches"
    monkeypatch.setattr(runs_module, "exact_job", counted)
    for expected_calls in (len(recorded) - 2, 0):
        calls.clear()
        screen_calls.clear()
        run_evaluation(evaluated.parent, out)
        assert len(calls) == expected_calls
        assert not screen_calls
        for name in csv_files(GOLDEN):
            assert_matches_golden(out, name)
