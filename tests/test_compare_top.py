"""experiments.compare's tables of the archives' best generators at S_eval: each figure counted
from the check folders' own files (selection.csv, runs.csv, summary.csv), the folders found by
their evaluate_config.yaml, and only those of the compared runs that have finished."""

import json

import numpy as np

from nca_qd.compare import compare
from nca_qd.evaluation.store import RepairStore
from nca_qd.scoring.jobs import RepairOutcome

SEL_HEAD = (
    "cell,objective_s,repair_status,similarity,hamming,screen_runs,screen_success_rate,note,selected,file"
)
RUNS_HEAD = "layout,kind,cell,size,which,n_agents,simulator,seed,throughput,success"


def _run(path, seed, alpha):
    path.mkdir(parents=True)
    (path / "config.yaml").write_text(
        f"seed: {seed}\nalpha: {alpha}\nalgo:\n  name: cma_mae\ndomain:\n  name: warehouse_even\n"
        "  alpha: 5\n  measures:\n    names: [entropy, shelf_components]\n"
    )
    (path / "metrics.csv").write_text("iteration,evaluations,qd_score,coverage\n1,10000,20000,0.3\n")


def _check(folder, run_dir, *, by="s", pool=10, exact_top=0, elites=1, exact_eval=0, files=None):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "evaluate_config.yaml").write_text(
        f"run_dir: {run_dir}\nelites: {elites}\nselect:\n  by: {by}\n  pool: {pool}\n"
        f"  exact_top: {exact_top}\nexact:\n  eval: {exact_eval}\n"
    )
    for name, text in (files or {}).items():
        (folder / name).write_text(text)


def _runs_csv(results):
    """runs.csv of exact S_eval runs: {cell: [success, ...]} (and a screened S run per cell)."""
    lines = [RUNS_HEAD]
    for cell, flows in results.items():
        lines.append(f"NCA (cell {cell}),nca,{cell},33x36,train,200,screen,0,5.0,true")
        lines += [
            f"NCA (cell {cell}),nca,{cell},101x102,eval,1400,rhcr,{s},{16.0 if ok else 2.0},{str(ok).lower()}"
            for s, ok in enumerate(flows)
        ]
    return "\n".join(lines) + "\n"


def _section(table, title):
    part = table.split(f"### {title}")[1].split("\n### ")[0].split("\n## ")[0]
    rows = [r.split(" | ") for r in part.splitlines() if r.startswith("| cma_mae")]
    return {r[0].lstrip("| "): r for r in rows}


