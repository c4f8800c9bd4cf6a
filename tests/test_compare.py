"""experiments.compare: runs grouped by domain and algorithm, mean ± s.e. of the final
QD-score and coverage, curves drawn, bad input one line."""

import numpy as np
import pytest

from nca_qd.compare import compare, mean_se, read_run, step_values
from nca_qd.errors import NcaQdError


def _fake_run(path, algo, seed, rows, measures=("n_walls", "path_length")):
    path.mkdir(parents=True)
    (path / "config.yaml").write_text(
        f"seed: {seed}\nalgo:\n  name: {algo}\ndomain:\n  name: maze\n  measures:\n"
        f"    names: [{', '.join(measures)}]\n"
    )
    lines = ["iteration,evaluations,qd_score,coverage"]
    lines += [f"{i + 1},{e},{q},{c}" for i, (e, q, c) in enumerate(rows)]
    (path / "metrics.csv").write_text("\n".join(lines) + "\n")


def _warehouse_run(path, seed, alpha, qd=20000):
    """A finished CMA-MAE warehouse (even) run: its config and one line of metrics."""
    path.mkdir(parents=True)
    (path / "config.yaml").write_text(
        f"seed: {seed}\nalpha: {alpha}\nalgo:\n  name: cma_mae\ndomain:\n  name: warehouse_even\n"
        "  alpha: 5\n  measures:\n    names: [entropy, shelf_components]\n"
    )
    (path / "metrics.csv").write_text(f"iteration,evaluations,qd_score,coverage\n1,10000,{qd},0.3\n")


def test_runs_are_grouped_and_summarised_as_mean_and_standard_error(tmp_path):
    _fake_run(tmp_path / "a0", "cma_mae", 0, [(150, 10, 0.1), (300, 30, 0.3)])
    _fake_run(tmp_path / "a1", "cma_mae", 1, [(150, 20, 0.2), (300, 50, 0.5)])
    _fake_run(tmp_path / "b0", "dsage", 0, [(100, 5, 0.05), (864, 40, 0.4)])
    _fake_run(tmp_path / "c0", "dsage", 0, [(100, 1, 0.01)], measures=("entropy", "path_length"))
    table, files = compare([tmp_path], tmp_path / "out")
    assert all(f.is_file() for f in files)
    assert sorted(f.name for f in files) == ["comparison.csv", "comparison.md", "comparison.png"]
    rows = [line for line in table.splitlines() if line.startswith("| maze")]
    # per domain, the best QD-score first
    assert rows[0].startswith("| maze (entropy+path_length) | dsage | 1 (0)")
    assert rows[1].startswith("| maze (n_walls+path_length) | cma_mae | 2 (0,1) | 300 |")
    assert "40.00 ± 10.00" in rows[1] and "0.400 ± 0.100" in rows[1]
    assert rows[2].startswith("| maze (n_walls+path_length) | dsage | 1 (0) | 864 | 40.00 | 0.400 |")
    # the paper's row beside ours (its appendix table), none for a group it did not run, and
    # its budget named where the runs' differs (the maze's rows are at 100,000 evaluations)
    budget = " (at 100,000 evaluations: not this run's budget) | — |"  # and no verdict
    assert rows[1].endswith("| 22,299.00 ± 612.46 / 0.54 ± 0.01" + budget)
    assert rows[0].endswith("| 1,444.20 ± 52.60 / 0.09 ± 0.00" + budget)
    _fake_run(tmp_path / "full", "map_elites", 0, [(50000, 5, 0.1), (100000, 6000, 0.3)])
    table, _ = compare([tmp_path / "full"], tmp_path / "out")
    # one run against the paper's five: within 2 s.e. of the difference (the paper's spread of
    # one run, 2,207.08 × √5, and its s.e.: 6,446.80 / 5,406.2 = 1.2 s.e.)
    row = table.splitlines()[2]
    assert row.endswith("| 6,000.00 | 0.300 | 12,446.80 ± 2,207.08 / 0.30 ± 0.05 | within |")
    _fake_run(tmp_path / "high", "cma_mae", 0, [(100000, 30000, 0.6)])
    table, _ = compare([tmp_path / "high"], tmp_path / "out")
    # 7,701 above the paper's 22,299 ± 612.46: 7,701 / (612.46 × √6) = 5.1 s.e.
    assert table.splitlines()[2].endswith("/ 0.54 ± 0.01 | differs: QD-score +7,701 (+5.1 s.e.) |")


