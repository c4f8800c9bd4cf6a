"""experiments.evaluate on a tiny synthetic warehouse run: every table and figure, simulator
labels, statistics, the tiling baseline. Bad input: test_evaluate_cli; records and reuse:
test_evaluate_records."""

from __future__ import annotations

import contextlib
import io
import math
from pathlib import Path

import numpy as np
import pytest
from evaluate_helpers import FAST, SCREEN_ONLY, TINY_RUN, HUMAN_9x14, make_run, read, record_lines

from experiments import evaluate as evaluate_cli
from nca_qd import evaluation as ev
from nca_qd.errors import NcaQdError
from nca_qd.io import load_map
from nca_qd.scoring.jobs import ExactSettings, RunOutcome, exact_job


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory, maps):
    """One tiny evaluation: returns (output dir, printed stdout)."""
    run_dir = make_run(tmp_path_factory.mktemp("run") / "run")
    out = run_dir.parent / "evaluation"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = evaluate_cli.main([f"run_dir={run_dir}", f"out={out}", *FAST])
    assert code == 0
    return out, buf.getvalue()


def test_every_output_is_written(evaluated):
    out, printed = evaluated
    for stem in (
        "summary",
        "throughput_vs_agents_train",
        "tasks_over_time_train",
        "tasks_over_time_eval",
        "tile_usage_train",
        "tile_usage_eval",
        "scaling_sizes",
    ):
        if stem != "summary":
            assert (out / f"{stem}.png").stat().st_size > 1000, stem
        gz = stem.startswith(("tasks_over_time", "tile_usage"))  # per step / per tile: compressed
        assert read(out / f"{stem}.csv{'.gz' if gz else ''}"), stem
    for name in (
        "summary.md",
        "runs.csv",
        "layouts.csv",
        "scaling_sizes_grid.csv",
        "evaluate_config.yaml",
        "layouts_9x14.png",
        "layouts_13x18.png",
    ):
        assert (out / name).is_file(), name
    assert not (out / "throughput_vs_agents_eval.csv").exists()  # sweep.eval.agents=[]
    # the printed table is summary.md, one row per (layout, size, simulator)
    md = (out / "summary.md").read_text()
    assert md.strip() in printed
    assert len([l for l in md.splitlines() if l.startswith("| ") and "N_a" not in l]) == len(
        read(out / "summary.csv")
    )


def test_summary_has_every_layout_and_simulator_with_sane_statistics(evaluated):
    out, _ = evaluated
    rows = read(out / "summary.csv")
    got = {(r["size"], r["kind"], r["simulator"], r["runs"]) for r in rows}
    # S: the best generator (elites=1 -> cell 3) and the human map; S_eval: NCA and tiling
    # (no human 13x18 map exists): RHCR for exact.* runs, the screen for runs.*
    assert got == {
        ("9x14", "nca", "rhcr", "2"),
        ("9x14", "nca", "screen", "3"),
        ("9x14", "human", "rhcr", "2"),
        ("9x14", "human", "screen", "3"),
        ("13x18", "nca", "rhcr", "1"),
        ("13x18", "nca", "screen", "2"),
        ("13x18", "tiling", "rhcr", "1"),
        ("13x18", "tiling", "screen", "2"),
    }
    for r in rows:
        assert r["n_agents"] == ("8" if r["which"] == "train" else "12")
        assert 0.0 <= float(r["success_rate"]) <= 1.0
        assert int(r["completed"]) + int(r["timed_out"]) + int(r["errors"]) >= int(r["runs"])
        if r["throughput_se"]:
            assert float(r["throughput_se"]) >= 0
            assert float(r["ci95_low"]) <= float(r["throughput_mean"]) <= float(r["ci95_high"])
        else:  # one run: no standard error
            assert r["runs"] == "1"
        if r["kind"] == "human":
            assert r["repair_status"] == "given" and r["similarity"] == ""
        else:
            assert r["repair_status"] in ("optimal", "feasible")
            assert 0.0 <= float(r["similarity"]) <= 1.0 and float(r["repair_seconds"]) >= 0
        if r["kind"] == "nca":
            assert r["cell"] == "3" and float(r["gen_seconds"]) > 0