def test_the_archives_best_are_counted_from_each_check_folders_files(tmp_path):
    root = tmp_path / "qd"
    _run(root / "a0", 0, 0)
    _run(root / "a5", 0, 5)
    checks = root / "top"
    # a screen of 3 candidates, 4 runs each: one flows in all, one in none, one in 2
    sel = [
        f"{SEL_HEAD}",
        "11,6.8,optimal,0.80,1900,4,1.0,,false,selection/a.json",
        "12,6.7,optimal,0.90,900,4,0.0,,false,selection/b.json",
        "13,6.6,optimal,0.70,2500,4,0.5,,true,selection/c.json",
    ]
    _check(checks / "a0", root / "a0", by="s_eval", pool=3, files={"selection.csv": "\n".join(sel) + "\n"})
    # the exact check of the two best: cell 11 flows in both runs, 12 in one of two
    _check(
        checks / "a0" / "exact",
        root / "a0",
        elites=2,
        exact_eval=2,
        files={"runs.csv": _runs_csv({11: [True, True], 12: [False, True]})},
    )
    # the two-stage pick: cell 13 picked, 3 exact runs, all flowing
    summary = (
        "which,kind,cell,simulator,throughput_mean,throughput_se\n"
        "train,nca,13,screen,5.0,\neval,nca,13,rhcr,16.40,0.02\n"
    )
    _check(
        checks / "a0" / "pick",
        root / "a0",
        by="s_eval",
        pool=3,
        exact_top=3,
        files={
            "selection.csv": "\n".join([sel[0], *sel[:0:-1]]) + "\n",  # not in S order: the S-best found
            "runs.csv": _runs_csv({13: [True, True, True]}),
            "summary.csv": summary,
        },
    )
    # not counted: a main evaluation (elites 1), a check still under way (no selection.csv yet),
    # and a check of a run that is not compared
    _check(root / "a5" / "evaluation", root / "a5", files={"runs.csv": _runs_csv({1: [False]})})
    _check(checks / "a5", root / "a5", by="s_eval", pool=20)
    elsewhere = tmp_path / "elsewhere" / "a9"
    _check(checks / "other", elsewhere, elites=10, exact_eval=2, files={"runs.csv": RUNS_HEAD})
    (checks / "broken").mkdir()
    (checks / "broken" / "evaluate_config.yaml").write_text("run_dir: [unclosed\n")  # warned, skipped

    table, _ = compare([root], tmp_path / "out")

    screened = _section(table, "Screened")
    assert list(screened) == ["cma_mae α=0, seed 0"]
    row = screened["cma_mae α=0, seed 0"]
    assert row[1:5] == ["3 × 4 runs", "1", "1", "6 (50 %) of 12"]
    assert row[5] == "0.800 (0.700–0.900)" and row[6] == "1,900 (900–2,500)"
    exact = _section(table, "Exact RHCR")
    assert list(exact) == ["cma_mae α=0, seed 0"]
    # 3 of 4 exact runs; generators in both / one / none: 1 / 1 / 0; their screened runs: 4 of 8
    assert exact["cma_mae α=0, seed 0"][1:5] == ["2", "3 (75 %) of 4", "1 / 1 / 0", "4 (50 %) of 8"]
    pick = _section(table, "The two-stage pick")
    assert pick["cma_mae α=0, seed 0"][1:6] == ["3", "11", "13", "3 of 3", "16.40 ± 0.02"]
    assert "cma_mae α=5" not in table.split("## The archives' best")[1]


def test_without_checks_there_is_no_such_section(tmp_path):
    _run(tmp_path / "qd" / "a0", 0, 0)
    table, _ = compare([tmp_path / "qd"], tmp_path / "out")
    assert "The archives' best" not in table


def test_an_older_selection_takes_delta_and_hamming_from_the_repair_records_by_layout(tmp_path):
    """selection.csv written before it carried Δ and Hamming: the figures of the repair whose
    layout is the candidate's repaired layout (a map file of characters; the record holds tile
    indices), and none where no record matches."""
    root = tmp_path / "qd"
    _run(root / "a0", 0, 0)
    folder = root / "top"
    rng = np.random.default_rng(0)
    layouts = [rng.integers(0, 4, size=(5, 6)) for _ in range(3)]
    store = RepairStore(folder)
    for k, (layout, sim, ham) in enumerate(zip(layouts[:2], (0.91, 0.83), (12, 30))):
        store.add(f"key{k}", RepairOutcome(layout, "optimal", sim, ham, 1.0))
    (folder / "selection").mkdir()
    tiles = ".@ew"
    lines = ["cell,objective_s,repair_status,screen_runs,screen_success_rate,note,selected,file"]
    for cell, layout in zip((7, 8, 9), layouts[::-1]):  # 9 <- layout 0, 8 <- layout 1, 7 <- none
        rows = ["".join(tiles[v] for v in row) for row in layout]
        (folder / "selection" / f"c{cell}.json").write_text(json.dumps({"layout": rows}))
        lines.append(f"{cell},6.0,optimal,2,0.5,,false,selection/c{cell}.json")
    _check(folder, root / "a0", by="s_eval", pool=3, files={"selection.csv": "\n".join(lines) + "\n"})

    table, _ = compare([root], tmp_path / "out")

    row = _section(table, "Screened")["cma_mae α=0, seed 0"]
    # the median and range over the two candidates whose repair is recorded
    assert row[5] == "0.870 (0.830–0.910)" and row[6] == "21 (12–30)"