def test_a_search_under_way_is_a_row_of_its_own(tmp_path):
    """A run below its budget (qd.n_evals: a campaign's arm between legs) is not pooled with
    the finished seeds of its arm, whose mean it would pull down; it stands in its own row,
    named with its seed and progress, without the paper's row beside it."""
    for seed, rows in ((0, [(50000, 10000, 0.3), (100000, 22000, 0.5)]), (1, [(50000, 9000, 0.25)])):
        _fake_run(tmp_path / f"s{seed}", "cma_mae", seed, rows)
        cfg = tmp_path / f"s{seed}" / "config.yaml"
        cfg.write_text(cfg.read_text() + "qd:\n  n_evals: 100000\n")
    table, _ = compare([tmp_path], tmp_path / "out")
    rows = {r.split(" | ")[1]: r for r in table.splitlines() if r.startswith("| maze")}
    assert sorted(rows) == ["cma_mae", "cma_mae (in progress: seed 1, 50,000 of 100,000)"]
    assert " 1 (0) | 100,000 | 22,000.00 | 0.500 | 22,299.00" in rows["cma_mae"]
    assert rows["cma_mae (in progress: seed 1, 50,000 of 100,000)"].endswith("| 9,000.00 | 0.250 | — | — |")


def test_a_curve_is_what_the_archive_held_after_each_iteration(tmp_path):
    _fake_run(tmp_path / "r", "dsage", 3, [(100, 5, 0.05), (864, 40, 0.4)])
    curve = read_run(tmp_path / "r")
    v = step_values(curve, "qd_score", np.asarray([50, 100, 500, 864, 900]))
    np.testing.assert_array_equal(v[1:], [5, 5, 40, 40])
    assert np.isnan(v[0])
    assert mean_se([1.0, 3.0]) == (2.0, 1.0)


def test_a_folder_without_runs_is_one_clear_error(tmp_path):
    with pytest.raises(NcaQdError, match="no run directories"):
        compare([tmp_path], tmp_path / "out")
    with pytest.raises(NcaQdError, match="does not exist"):
        compare([tmp_path / "missing"], tmp_path / "out")
    for bad in ("sub/table", "", ".hidden"):
        with pytest.raises(NcaQdError, match="name must be a plain file name stem"):
            compare([tmp_path], tmp_path / "out", name=bad)


def test_an_arm_just_started_is_named_not_fatal_unless_asked_for_itself(tmp_path):
    """A campaign's next arm has a metrics.csv with its header only: the folder's comparison
    leaves it out and says so; asked for by itself, it is one clear error."""
    _fake_run(tmp_path / "done", "cma_mae", 0, [(150, 10, 0.1)])
    _fake_run(tmp_path / "next", "cma_mae", 1, [])
    table, _ = compare([tmp_path], tmp_path / "out")
    assert "| cma_mae | 1 (0) |" in table
    assert f"Not in these tables yet (no iteration finished): `{tmp_path / 'next'}`." in table
    with pytest.raises(NcaQdError, match="has no iterations yet"):
        compare([tmp_path / "next"], tmp_path / "out")
    _fake_run(tmp_path / "later" / "arm", "cma_mae", 2, [])
    with pytest.raises(NcaQdError, match="no run with iterations yet"):
        compare([tmp_path / "later"], tmp_path / "out")


def test_arms_that_differ_in_alpha_are_not_pooled(tmp_path):
    """The paper compares CMA-MAE at α = 0, 1 and 5: one group each, and the paper's α = 5 row
    beside the α = 5 arm only (a run saved with alpha: null takes its domain's α)."""

    _warehouse_run(tmp_path / "a5s0", 0, "null", 20000)
    _warehouse_run(tmp_path / "a5s1", 1, 5, 21000)
    _warehouse_run(tmp_path / "a0s0", 0, 0, 9000)
    table, _ = compare([tmp_path], tmp_path / "out")
    rows = [line for line in table.splitlines() if line.startswith("| warehouse_even")]
    assert len(rows) == 2
    assert rows[0].startswith("| warehouse_even (entropy+shelf_components) | cma_mae α=5 | 2 (0,1) |")
    assert "20,500.00 ± 500.00" in rows[0]
    assert rows[0].endswith("| 20,366.07 ± 653.46 / 0.33 ± 0.01 | within |")
    assert rows[1].startswith("| warehouse_even (entropy+shelf_components) | cma_mae α=0 | 1 (0) |")
    assert "20,366.07" not in rows[1]