def test_statistics_match_the_raw_runs(evaluated):
    out, _ = evaluated
    runs = read(out / "runs.csv")
    assert {r["simulator"] for r in runs} == {"rhcr", "screen"}
    for row in read(out / "summary.csv"):
        mine = [
            r
            for r in runs
            if r["layout"] == row["layout"]
            and r["size"] == row["size"]
            and r["simulator"] == row["simulator"]
            and r["n_agents"] == row["n_agents"]
        ]
        mine = sorted(mine, key=lambda r: int(r["seed"]))[: int(row["runs"])]
        assert [int(r["seed"]) for r in mine] == list(range(int(row["runs"])))
        thr = [float(r["throughput"]) for r in mine]
        assert float(row["throughput_mean"]) == pytest.approx(np.mean(thr), abs=1e-6)
        ok = [r["success"] == "true" for r in mine]
        assert float(row["success_rate"]) == pytest.approx(np.mean(ok), abs=1e-6)
        if len(thr) > 1:
            se = np.std(thr, ddof=1) / math.sqrt(len(thr))
            assert float(row["throughput_se"]) == pytest.approx(se, abs=1e-6)


def test_curves_heatmaps_and_tasks(evaluated):
    out, _ = evaluated
    curve = read(out / "throughput_vs_agents_train.csv")
    assert {(r["layout"], r["n_agents"], r["simulator"]) for r in curve} == {
        (lab, n, "screen") for lab in ("NCA (cell 3)", "human") for n in ("4", "8")
    }
    assert all(r["runs"] == "2" for r in curve)
    heat = read(out / "tile_usage_train.csv.gz")
    nca = [r for r in heat if r["kind"] == "nca"]
    assert len(nca) == 9 * 14 and {r["simulator"] for r in heat} == {"rhcr"}  # RHCR preferred
    assert all(float(r["visits_mean"]) == 0 for r in nca if r["tile"] == "@")
    # every agent is on some tile at every step until the run stops: visits add up to
    # N_a * stop_time, averaged over the RHCR runs of the main comparison
    stops = [
        int(r["stop_time"])
        for r in read(out / "runs.csv")
        if r["kind"] == "nca" and r["size"] == "9x14" and r["simulator"] == "rhcr" and r["n_agents"] == "8"
    ]
    assert len(stops) == 2
    total = sum(float(r["visits_mean"]) for r in nca)
    assert total == pytest.approx(8 * np.mean(stops))
    tasks = read(out / "tasks_over_time_train.csv.gz")
    for lab, sim in {(r["layout"], r["simulator"]) for r in tasks}:
        ts = [r for r in tasks if r["layout"] == lab and r["simulator"] == sim]
        assert [int(r["t"]) for r in ts] == list(range(1, 41))
    sizes = read(out / "scaling_sizes.csv")
    assert {(r["layout"], r["size"]) for r in sizes} == {
        ("NCA (cell 3)", "9x14"),
        ("NCA (cell 3)", "11x15"),
        ("NCA (cell 3)", "13x18"),
        ("human", "9x14"),
    }
    assert all(r["simulator"] == "screen" for r in sizes)  # exact.sizes=0
    assert {r["agents_at_max"] for r in sizes if r["size"] == "11x15"} == {"8"}


def test_layouts_are_saved_and_tiling_is_repaired(evaluated):
    from nca_qd.layouts import warehouse as wh
    from nca_qd.repair import make_rules
    from nca_qd.repair.validator import check

    out, _ = evaluated
    lays = {r["layout"] + "@" + r["size"]: r for r in read(out / "layouts.csv")}
    assert lays["NCA (cell 3)@11x15"]["nca_iters"] == str(
        ev.interpolate_iters((11, 15), (9, 14), (13, 18), 50, 200)
    )
    for key, n_s in (
        ("NCA (cell 3)@9x14", 12),
        ("NCA (cell 3)@13x18", 24),
        ("tiling (cell 3)@13x18", 24),
        ("NCA (cell 3)@11x15", 14),
    ):
        lay = load_map(out / lays[key]["file"], wh.TILES).to_array(wh.TILES)
        assert check(lay, make_rules("warehouse_even", lay.shape, n_shelves=n_s)) is None, key
        # what the NCA placed and the repair kept, recounted from the two map files
        raw = load_map(out / lays[key]["file"].replace(".json", "_unrepaired.json"), wh.TILES)
        nca = raw.to_array(wh.TILES)
        for tile, name in (("@", "shelves"), ("e", "endpoints")):
            i = wh.TILES.index(tile)
            assert int(lays[key][f"nca_{name}"]) == int((nca == i).sum()), key
            assert int(lays[key][f"repaired_{name}"]) == int((lay == i).sum()), key
            assert int(lays[key][f"kept_{name}"]) == int(((nca == i) & (lay == i)).sum()), key
        assert int(lays[key]["repaired_shelves"]) == n_s
    assert all(v == "" for k, v in lays["human@9x14"].items() if k.startswith(("nca_", "kept_"))), lays


def test_a_dsage_run_is_evaluated_at_s_only(tmp_path, maps):
    """A DSAGE archive holds tile layouts of size S: the best is repaired and simulated at S
    beside the human layout; no S_eval, tiling or other size (the paper's "N/A")."""
    from nca_qd.layouts import warehouse as wh
    from nca_qd.repair import make_rules
    from nca_qd.repair.validator import check

    run_dir = make_run(tmp_path / "dsage", [*TINY_RUN, "algo=dsage"])
    out = tmp_path / "evaluation"
    with contextlib.redirect_stdout(io.StringIO()):
        assert evaluate_cli.main([f"run_dir={run_dir}", f"out={out}", *FAST, "sweep.train.agents=[]"]) == 0
    summary = read(out / "summary.csv")
    assert {(r["layout"], r["kind"], r["size"]) for r in summary} == {
        ("DSAGE (cell 3)", "dsage", "9x14"),
        ("human", "human", "9x14"),
    }
    assert {r["simulator"] for r in summary} == {"rhcr", "screen"}
    runs = read(out / "runs.csv")
    assert {r["size"] for r in runs} == {"9x14"}
    assert sum(r["simulator"] == "rhcr" and r["kind"] == "dsage" for r in runs) == 2  # exact.train
    # the unrepaired layout is the archive's elite itself (no generation step), with the frame
    elite = np.load(run_dir / "archive_result.npz")["genotypes"][3].reshape(9, 10)
    unrepaired = load_map(out / "layouts" / "dsage_c3_9x14_unrepaired.json", wh.TILES).to_array(wh.TILES)
    assert np.array_equal(unrepaired[:, 2:-2], elite.astype(np.int32))
    repaired = load_map(out / "layouts" / "dsage_c3_9x14.json", wh.TILES).to_array(wh.TILES)
    assert check(repaired, make_rules("warehouse_even", repaired.shape, n_shelves=12)) is None
    assert not list(out.glob("*13x18*")) and not list((out / "layouts").glob("*13x18*"))


def test_tiling_keeps_the_frame_and_repeats_the_pattern():
    from nca_qd.layouts import warehouse as wh

    rng = np.random.default_rng(1)
    small = wh.assemble(rng.integers(0, 3, (5, 4)))
    big = ev.tile_layout("warehouse_even", small, (12, 13))
    assert big.shape == (12, 13)
    np.testing.assert_array_equal(big, wh.assemble(wh.storage(big)))  # frame as required
    store = wh.storage(big)
    np.testing.assert_array_equal(store[5:10, 4:8], wh.storage(small))
    man = rng.integers(0, 5, (4, 6))
    tiled = ev.tile_layout("manufacturing", man, (9, 10))
    np.testing.assert_array_equal(tiled[4:8, 6:10], man[:, :4])