def test_maze_runs_measured_by_another_agent_are_not_pooled(tmp_path):
    """A maze run measured by the paper's agent (or other learned weights) is its own arm. The
    paper's row stands beside the shipped agent's arm and the paper's agent's as its search
    played it (the agent behind that row), not beside other weights' arm."""

    def run(path, seed, agent, qd):
        _fake_run(path, "cma_mae", seed, [(10050, qd, 0.1)], measures=("entropy", "path_length"))
        with (path / "config.yaml").open("a") as fh:
            fh.write(agent)

    run(tmp_path / "ours", 0, "  agent:\n    kind: learned\n    weights: null\n", 2356)
    paper = "  agent:\n    kind: paper_accel_search\n    weights: /x/model_20000.tar\n"
    run(tmp_path / "theirs", 0, paper, 3000)
    run(tmp_path / "clean", 0, "  agent:\n    kind: learned\n    weights: runs/clean\n", 2000)
    table, _ = compare([tmp_path], tmp_path / "out")
    rows = [line for line in table.splitlines() if line.startswith("| maze")]
    assert [r.split(" | ")[1] for r in rows] == [
        "cma_mae, agent paper_accel_search (model_20000.tar)",
        "cma_mae",
        "cma_mae, agent learned (clean)",
    ]
    assert all(" 1 (0) " in r for r in rows)
    assert "12,468.20" in rows[0] and "12,468.20" in rows[1] and "12,468.20" not in rows[2]


def test_a_reduced_dsage_is_its_own_arm_and_says_what_it_cut(tmp_path):
    """DSAGE below its public settings (the paper's) on a CPU: its own row, labelled with what
    was cut, the paper's row beside it marked as DSAGE's full settings; at those settings (or
    more) it is plain ``dsage`` beside the paper's row."""

    def run(path, seed, algo_extra):
        _fake_run(path, "dsage", seed, [(100000, 1000, 0.05)], measures=("entropy", "path_length"))
        text = (path / "config.yaml").read_text().replace("  name: dsage\n", "  name: dsage\n" + algo_extra)
        (path / "config.yaml").write_text(text)

    cut = "  inner:\n    iterations: 500\n  surrogate:\n    epochs: 20\n    features: 32\n"
    run(tmp_path / "r0", 0, cut)
    run(tmp_path / "r1", 1, cut)
    run(tmp_path / "full", 0, "  inner:\n    iterations: 10000\n  surrogate:\n    epochs: 200\n")
    table, _ = compare([tmp_path], tmp_path / "out")
    rows = {r.split(" | ")[1]: r for r in table.splitlines() if r.startswith("| maze")}
    label = (
        "dsage (reduced: inner.iterations 500 of 10,000, surrogate.epochs 20 of 200, "
        "surrogate.features 32 of 64)"
    )
    assert sorted(rows) == ["dsage", label]
    assert " 2 (0,1) " in rows[label] and " 1 (0) " in rows["dsage"]
    assert rows[label].endswith("| 1,444.20 ± 52.60 / 0.09 ± 0.00 (DSAGE's full settings) | — |")
    # 1,000 against 1,444.20 ± 52.60: -444.2 / (52.60 × √6) = -3.4 s.e.
    assert rows["dsage"].endswith("| 1,444.20 ± 52.60 / 0.09 ± 0.00 | differs: QD-score -444 (-3.4 s.e.) |")