def test_statistics_leave_out_timed_out_runs(maps):
    settings = ExactSettings(5000, 1e-6, 10, 5, {})
    rows = exact_job(HUMAN_9x14, "warehouse_even", 6, 0, settings)
    assert rows.timed_out and not rows.success
    ok = RunOutcome("rhcr", 1, 0.5, True, 100)
    s = ev.run_stats([rows, ok, RunOutcome("rhcr", 2, error="boom")])
    assert (s["runs"], s["completed"], s["timed_out"], s["errors"]) == (3, 1, 1, 1)
    assert s["success_rate"] == 1.0 and s["throughput_mean"] == 0.5
    assert math.isnan(s["throughput_se"])


def test_agent_counts():
    assert ev.agent_range(
        {"agents": None, "start": None, "stop": None, "step": None}, 1400, 25, "sweep.eval"
    ) == list(range(700, 1751, 25))
    assert ev.agent_range({"agents": [5, 3]}, 10, 1, "x") == [5, 3]
    assert ev.scaled_agents((101, 102), 1400, (101, 102), [0.5, 1.0], 10) == [700, 1400]
    assert ev.scaled_agents((45, 47), 1400, (101, 102), [1.0], 10) == [290]
    with pytest.raises(NcaQdError, match="positive"):
        ev.agent_range({"agents": [0]}, 10, 1, "sweep.train")


def test_pick_cells():
    obj = np.array([1.0, -np.inf, 3.0, 2.0, -np.inf])
    assert list(ev.pick_cells(obj, 2)) == [2, 3]
    assert list(ev.pick_cells(obj, 9)) == [2, 3, 0]
    assert list(ev.pick_cells(obj, [3, 0])) == [3, 0]
    with pytest.raises(NcaQdError, match=r"no elite in archive cell\(s\) \[1, 7\]"):
        ev.pick_cells(obj, [1, 7, 2])


def _selection_args(tmp_path: Path, *more: str) -> tuple[Path, list[str]]:
    """The evaluation folder and the arguments of a screened evaluation of a tiny run (S_eval
    only, no tiling baseline) whose generators are picked by select.by=s_eval among its two,
    2 screened runs each, with ``more``."""
    run_dir, out = make_run(tmp_path / "run"), tmp_path / "evaluation"
    pool = ["baselines.tiling=false", "select.by=s_eval", "select.pool=2", "select.runs=2"]
    return out, [f"run_dir={run_dir}", f"out={out}", *SCREEN_ONLY, "runs.train=1", *pool, *more]


def test_select_by_s_eval_picks_the_best_screened_generator(tmp_path, maps, monkeypatch):
    """select.by=s_eval screens the pool's S_eval layouts and evaluates the best one; its
    figure is reproduced by screening the layout saved under selection/, and the evaluation
    reuses that layout instead of generating and repairing it again."""
    from nca_qd.sim.screen import simulate_batch

    repaired: list[str] = []
    real_repair_all = ev.repair_all

    def counting_repair_all(backend, domain_name, items, **kw):
        repaired.extend(it.key for it, _ in items)
        return real_repair_all(backend, domain_name, items, **kw)

    monkeypatch.setattr(ev, "repair_all", counting_repair_all)
    out, args = _selection_args(tmp_path, "runs.eval=1", "select.T=60")
    assert evaluate_cli.main(args) == 0
    sel = read(out / "selection.csv")
    assert sorted(int(r["cell"]) for r in sel) == [3, 7]
    scored = [r for r in sel if r["screen_runs"] == "2"]
    assert scored, sel
    best = max(scored, key=lambda r: (float(r["screen_throughput_mean"]), float(r["objective_s"])))
    assert [r["cell"] for r in sel if r["selected"] == "true"] == [best["cell"]]
    cells = {r["cell"] for r in read(out / "summary.csv") if r["kind"] == "nca"}
    assert cells == {best["cell"]}
    assert all((out / r["file"]).is_file() for r in sel)  # every candidate's layout
    rows = load_map(out / best["file"]).rows
    # one repair per layout: the pool at S_eval (selection), then the chosen one's S layout only
    assert sorted(repaired) == sorted(["nca_c3@13x18", "nca_c7@13x18", f"nca_c{best['cell']}@9x14"])
    assert load_map(out / "layouts" / f"nca_c{best['cell']}_13x18.json").rows == rows
    # each candidate's repair figures: the Hamming distance between its generated and repaired
    # S_eval layouts, counted here from the files, and Δ = 1 - Hamming / tiles
    unrepaired = load_map(out / "layouts" / f"nca_c{best['cell']}_13x18_unrepaired.json").rows
    changed = sum(a != b for ra, rb in zip(rows, unrepaired) for a, b in zip(ra, rb))
    best_row = next(r for r in sel if r["cell"] == best["cell"])
    assert int(best_row["hamming"]) == changed
    assert float(best_row["similarity"]) == pytest.approx(1 - changed / (13 * 18), abs=1e-6)
    again = simulate_batch([rows], "warehouse_even", 12, 60, [0, 1])[0]
    assert np.mean([r.throughput for r in again]) == pytest.approx(float(best["screen_throughput_mean"]))
    # the same command again: the selection's screened runs come from screen_runs.jsonl (and
    # the repairs from repairs.jsonl): nothing is simulated, the same selection.csv
    import nca_qd.sim.screen as screen_mod

    def no_screen(*a, **kw):
        raise AssertionError("screened again")

    monkeypatch.setattr(screen_mod, "simulate_scenarios", no_screen)
    before = (out / "selection.csv").read_text()
    assert evaluate_cli.main(args) == 0
    assert (out / "selection.csv").read_text() == before


def test_select_exact_top_checks_the_screens_best_by_exact_runs(tmp_path, maps):
    """select.exact_top: the best by the screen get select.exact_runs exact RHCR runs at S_eval
    and the best by those (success rate, then mean throughput) is chosen; each candidate's
    exact figures are reproduced by simulating its saved layout here, and with select.T = T
    the chosen one's check runs are its first S_eval runs (recorded once, not run again)."""
    from experiments.cli import compose_config
    from nca_qd.sim.rhcr import simulate

    out, args = _selection_args(
        tmp_path,
        "runs.eval=3",
        "exact.eval=3",
        "exact.time_limit_s=60",
        "select.T=20",
        "select.exact_top=2",
        "select.exact_runs=2",
    )
    assert evaluate_cli.main(args) == 0
    sel = read(out / "selection.csv")
    checked = [r for r in sel if r["exact_runs"] == "2"]
    assert len(checked) == 2, sel
    ex = compose_config("evaluate", args).exact
    for r in checked:
        rows = load_map(out / r["file"]).rows
        opts = {"window": ex.window, "replan": ex.replan}
        runs = [simulate(rows, "warehouse_even", 12, 20, seed, **opts) for seed in (0, 1)]
        assert float(r["exact_success_rate"]) == pytest.approx(np.mean([x.success for x in runs]))
        assert float(r["exact_throughput_mean"]) == pytest.approx(np.mean([x.throughput for x in runs]))
    best = max(checked, key=lambda r: (float(r["exact_success_rate"]), float(r["exact_throughput_mean"])))
    assert [r["cell"] for r in sel if r["selected"] == "true"] == [best["cell"]]
    assert {r["cell"] for r in read(out / "summary.csv") if r["kind"] == "nca"} == {best["cell"]}
    # 2 candidates x 2 check runs, and the chosen one's third S_eval run: 5 exact runs, not 7
    assert len(record_lines(out, "exact_runs")) == 5
    chosen = [r for r in read(out / "runs.csv") if r["simulator"] == "rhcr" and r["size"] == "13x18"]
    assert sorted(int(r["seed"]) for r in chosen) == [0, 1, 2]
    # and a bad setting is one clear error
    with pytest.raises(NcaQdError, match=r"select.exact_top \(3\) exceeds select.pool \(2\)"):
        evaluate_cli.main([*args, "select.exact_top=3"])