def test_a_warehouse_dsage_is_never_the_papers_row(tmp_path):
    """The paper's warehouse and manufacturing DSAGE (config/warehouse/*/DSAGE_a=5.gin) is not
    the maze's: a DSAGE run here in those domains says what it lacks and which settings differ,
    and gets no paper row (the paper's 914.60 would be set beside another algorithm)."""
    path = tmp_path / "w"
    path.mkdir()
    (path / "config.yaml").write_text(
        "seed: 0\nalgo:\n  name: dsage\n  inner:\n    iterations: 10000\n    batch_size: 30\n"
        "    initial_population: 20\n  surrogate:\n    epochs: 20\n"
        "domain:\n  name: warehouse_even\n  alpha: 5\n  measures:\n    names: [entropy, shelf_components]\n"
    )
    (path / "metrics.csv").write_text("iteration,evaluations,qd_score,coverage\n1,10000,900,0.02\n")
    table, _ = compare([path], tmp_path / "out")
    (row,) = [r for r in table.splitlines() if r.startswith("| warehouse_even")]
    label = row.split(" | ")[1]
    assert label.startswith("dsage α=5 (not the paper's: lacks the mutation that keeps N_s shelves")
    assert label.endswith("the surrogate of the repaired layout; inner.batch_size 30 for 10)")
    assert "914.60" not in row and row.endswith("| — | — |")


SUMMARY_HEAD = (
    "domain,size,which,n_agents,layout,kind,cell,gen_seconds,repair_status,repair_seconds,similarity,hamming,"
    "simulator,runs,completed,timed_out,errors,success_rate,throughput_success_mean,throughput_success_se,"
    "throughput_mean,throughput_se,ci95_low,ci95_high,sim_seconds_mean\n"
)


def _summary_row(which, kind, sim, success, thr, thr_se="0.001", runs=50, sim_runs=None):
    size, n = ("33x36", 200) if which == "train" else ("101x102", 1400)
    gen = "0.002,optimal,1.0,0.95,120" if kind != "human" else ",given,,,"
    return (
        f"warehouse_even,{size},{which},{n},{kind},{kind},7,{gen},{sim},{sim_runs or runs},{runs},0,0,"
        f"{success},{thr},{thr_se},{thr},{thr_se},0,0,1.0\n"
    )


def test_arms_with_an_evaluation_get_the_papers_tables_2_and_3(tmp_path):
    """Each arm's best generator at S and S_eval (exact runs only) as mean ± s.e. over its
    seeds beside the paper's row; its tiling baseline; the human layouts once per domain."""

    def run(path, seed, alpha, success_eval, thr_eval, evaluated=True):
        _warehouse_run(path, seed, alpha)
        if not evaluated:
            return
        (path / "evaluation").mkdir()
        (path / "evaluation" / "summary.csv").write_text(
            SUMMARY_HEAD
            + _summary_row("train", "nca", "rhcr", 1.0, 6.70)
            + _summary_row("train", "nca", "screen", 0.0, 0.5)  # never set beside the paper's
            + _summary_row("eval", "nca", "rhcr", success_eval, thr_eval, runs=20)
            + _summary_row("eval", "tiling", "rhcr", 0.0, "", runs=20)
            + _summary_row("train", "human", "rhcr", 0.0, "")
        )

    run(tmp_path / "s0", 0, 5, 0.9, 16.0)
    run(tmp_path / "s1", 1, 5, 0.7, 15.0)
    run(tmp_path / "a0", 0, 0, 0.0, "")
    run(tmp_path / "s2", 2, 5, 0.0, "", evaluated=False)  # no evaluation: QD table only
    table, files = compare([tmp_path], tmp_path / "out", name="warehouse_even_comparison")
    names = {f.name for f in files}
    assert names == {f"warehouse_even_comparison{s}" for s in (".md", ".csv", ".png", "_evaluation.csv")}
    assert all(f.is_file() for f in files) and not (tmp_path / "out" / "comparison.md").exists()
    scaling, runtime_part = table.split("## Generation and repair")
    rows = {
        line.split(" | ")[1]: line for line in scaling.splitlines() if line.startswith("| warehouse_even | ")
    }
    a5 = rows["cma_mae α=5"]
    # S: 100 % in both seeds; S_eval: (90 + 70) / 2 = 80 ± 10 %, throughput (16 + 15) / 2 = 15.5 ± 0.5
    assert "| 0,1 | 100 ± 0 % (2 seeds × ≥ 50 runs), 6.70 ± 0.00 |" in a5
    assert "| 80 ± 10 % (2 seeds × ≥ 20 runs), 15.50 ± 0.50 |" in a5
    # within 15 points of the paper's success, but 15.50 is 3.2 % under its 16.01
    assert a5.endswith("| 100 %, 6.74 ± 0.00 / 90 %, 16.01 ± 0.00 | differs: S_eval throughput -3.2 % |")
    # the paper's tiling baseline (its appendix E): 0 % at S_eval, no run at S
    assert rows["tiling of cma_mae α=5"].endswith(
        "| — | 0 ± 0 % (2 seeds × ≥ 20 runs), N/A | N/A / 0 %, N/A | within |"
    )
    assert rows["cma_mae α=0"].endswith("| 100 %, 6.79 ± 0.00 / 0 %, N/A | within |")
    assert sum(line.startswith("| warehouse_even | human |") for line in scaling.splitlines()) == 1
    runtime = [line for line in runtime_part.splitlines() if "Hamming 120" in line]
    assert len(runtime) == 2 and "Δ 0.95" in runtime[0]