def test_the_exact_check_ranks_before_the_screen(monkeypatch):
    """_exact_check puts the checked candidates first by exact success, then throughput, even
    against the screen's order, and leaves the unchecked in the screen's order after them."""
    from types import SimpleNamespace

    from nca_qd.evaluation import selection

    def fake_cells(cells, layouts, *a, **kw):
        figures = {"a": (False, 3.0), "b": (True, 1.0), "c": (True, 2.0)}
        return {
            (k, n, "rhcr"): [RunOutcome("rhcr", s, figures[k][1], figures[k][0], 20) for s in (0, 1)]
            for (k, n) in cells
        }

    monkeypatch.setattr("nca_qd.evaluation.runs.simulate_cells", fake_cells)
    plan = SimpleNamespace(
        select=ev.SelectSettings("s_eval", 4, 2, 20, 3, 2), n_eval=12, seed=0, select_exact=None, screen=None
    )
    items = {i: SimpleNamespace(key=k) for i, k in enumerate("abcd")}
    ranked = [{"cell": i, "exact_runs": 0} for i in range(4)]  # the screen's order: a, b, c, d
    out = selection._exact_check(plan, "warehouse_even", "", items, ranked, None, None)
    assert [r["cell"] for r in out] == [2, 1, 0, 3]
    assert out[0]["exact_success_rate"] == 1.0 and out[0]["exact_throughput_mean"] == 2.0


def _evaluate_again(evaluated, name: str, *overrides: str) -> Path:
    """The fixture's run evaluated once more into ``name`` beside its evaluation, with the fast
    settings and ``overrides``."""
    out, _ = evaluated
    again = out.parent / name
    args = [f"run_dir={out.parent / 'run'}", f"out={again}", *FAST, *overrides]
    with contextlib.redirect_stdout(io.StringIO()):
        assert evaluate_cli.main(args) == 0
    return again


def test_an_evaluation_with_the_pibt_planner_labels_its_exact_runs_pibt(evaluated):
    out, _ = evaluated
    out2 = _evaluate_again(evaluated, "evaluation_pibt", "exact.planner=pibt")
    runs = read(out2 / "runs.csv")
    exact = [r for r in runs if r["simulator"] != "screen"]
    assert exact and {r["simulator"] for r in exact} == {"pibt"}
    assert {r["simulator"] for r in read(out2 / "summary.csv")} <= {"pibt", "screen", ""}
    assert {r["simulator"] for r in read(out2 / "tile_usage_train.csv.gz")} == {"pibt"}
    md = (out2 / "summary.md").read_text()
    assert "pibt = exact" in md and "| rhcr |" not in md and "with the PIBT planner instead of RHCR" in md
    # the RHCR evaluation of the same run says rhcr, as before
    assert "rhcr" in {r["simulator"] for r in read(out / "runs.csv")}


def test_the_tiling_baseline_tiles_the_repaired_or_the_generated_s_layout(evaluated):
    """baselines.tiling_from: the default tiles the repaired S layout; unrepaired tiles what the
    NCA generated at S (the paper's 2,500 shelves at S_eval are its unrepaired tiling's count).
    Checked against the storage regions of the S layouts the evaluation saved, tiled here."""
    out, _ = evaluated
    out3 = _evaluate_again(evaluated, "evaluation_tiling_unrepaired", "baselines.tiling_from=unrepaired")

    def region(path: Path) -> np.ndarray:
        return np.array([list(r[2:-2]) for r in load_map(path).rows])  # storage: between 2-column frames

    for folder, source in ((out, "nca_c3_9x14.json"), (out3, "nca_c3_9x14_unrepaired.json")):
        small = region(folder / "layouts" / source)
        tiled = region(folder / "layouts" / "tiling_c3_13x18_unrepaired.json")
        reps = (-(-tiled.shape[0] // small.shape[0]), -(-tiled.shape[1] // small.shape[1]))
        np.testing.assert_array_equal(tiled, np.tile(small, reps)[: tiled.shape[0], : tiled.shape[1]])
    labels = {r["layout"] for r in read(out3 / "layouts.csv") if r["kind"] == "tiling"}
    assert labels == {"tiling (cell 3, unrepaired S)"}
    assert not np.array_equal(
        region(out / "layouts" / "nca_c3_9x14.json"), region(out / "layouts" / "nca_c3_9x14_unrepaired.json")
    )


def test_tiling_draws_repair_one_tiled_layout_with_successive_seeds(evaluated):
    """baselines.tiling_draws=3: the same tiled layout three times, each repaired with the
    repair's seed + j (another of the equally near layouts the random tie-break can return),
    each valid by the independent validator, as near to the tiled layout as the first and
    simulated as it is. (At 24 shelves this tiling has one nearest repair; at 20 it has several.)"""
    from nca_qd.layouts import warehouse as wh
    from nca_qd.repair.validator import check

    out4 = _evaluate_again(
        evaluated, "evaluation_tiling_draws", "baselines.tiling_draws=3", "n_shelves.eval=20"
    )
    rows = [r for r in read(out4 / "layouts.csv") if r["kind"] == "tiling"]
    assert [r["layout"] for r in rows] == [
        "tiling (cell 3)",
        "tiling (cell 3, repair draw 1)",
        "tiling (cell 3, repair draw 2)",
    ]
    names = ["tiling_c3_13x18", "tiling_c3_d1_13x18", "tiling_c3_d2_13x18"]
    raw = [load_map(out4 / "layouts" / f"{n}_unrepaired.json").rows for n in names]
    assert raw[0] == raw[1] == raw[2]
    fixed = [load_map(out4 / "layouts" / f"{n}.json") for n in names]
    for m in fixed:
        assert check(m.to_array(wh.TILES), wh.rules((13, 18), n_shelves=20)) is None
    changed = {sum(a != b for x, y in zip(raw[0], m.rows) for a, b in zip(x, y)) for m in fixed}
    assert len(changed) == 1 and changed != {0}  # equally near
    assert len({tuple(m.rows) for m in fixed}) > 1  # another seed, another of the nearest repairs
    exact = [r for r in read(out4 / "summary.csv") if r["kind"] == "tiling" and r["simulator"] == "rhcr"]
    assert [r["layout"] for r in exact] == [r["layout"] for r in rows] and {r["runs"] for r in exact} == {"1"}


def test_detail_false_keeps_verdicts_and_throughputs_but_no_per_step_records_or_pictures(evaluated):
    """detail=false (a check that needs only verdicts): the same figures as the detailed
    evaluation of the same run (same layouts, seeds), no tasks_over_time_* or tile_usage_*
    files, and exact records without tasks per step or tile visits (the bulk of a record)."""
    out, _ = evaluated
    bare = _evaluate_again(evaluated, "evaluation_bare", "detail=false")
    assert not list(bare.glob("tasks_over_time_*")) and not list(bare.glob("tile_usage_*"))
    assert list(out.glob("tasks_over_time_*")) and list(out.glob("tile_usage_*"))
    recs = record_lines(bare, "exact_runs")
    assert recs and all(r["tasks_per_step"] is None and r["tile_visits"] is None for r in recs)
    assert any(r["tasks_per_step"] is not None for r in record_lines(out, "exact_runs"))

    def figures(folder: Path) -> list[tuple[str, ...]]:
        cols = ("size", "n_agents", "layout", "simulator", "runs", "success_rate", "throughput_mean")
        return sorted(tuple(r[c] for c in cols) for r in read(folder / "summary.csv"))

    assert figures(bare) == figures(out)