def test_a_runs_other_evaluation_gets_its_own_s_eval_table(tmp_path):
    """``<run>/evaluation_<tag>`` (e.g. S_eval at the paper's code's 2,500 shelves): its S_eval
    rows in a table of their own, headed by the settings that differ from the main evaluation's,
    beside the main evaluation's figure and the paper's; its rows in the CSV, named."""
    import csv

    def run(path, seed, main_eval, ns2500_eval=None):
        _warehouse_run(path, seed, 5)
        for folder, success, shelves, runs in (
            ("evaluation", main_eval, "null", 50),
            ("evaluation_ns2500", ns2500_eval, 2500, 20),
        ):
            if success is None:  # this seed has no other evaluation
                continue
            (path / folder).mkdir()
            (path / folder / "summary.csv").write_text(
                SUMMARY_HEAD
                + _summary_row("train", "nca", "rhcr", 1.0, 6.70)
                + _summary_row("eval", "nca", "rhcr", success, 16.0, runs=runs)
                + _summary_row("eval", "tiling", "rhcr", success / 2, 15.0, runs=runs)
            )
            (path / folder / "evaluate_config.yaml").write_text(
                f"T: 5000\nruns:\n  eval: {runs}\nexact:\n  eval: {runs}\n  planner: rhcr\n"
                f"n_shelves:\n  train: null\n  eval: {shelves}\n"
            )

    run(tmp_path / "s0", 0, 0.9, 0.7)
    run(tmp_path / "s1", 1, 0.9, 0.8)
    run(tmp_path / "s2", 2, 0.3)  # main evaluation only: not in the other table's main column
    table, files = compare([tmp_path], tmp_path / "out")
    part = table.split("## S_eval in the runs' other evaluations")[1]
    # only the setting that moves the figure is named (not the run counts, which stand in the cells)
    assert "### `evaluation_ns2500`: `n_shelves.eval=2500` (main evaluation: `None`)\n" in part
    rows = {r.split(" | ")[1]: r for r in part.splitlines() if r.startswith("| warehouse_even")}
    assert rows["cma_mae α=5"] == (
        "| warehouse_even | cma_mae α=5 | 0,1 | 75 ± 5 % (2 seeds × ≥ 20 runs), 16.00 ± 0.00 "
        "| 90 ± 0 % (2 seeds × ≥ 50 runs), 16.00 ± 0.00 | 90 %, 16.01 ± 0.00 |"
    )
    assert rows["tiling of cma_mae α=5"].endswith(
        "| 45 ± 0 % (2 seeds × ≥ 50 runs), 15.00 ± 0.00 | 0 %, N/A |"
    )
    # the table 2 above is still the main evaluation's, over all three seeds
    assert "| 70 ± 20 % (3 seeds × ≥ 50 runs), 16.00 ± 0.00 |" in table.split("## Generation and repair")[0]
    with (tmp_path / "out" / "comparison_evaluation.csv").open() as fh:
        by = {(r["layout"], r["evaluation"]): r for r in csv.DictReader(fh)}
    assert float(by[("cma_mae α=5", "evaluation_ns2500")]["success_eval"]) == 0.75
    assert float(by[("cma_mae α=5", "evaluation")]["success_eval"]) == pytest.approx(0.7)


def test_the_tiling_baselines_repair_draws_get_a_row_of_their_own(tmp_path):
    """baselines.tiling_draws = k: the first draw stays the table's tiling row (the paper's
    protocol, one repair); a row below gives success and throughput over the draws and each
    draw's success, the spread the repair's choice among equally near layouts makes."""
    _warehouse_run(tmp_path / "s0", 0, 5)
    (tmp_path / "s0" / "evaluation").mkdir()
    (tmp_path / "s0" / "evaluation" / "summary.csv").write_text(
        SUMMARY_HEAD
        + _summary_row("eval", "nca", "rhcr", 0.9, 16.0, runs=20)
        + _summary_row("eval", "tiling", "rhcr", 0.0, "", runs=20)
        + _summary_row("eval", "tiling", "screen", 1.0, 12.0, runs=20)  # not an exact figure
        + _summary_row("eval", "tiling", "rhcr", 0.6, 16.0, runs=20)
        + _summary_row("eval", "tiling", "rhcr", 0.3, 15.0, runs=20)
    )
    table, _ = compare([tmp_path], tmp_path / "out", name="c")
    rows = {r.split(" | ")[1]: r for r in table.splitlines() if r.startswith("| warehouse_even | ")}
    assert "| 0 % (20 runs), N/A |" in rows["tiling of cma_mae α=5"]
    # (0 + 60 + 30) / 3 = 30 ± 17 %; throughput of the draws that flowed: 15.5 ± 0.5
    assert (
        "| 30 ± 17 % (3 repair draws × ≥ 20 runs), 15.50 ± 0.50; per draw 0, 30, 60 % |"
        in rows["tiling of cma_mae α=5, 3 repair draws"]
    )


CURVE_HEAD = (
    "layout,kind,cell,size,which,n_agents,simulator,runs,completed,timed_out,errors,success_rate,"
    "throughput_mean,throughput_se,ci95_low,ci95_high,throughput_success_mean,throughput_success_se,"
    "sim_seconds_mean\n"
)


def _curve_row(kind, n, sim, success, thr, runs=10, which="eval"):
    size = "101x102" if which == "eval" else "33x36"
    figures = f"{success},{thr},0.1,{thr - 0.2},{thr + 0.2},,,1"
    return f"{kind},{kind},7,{size},{which},{n},{sim},{runs},{runs},0,0,{figures}\n"


def test_the_curves_over_agents_carry_their_exact_points_and_the_main_counts(tmp_path):
    """Figure 3: each arm's screened curves drawn, and a table of every exact point beside the
    screened figure at the same count — the curve's exact points and the main comparison's exact
    runs at N_a_eval (summary.csv); the human layout once; arms without curves add nothing."""

    def run(path, seed, alpha, curve=True):
        _warehouse_run(path, seed, alpha)
        (path / "evaluation").mkdir()
        (path / "evaluation" / "summary.csv").write_text(
            SUMMARY_HEAD
            + _summary_row("eval", "nca", "rhcr", 0.9, 16.0, runs=50)
            + _summary_row("eval", "human", "rhcr", 0.0, "", runs=50)
        )
        if curve:
            (path / "evaluation" / "throughput_vs_agents_eval.csv").write_text(
                CURVE_HEAD
                + "".join(_curve_row("nca", n, "screen", 1.0, 0.01 * n, runs=20) for n in (1000, 1400, 1600))
                + _curve_row("nca", 1000, "rhcr", 1.0, 11.5)
                + _curve_row("nca", 1600, "rhcr", 0.1, 3.0 + seed)
                + "".join(_curve_row("human", n, "screen", 0.0, 0.2, runs=20) for n in (1000, 1400, 1600))
                + _curve_row("human", 1000, "rhcr", 0.0, 0.36)
            )

    run(tmp_path / "a5_s0", 0, 5)
    run(tmp_path / "a0_s0", 0, 0)
    run(tmp_path / "me", 0, 1, curve=False)
    table, files = compare([tmp_path], tmp_path / "out", name="cmp")
    assert (tmp_path / "out" / "cmp_agents.png") in files and files[-1].is_file()
    part = table.split("## Throughput against agents")[1]
    rows = [line for line in part.splitlines() if line.startswith("| S_eval")]
    nca = [r for r in rows if "nca, cma_mae α=5 s0" in r]
    assert [r.split(" | ")[2] for r in nca] == ["1000", "1400", "1600"]  # 1400: the main count
    assert nca[1].endswith("| 50, 90 %, 16.00 ± 0.00 | 20, 100 %, 14.00 ± 0.10 |")
    assert nca[2].endswith("| 10, 10 %, 3.00 ± 0.10 | 20, 100 %, 16.00 ± 0.10 |")
    assert sum("nca, cma_mae α=0 s0" in r for r in rows) == 3 and not any("α=1" in r for r in rows)
    assert sum("| human |" in r for r in rows) == 2  # one arm's: the same layout in every arm


def test_an_output_folder_that_cannot_be_made_is_one_line_exit_2(tmp_path, monkeypatch, capsys):
    """``out=`` under a file (or a missing, unwritable place): the path and the reason on one
    line, exit 2, no traceback; the runs read are untouched."""
    import sys

    from experiments import compare as compare_cli
    from experiments.cli import main_guard

    _fake_run(tmp_path / "r", "cma_mae", 0, [(150, 10, 0.1)])
    (tmp_path / "file").write_text("a file, not a folder")
    before = (tmp_path / "r" / "metrics.csv").read_bytes()
    monkeypatch.setattr(sys, "argv", ["prog", f"runs={tmp_path / 'r'}", f"out={tmp_path / 'file' / 'cmp'}"])
    with pytest.raises(SystemExit) as exc:
        main_guard(compare_cli.main)()
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2
    assert err == [f"error: {tmp_path / 'file' / 'cmp'}: Not a directory"]
    assert (tmp_path / "r" / "metrics.csv").read_bytes() == before


def test_elites_at_low_entropy_are_counted_per_arm_from_each_runs_archive(tmp_path):
    """The paper's appendix on α (a larger α, more elites at low environment entropy): per arm,
    the final result archive's elites below fixed entropy values, mean ± s.e. over seeds, read
    from archive_result.npz; a domain without an entropy measure and a run without an archive
    get no row."""
    from nca_qd.qd.archive_io import save_archive

    def archive(path, entropies):
        n = len(entropies)
        save_archive(
            path / "archive_result.npz",
            {
                "cells": np.arange(n, dtype=np.int64),
                "objective": np.full(n, 6.5, np.float32),
                "measures": np.stack([entropies, np.full(n, 200.0)], axis=1).astype(np.float32),
                "genotypes": np.zeros((n, 3), np.float32),
            },
            [100, 100],
            [[0, 1], [140, 240]],
        )

    for seed, ent in ((0, [0.3, 0.45, 0.55, 0.65, 0.8]), (1, [0.4, 0.62, 0.9])):
        _warehouse_run(tmp_path / f"a5_s{seed}", seed, 5)
        archive(tmp_path / f"a5_s{seed}", ent)
    _warehouse_run(tmp_path / "a0_s0", 0, 0)
    archive(tmp_path / "a0_s0", [0.58, 0.75, 0.85, 0.95])
    _warehouse_run(tmp_path / "a1_s0", 0, 1)  # no archive kept: no row, no error
    _fake_run(tmp_path / "maze", "cma_mae", 0, [(100, 1, 0.1)])  # no entropy measure
    table, _ = compare([tmp_path], tmp_path / "out")
    section = table.split("## Elites at low environment entropy")[1].split("\n## ")[0]
    rows = [line for line in section.splitlines() if line.startswith("| warehouse_even")]
    assert len(rows) == 2, rows
    a0 = next(r for r in rows if "α=0" in r)
    a5 = next(r for r in rows if "α=5" in r)
    # α = 0, one seed: 4 elites, lowest 0.58; below 0.5 / 0.6 / 0.7: 0, 1, 1
    assert "| 0 | 4 | 0.580 | 0 (0.0 %) | 1 (25.0 %) | 1 (25.0 %) |" in a0
    # α = 5, seeds 0 and 1: 5 and 3 elites (4 ± 1), lowest 0.3; below 0.5: 2 and 1 (1.5 ± 0.5,
    # 3 of 8); below 0.6: 3 and 1 (2 ± 1, 4 of 8); below 0.7: 4 and 2 (3 ± 1, 6 of 8)
    assert "| 0,1 | 4.0 ± 1.0 | 0.300 | 1.5 ± 0.5 (37.5 %) | 2.0 ± 1.0 (50.0 %) | 3.0 ± 1.0 (75.0 %) |" in a5
    assert "maze" not in section


def test_a_row_is_set_against_the_papers_by_issue_55s_bounds():
    """More than 15 points of success or 2 % of throughput from the paper's differs, at either
    size; the paper's 0 % (no throughput) is compared by success only; no paper row: no verdict."""
    from nca_qd.compare_evaluation import against_paper
    from nca_qd.paper import Scaling

    paper = Scaling(100, (6.74, 0.0), 90, (16.01, 0.0))
    row = {"success_s": 1.0, "throughput_s": 6.75, "success_eval": 0.96, "throughput_eval": 16.09}
    assert against_paper(row, paper) == "within"
    assert against_paper({**row, "success_eval": 0.74}, paper) == "differs: S_eval success -16 points"
    assert against_paper({**row, "throughput_s": 6.60}, paper) == "differs: S throughput -2.1 %"
    jams = Scaling(100, (6.79, 0.0), 0, None)
    assert against_paper({**row, "success_eval": 0.49, "throughput_eval": 16.37}, jams) == (
        "differs: S_eval success +49 points"
    )
    assert against_paper({**row, "success_eval": 0.10}, jams) == "within"
    assert against_paper(row, None) == "—"
    assert against_paper({"success_s": float("nan"), "success_eval": float("nan")}, paper) == "—"


def test_a_runs_last_row_is_checked_against_its_elites_record(tmp_path):
    """A run that ships elites.npz (the maze table's): the QD-score and coverage recounted from
    the record's archive must be its metrics' last row; a row that is not is one clear error."""
    from nca_qd.qd.archive_io import save_elites_record

    objective = np.asarray([1.0, 0.0, 1.0, 1.0], np.float32)
    elites = {
        "cells": np.asarray([3, 7, 40, 41]),
        "objective": objective,
        "measures": np.zeros((4, 2), np.float32),
        "thresholds": objective,
        "genotypes": np.ones((4, 5), np.float32),
    }
    for name, qd in (("agrees", 3), ("differs", 4)):
        _fake_run(tmp_path / name, "cma_mae", 0, [(150, 1, 0.01), (300, qd, 4 / 100)])
        with (tmp_path / name / "config.yaml").open("a") as fh:
            fh.write("  objective_range: [0.0, 1.0]\n")
        save_elites_record(tmp_path / name / "elites.npz", elites, [3], [10, 10], [[0, 1], [0, 1]])
    assert read_run(tmp_path / "agrees").values["qd_score"][-1] == 3
    with pytest.raises(NcaQdError, match=r"row \(QD-score 4.00, coverage 0.040000\) is not its elites"):
        read_run(tmp_path / "differs")


def test_arms_of_different_budgets_are_also_ranked_at_the_smallest(tmp_path):
    # CMA-MAE ran 300 evaluations and leads at the end; the reduced arm stopped at 200, where
    # CMA-MAE's archive (after its last iteration with at most 200: 150) held less than it.
    _fake_run(tmp_path / "a0", "cma_mae", 0, [(150, 10, 0.1), (300, 90, 0.9)])
    _fake_run(tmp_path / "a1", "cma_mae", 1, [(150, 20, 0.2), (300, 110, 0.7)])
    _fake_run(tmp_path / "d0", "dsage", 0, [(100, 12, 0.12), (200, 40, 0.4)])
    _fake_run(tmp_path / "e0", "dsage", 0, [(100, 1, 0.01)], measures=("entropy", "path_length"))
    table, _ = compare([tmp_path], tmp_path / "out")
    final, _, equal = table.partition("## At equal budget")
    walls = "| maze (n_walls+path_length) |"
    assert final.index(walls + " cma_mae |") < final.index(walls + " dsage |")
    assert equal.count("### ") == 1  # the entropy domain has one arm: no section
    assert "### maze (n_walls+path_length) at 200 evaluations" in equal
    rows = [line for line in equal.splitlines() if line.startswith("| ") and "---" not in line][1:]
    assert rows == [
        "| dsage | 1 | 200 | 40.00 | 0.400 |",
        "| cma_mae | 2 | 300 | 15.00 ± 5.00 | 0.150 ± 0.050 |",
    ]
    # one budget everywhere: no such section
    table, _ = compare([tmp_path / "a0", tmp_path / "a1"], tmp_path / "out2")
    assert "At equal budget" not in table
