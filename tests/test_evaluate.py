"""experiments.evaluate on a tiny synthetic warehouse run: every table and figure, simulator
labels, statistics, the tiling baseline; one-line errors (exit 2) on bad input."""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

from experiments import evaluate as evaluate_cli
from experiments.cli import compose_config, main_guard
from nca_qd import evaluation as ev
from nca_qd.errors import NcaQdError
from nca_qd.io import atomic_write_text, load_map, save_npz
from nca_qd.scoring.jobs import ExactSettings, RunOutcome, exact_job

# Storage 9x10 (9x14 with the workstation columns) at S, 13x14 (13x18) at S_eval.
TINY_RUN = [
    "domain=warehouse_even",
    "domain.size.train=[9,10]",
    "domain.size.eval=[13,14]",
    "domain.repair.n_shelves.train=12",
    "domain.repair.n_shelves.eval=24",
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
FAST = [
    "T=40",
    "runs.train=3",
    "runs.eval=2",
    "exact.train=2",
    "exact.eval=1",
    "exact.time_limit_s=60",
    "sweep.train.agents=[4,8]",
    "sweep.train.runs=2",
    "sweep.eval.agents=[]",
    "sizes.shapes=[[11,15]]",
    "sizes.n_shelves={11x15: 14}",
    "sizes.agents={9x14: [8], 13x18: [12], 11x15: [8]}",
    "sizes.runs=2",
    "eval.workers=0",
    "progress=false",
    "tasks_smooth=5",
]


def make_run(run_dir: Path, overrides=TINY_RUN, elites=(3, 7), empty=False) -> Path:
    """A run directory with config.yaml and a result archive of random generators."""
    from nca_qd.domains import make_domain
    from nca_qd.pipeline import make_generator

    cfg = compose_config("run", list(overrides))
    direct = cfg.algo.name == "dsage"  # the archive holds tile layouts, not NCA parameters
    domain = make_domain(cfg.domain) if cfg.domain.name != "maze" else None
    n_params = make_generator(domain, cfg.algo.name).n_params if domain is not None else 10
    cells = 12
    rng = np.random.default_rng(0)
    genotypes = np.zeros((cells, n_params), np.float32)
    objective = np.full(cells, -np.inf, np.float32)
    if not empty:
        for rank, c in enumerate(elites):
            genotypes[c] = (
                (rng.random(n_params) < 0.15).astype(np.float32)  # 0 = empty, 1 = shelf
                if direct
                else 0.3 * rng.standard_normal(n_params)
            )
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


@pytest.fixture(scope="module")
def maps(tmp_path_factory):
    root = tmp_path_factory.mktemp("maps")
    (root / "warehouse").mkdir()
    (root / "warehouse" / "human_9x14.json").write_text(
        json.dumps({"name": "human_9x14", "layout": HUMAN_9x14, "n_row": 9, "n_col": 14})
    )
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("NCA_QD_MAPS", str(root))
        yield root


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


def read(path: Path) -> list[dict[str, str]]:
    import gzip

    with gzip.open(path, "rt") if path.suffix == ".gz" else path.open() as fh:
        return list(csv.DictReader(fh))


def record_lines(folder: Path, name: str) -> list[dict]:
    """The records of ``<folder>/<name>``, read from the files themselves: the packed
    ``.jsonl.gz`` (written when an evaluation stops), then the plain journal appended since."""
    import gzip

    lines: list[str] = []
    if (folder / f"{name}.jsonl.gz").is_file():
        lines += gzip.decompress((folder / f"{name}.jsonl.gz").read_bytes()).decode().splitlines()
    if (folder / f"{name}.jsonl").is_file():
        lines += (folder / f"{name}.jsonl").read_text().splitlines()
    return [json.loads(x) for x in lines if x.strip()]


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
    run_dir = make_run(tmp_path / "run")
    out = tmp_path / "evaluation"
    code = evaluate_cli.main(
        [
            f"run_dir={run_dir}",
            f"out={out}",
            "T=20",
            "runs.train=1",
            "runs.eval=1",
            "exact.train=0",
            "exact.eval=0",
            "sweep.train.agents=[]",
            "sweep.eval.agents=[]",
            "sizes.shapes=[]",
            "sizes.include_main=false",
            "baselines.tiling=false",
            "baselines.human=false",
            "eval.workers=0",
            "progress=false",
            "select.by=s_eval",
            "select.pool=2",
            "select.runs=2",
            "select.T=60",
        ]
    )
    assert code == 0
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
    again = simulate_batch([rows], "warehouse_even", 12, 60, [0, 1])[0]
    assert np.mean([r.throughput for r in again]) == pytest.approx(float(best["screen_throughput_mean"]))


# ------------------------------------------------------------------------------ bad input
def run_cli(argv, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["prog", *argv])
    with pytest.raises(SystemExit) as exc:
        main_guard(evaluate_cli.main)()
    return exc.value.code


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    return make_run(tmp_path_factory.mktemp("bad") / "run")


@pytest.mark.parametrize(
    "case, expect",
    [
        ("missing", "does not exist"),
        ("not_a_run", "not a run directory"),
        ("maze", "maze run: experiments.evaluate supports only"),
        ("dsage", "is a DSAGE run: its layouts exist at the training size only, so select.by=s_eval"),
        ("mismatch", "domain=manufacturing given, but"),
        ("empty", "the result archive is empty"),
        ("no_run_dir", "give run_dir"),
        ("exact_over_runs", "exact.train (9) exceeds runs.train (3)"),
        ("dask", "Dask scheduler"),
        ("stray_size", "sizes.agents names 50x50, not a size of the curve"),
        ("not_a_map", "sizes.n_shelves must map sizes to values"),
        ("select_by", "select.by must be s or s_eval, got 'best'"),
        ("select_pool", "elites (3) exceeds select.pool (2)"),
        ("select_list", "elites must be a count"),
        ("screen_reuse", "screen.reuse must be true or false, got 'sometimes'"),
        ("shelves_count", "n_shelves.eval must be an integer >= 1, got 0"),
        ("shelves_manufacturing", "n_shelves.eval: manufacturing has no shelves"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(case, expect, tmp_path, tiny_run, monkeypatch, capsys):
    argv = [f"run_dir={tiny_run}", f"out={tmp_path / 'o'}"]
    if case == "missing":
        argv[0] = f"run_dir={tmp_path / 'nope'}"
    elif case == "not_a_run":
        argv[0] = f"run_dir={tmp_path}"
    elif case == "maze":
        argv[0] = f"run_dir={make_run(tmp_path / 'maze', ['domain=maze'])}"
    elif case == "dsage":
        argv[0] = f"run_dir={make_run(tmp_path / 'dsage', [*TINY_RUN, 'algo=dsage'])}"
        argv.append("select.by=s_eval")
    elif case == "mismatch":
        argv.append("domain=manufacturing")
    elif case == "empty":
        argv[0] = f"run_dir={make_run(tmp_path / 'empty', empty=True)}"
    elif case == "no_run_dir":
        argv = []
    elif case == "exact_over_runs":
        argv += ["runs.train=3", "exact.train=9"]
    elif case == "stray_size":
        argv.append("sizes.agents={50x50: [10]}")
    elif case == "not_a_map":
        argv.append("sizes.n_shelves=[1,2]")
    elif case == "select_by":
        argv.append("select.by=best")
    elif case == "select_pool":
        argv += ["select.by=s_eval", "select.pool=2", "elites=3"]
    elif case == "select_list":
        argv += ["select.by=s_eval", "elites=[3,7]"]
    elif case == "screen_reuse":
        argv.append("screen.reuse=sometimes")
    elif case == "shelves_count":
        argv.append("n_shelves.eval=0")
    elif case == "shelves_manufacturing":
        argv[0] = f"run_dir={make_run(tmp_path / 'mf', ['domain=manufacturing'])}"
        argv.append("n_shelves.eval=2500")
    elif case == "dask":
        argv += ["eval.scheduler=tcp://127.0.0.1:9", "eval.connect_timeout_s=1"]
    code = run_cli(argv, monkeypatch)
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert err.startswith("error: ") and expect in err, err
    assert not (tmp_path / "o").exists()


def test_n_shelves_sets_the_shelf_count_of_its_size_only(tiny_run):
    """n_shelves.eval (the paper's released S_eval layouts hold 2,500 shelves where its table
    says 2,250) changes N_s at S_eval; S keeps the run's count."""
    from nca_qd.evaluation.plan import Plan, validated

    e = validated(
        OmegaConf.to_container(compose_config("evaluate", [f"run_dir={tiny_run}", "n_shelves.eval=30"]))
    )
    d = OmegaConf.to_container(compose_config("run", TINY_RUN).domain, resolve=True)
    plan = Plan(e, d, "warehouse_even")
    assert plan.repair_options(plan.s_eval)["n_shelves"] == 30
    assert plan.repair_options(plan.s_train)["n_shelves"] == 12
    e_default = validated(OmegaConf.to_container(compose_config("evaluate", [f"run_dir={tiny_run}"])))
    plan = Plan(e_default, d, "warehouse_even")
    assert plan.repair_options(plan.s_eval)["n_shelves"] == 24


def test_exact_runs_go_to_the_curve_points_named_and_no_others(tiny_run):
    """sweep.<size>.exact_agents: exact verdicts on a few points of a curve (issue 55 asks for
    three per curve) without exact runs at every point; null keeps every point exact."""
    from nca_qd.evaluation.plan import Plan, validated
    from nca_qd.evaluation.records import EvalLayout

    d = OmegaConf.to_container(compose_config("run", TINY_RUN).domain, resolve=True)

    def exact_at(cmd: list[str]) -> dict[int, int]:
        e = validated(OmegaConf.to_container(compose_config("evaluate", [f"run_dir={tiny_run}", *cmd])))
        plan = Plan(e, d, "warehouse_even")
        lay = EvalLayout("k", "NCA", "nca", "9x14", "train", np.zeros(plan.s_train, np.int32), cell=3)
        return {r.n_agents: r.exact_runs for r in plan.requests({"k": lay}) if r.purpose == "sweep_train"}

    base = ["sweep.train.agents=[4,6,8]", "exact.sweep_train=2"]
    assert exact_at(base) == {4: 2, 6: 2, 8: 2}
    assert exact_at([*base, "sweep.train.exact_agents=[4,8]"]) == {4: 2, 6: 0, 8: 2}
    with pytest.raises(NcaQdError, match="sweep.train.exact_agents names 5, not a point of the curve"):
        exact_at([*base, "sweep.train.exact_agents=[5]"])


def test_repair_tie_break_comes_from_the_run_unless_this_command_overrides_it(tiny_run):
    """A run repaired with tie_break=none is evaluated with none (its own repair); the
    command's repair.tie_break=random overrides it at every size."""
    from nca_qd.evaluation.plan import Plan, validated

    def opts(cmd: list[str], run: list[str]) -> list[str]:
        e = validated(OmegaConf.to_container(compose_config("evaluate", [f"run_dir={tiny_run}", *cmd])))
        d = OmegaConf.to_container(compose_config("run", [*TINY_RUN, *run]).domain, resolve=True)
        plan = Plan(e, d, "warehouse_even")
        return [plan.repair_options(s)["tie_break"] for s in (plan.s_train, plan.s_eval)]

    assert opts([], ["domain.repair.tie_break=none"]) == ["none", "none"]
    assert opts([], []) == ["random", "random"]  # the domains' default
    assert opts(["repair.tie_break=random"], ["domain.repair.tie_break=none"]) == ["random", "random"]


def test_too_many_agents_names_the_layout(tiny_run, tmp_path, maps, monkeypatch, capsys):
    code = run_cli(
        [
            f"run_dir={tiny_run}",
            f"out={tmp_path / 'o'}",
            "sweep.train.agents=[500]",
            "sweep.eval.agents=[]",
            "sizes.shapes=[]",
            "sizes.include_main=false",
            "baselines.tiling=false",
            "eval.workers=0",
            "progress=false",
        ],
        monkeypatch,
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and not any("Traceback" in l for l in err)
    assert err[-1].startswith("error: ") and "500 agents but only" in err[-1]
    assert "(9x14)" in err[-1] and "lower the agent counts" in err[-1]
    # no output, only the repairs made before the check, which the corrected command reuses
    # (packed when the evaluation stopped)
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["repairs.jsonl.gz"]


def test_a_failed_repair_is_a_row_without_runs_and_old_outputs_go(tmp_path, maps):
    """N_s = 1000 cannot fit 13x18: the S_eval repair is infeasible; the summary says so and
    nothing is simulated there; a file of an earlier evaluation that is not rewritten goes."""
    run_dir = make_run(
        tmp_path / "run",
        [o for o in TINY_RUN if "n_shelves.eval" not in o] + ["domain.repair.n_shelves.eval=1000"],
    )
    out = tmp_path / "ev"
    out.mkdir()
    stale = out / "throughput_vs_agents_eval.png"
    stale.write_bytes(b"old")
    import os

    os.utime(stale, (1, 1))
    with contextlib.redirect_stdout(io.StringIO()):
        assert (
            evaluate_cli.main(
                [
                    f"run_dir={run_dir}",
                    f"out={out}",
                    "T=20",
                    "runs.train=2",
                    "runs.eval=2",
                    "exact.train=0",
                    "exact.eval=0",
                    "sweep.train.agents=[]",
                    "sweep.eval.agents=[]",
                    "sizes.shapes=[]",
                    "sizes.include_main=false",
                    "baselines.human=false",
                    "eval.workers=0",
                    "progress=false",
                ]
            )
            == 0
        )
    rows = read(out / "summary.csv")
    failed = [r for r in rows if r["which"] == "eval"]
    assert [(r["kind"], r["repair_status"], r["simulator"], r["runs"]) for r in failed] == [
        ("nca", "infeasible", "", ""),
        ("tiling", "infeasible", "", ""),
    ]
    assert {r["simulator"] for r in rows if r["which"] == "train"} == {"screen"}
    assert not stale.exists()
    assert "infeasible" in (out / "summary.md").read_text()


def test_the_exact_run_record_keys_on_every_input_and_keeps_only_what_it_can_serve(tmp_path, monkeypatch):
    from nca_qd.evaluation.store import ExactRunStore
    from nca_qd.scoring.keys import exact_run_key
    from nca_qd.sim import rhcr

    settings = ExactSettings(40, None, 10, 5, {"pbs_max_nodes": 2000})
    args = (HUMAN_9x14, "warehouse_even", 8, 0, settings)
    key = exact_run_key(*args)
    assert exact_run_key(*args) == key
    changed = [
        ([HUMAN_9x14[0][:-1] + "@", *HUMAN_9x14[1:]], *args[1:]),  # one tile
        (*args[:3], 1, settings),  # the seed
        (*args[:4], ExactSettings(40, None, 10, 5, {"pbs_max_nodes": 3000})),  # the planner
        (*args[:4], ExactSettings(40, None, 10, 4, {"pbs_max_nodes": 2000})),  # replanning
    ]
    assert len({key, *(exact_run_key(*a) for a in changed)}) == 5
    # the wall-clock limit does not decide a run that ends: a run recorded under one serves
    assert exact_run_key(*args[:4], ExactSettings(40, 60.0, 10, 5, {"pbs_max_nodes": 2000})) == key
    monkeypatch.setattr(rhcr, "VERSION", rhcr.VERSION + 1)
    assert exact_run_key(*args) != key  # a revised simulator
    monkeypatch.setattr(rhcr, "VERSION", 1)
    # recorded files hold these keys: the digest must not drift with a refactor
    assert exact_run_key(*args) == "3b0a1e335a9a2af27f08b9b83f19575c"
    monkeypatch.undo()

    store = ExactRunStore(tmp_path)
    tasks, visits = np.arange(40, dtype=np.int32) % 3, np.ones((9, 14), np.int64)
    store.add(key, RunOutcome("rhcr", 0, 0.5, True, 40, False, 1.0, None, tasks, visits))
    store.add("bare", RunOutcome("rhcr", 1, 0.25, False, 12, False, 1.0))
    store.add("slow", RunOutcome("rhcr", 2, timed_out=True))
    store.add(key, RunOutcome("rhcr", 0, 0.5, True, 40, False, 1.0))  # never replaces detail
    again = ExactRunStore(tmp_path)  # as the next evaluation reads it
    got = again.get(key, need_detail=True)
    assert got is not None and (got.throughput, got.success, got.stop_time) == (0.5, True, 40)
    np.testing.assert_array_equal(got.tasks_per_step, tasks)
    np.testing.assert_array_equal(got.tile_visits, visits)
    assert again.get("bare", need_detail=False).stop_time == 12
    assert again.get("bare", need_detail=True) is None  # a request for tasks over time reruns it
    assert again.get("slow", need_detail=False) is None  # a timed-out run is tried again
    assert again.get("unknown", need_detail=False) is None


def test_the_screen_run_record_keys_on_every_input_and_the_screen_version(tmp_path, monkeypatch):
    from nca_qd.evaluation.store import ScreenRunStore
    from nca_qd.scoring.keys import screen_run_key
    from nca_qd.sim import screen

    args = (HUMAN_9x14, "warehouse_even", 8, 40, 0, 5)
    key = screen_run_key(*args)
    changed = [
        ([HUMAN_9x14[0][:-1] + "@", *HUMAN_9x14[1:]], *args[1:]),  # one tile
        (*args[:2], 9, *args[3:]),  # agents
        (*args[:4], 1, args[5]),  # the seed
        (*args[:5], 4),  # replan
        (*args, 19.25),  # the crowding threshold (a domain's own)
    ]
    assert len({key, *(screen_run_key(*a) for a in changed)}) == 6
    assert screen_run_key(*args, screen.CROWD_MEAN) == key  # the default: keys recorded before it
    for name, value in (("VERSION", screen.VERSION + 1), ("PRIORITY", "age"), ("CONGESTION", "moved")):
        with monkeypatch.context() as mp:
            mp.setattr(screen, name, value)
            assert screen_run_key(*args) != key, name
    with monkeypatch.context() as mp:  # recorded files hold these keys: pinned against drift
        pinned = {"VERSION": 1, "PLANNER": "pibt", "PRIORITY": "random", "CONGESTION": "crowding"}
        for name, value in pinned.items():
            mp.setattr(screen, name, value)
        assert screen_run_key(*args) == "f490bfb73186cb2d981970e7b69be5c5"
    store = ScreenRunStore(tmp_path)
    store.add(key, RunOutcome("screen", 0, 0.5, True, 40, False, 0.1))
    got = ScreenRunStore(tmp_path).get(key, need_detail=False)
    assert got is not None and (got.simulator, got.throughput, got.stop_time) == ("screen", 0.5, 40)
    assert (tmp_path / "screen_runs.jsonl").is_file() and not (tmp_path / "exact_runs.jsonl").exists()
    store.pack()  # as when an evaluation stops: one gzip file, the journal gone
    assert not (tmp_path / "screen_runs.jsonl").exists()
    assert [r["key"] for r in record_lines(tmp_path, "screen_runs")] == [key]
    assert ScreenRunStore(tmp_path).get(key, need_detail=False) == got


def test_the_repair_record_keys_on_every_input_and_keeps_only_found_layouts(tmp_path):
    from nca_qd.evaluation.store import RepairStore
    from nca_qd.layouts import warehouse as wh
    from nca_qd.scoring.jobs import RepairOutcome
    from nca_qd.scoring.keys import repair_key

    lay = load_map_rows(HUMAN_9x14)
    opts = {"n_shelves": 12, "n_agents": 8, "method": "hybrid"}
    key = repair_key("warehouse_even", lay, opts)
    one_tile = lay.copy()
    one_tile[0, 0] = wh.TILES.index("@")
    changed = [
        repair_key("warehouse_uneven", lay, opts),
        repair_key("warehouse_even", one_tile, opts),
        repair_key("warehouse_even", lay, {**opts, "n_shelves": 13}),
        repair_key("warehouse_even", lay, {**opts, "time_limit_s": 5}),
    ]
    assert len({key, *changed}) == 5
    assert repair_key("warehouse_even", lay, dict(reversed(list(opts.items())))) == key
    # recorded files hold these keys: the digest must not drift with a refactor
    assert key == "ae7f8a3dc5c8a72b6589adcc85d43153"
    store = RepairStore(tmp_path)
    store.add(key, RepairOutcome(lay, "optimal", 0.9, 3, 1.5))
    store.add("failed", RepairOutcome(None, "infeasible", 0.0, None, 2.0))
    again = RepairStore(tmp_path)  # as the next evaluation reads it
    got = again.get(key)
    assert got is not None and (got.status, got.similarity, got.hamming, got.seconds) == (
        "optimal",
        0.9,
        3,
        1.5,
    )
    np.testing.assert_array_equal(got.layout, lay)
    assert again.get("failed") is None  # a repair that found nothing is tried again


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


def test_records_pack_narrow_and_an_evaluation_prunes_what_it_did_not_use(tmp_path):
    import base64
    import json
    import zlib

    from nca_qd.evaluation.store import ExactRunStore, _pack, _unpack

    visits = np.array([[0, 3958], [7, 1]], dtype=np.int32)  # fits two bytes, not one
    packed = _pack(visits)
    assert packed["dtype"] == "<i4" and packed["stored"] == "<u2"
    back = _unpack(packed)
    assert back.dtype == np.int32
    np.testing.assert_array_equal(back, visits)
    wide = np.array([-1, 70000], dtype=np.int64)
    np.testing.assert_array_equal(_unpack(_pack(wide)), wide)
    assert _unpack(_pack(wide)).dtype == np.int64
    # a record written before "stored" existed (bytes in the declared dtype) still reads
    raw = base64.b64encode(zlib.compress(visits.tobytes())).decode()
    old = {"dtype": "<i4", "shape": [2, 2], "zlib_b64": raw}
    np.testing.assert_array_equal(_unpack(old), visits)

    tasks = np.arange(40, dtype=np.int32) % 3
    first = ExactRunStore(tmp_path)
    for k in ("a", "b", "c"):
        first.add(k, RunOutcome("rhcr", 0, 0.5, True, 40, False, 1.0, None, tasks, visits))
    first.add("a", RunOutcome("rhcr", 0, 0.5, True, 40, False, 1.0, None, tasks, visits))  # 2 lines
    # the next evaluation into the folder asks for a and b only, then ends and prunes
    second = ExactRunStore(tmp_path)
    assert second.get("a", True) is not None and second.get("b", False) is not None
    assert second.prune() == 1
    main = [r["key"] for r in record_lines(tmp_path, "exact_runs")]
    spare = [
        json.loads(x)["key"] for x in (tmp_path / "exact_runs.superseded.jsonl").read_text().splitlines()
    ]
    assert (main, spare) == (["a", "b"], ["c"])
    # nothing is lost: a later evaluation that asks for c gets it, and c moves back
    third = ExactRunStore(tmp_path)
    got = third.get("c", True)
    assert got is not None
    np.testing.assert_array_equal(got.tile_visits, visits)
    assert third.prune() == 2  # a and b were not asked for this time
    fourth = ExactRunStore(tmp_path)
    assert len(fourth) == 1 and all(fourth.get(k, True) is not None for k in "abc")


def test_screened_records_keep_their_tile_visits_only_where_asked_for(tmp_path):
    """A screened run asked for without its tile visits (its cell has exact runs) is packed
    without them, its tasks per step kept; one asked for with them, or not asked for at all in
    this evaluation, keeps them. A record without visits does not serve a request for them."""
    from nca_qd.evaluation.store import ScreenRunStore

    tasks, visits = np.arange(30, dtype=np.int32) % 4, np.ones((3, 4), dtype=np.int32)
    first = ScreenRunStore(tmp_path)
    for k in ("bare", "heat", "other"):
        first.add(k, RunOutcome("screen", 0, 0.4, True, 30, False, 0.1, None, tasks, visits))
    first.pack()
    second = ScreenRunStore(tmp_path)
    assert second.get("bare", need_detail=True, need_visits=False) is not None
    assert second.get("heat", need_detail=True) is not None
    second.pack()
    recs = {r["key"]: r for r in record_lines(tmp_path, "screen_runs")}
    assert recs["bare"]["detail"] and recs["bare"]["tile_visits"] is None
    assert recs["heat"]["tile_visits"] is not None and recs["other"]["tile_visits"] is not None
    third = ScreenRunStore(tmp_path)
    assert third.get("bare", need_detail=True) is None  # its visits are gone
    got = third.get("bare", need_detail=True, need_visits=False)
    assert got is not None and got.tile_visits is None
    np.testing.assert_array_equal(got.tasks_per_step, tasks)
    # a run with visits recorded again (now asked for) replaces the bare record, not the reverse
    third.add("bare", RunOutcome("screen", 0, 0.4, True, 30, False, 0.1, None, tasks, visits))
    third.add("heat", RunOutcome("screen", 0, 0.4, True, 30, False, 0.1, None, tasks, None))
    fourth = ScreenRunStore(tmp_path)
    assert fourth.get("bare", True) is not None and fourth.get("heat", True) is not None


def load_map_rows(rows):
    from nca_qd.io import rows_to_array
    from nca_qd.layouts import warehouse as wh

    return rows_to_array(rows, wh.TILES)


def test_an_evaluation_into_the_same_folder_reuses_its_repairs_and_so_its_runs(tmp_path, maps, monkeypatch):
    """The repair is time-limited, so repairing again may give another layout, which no
    recorded run serves. A second evaluation into the folder repairs nothing and runs nothing
    again; a folder written before repairs.jsonl adopts the layouts it saved; a saved layout
    that breaks the domain's rules is repaired again."""
    from nca_qd.scoring import jobs

    calls: list[tuple[int, int]] = []
    real_repair_job = jobs.repair_job

    def counting_repair_job(domain_name, layout, options):
        calls.append(np.shape(layout))
        return real_repair_job(domain_name, layout, options)

    monkeypatch.setattr(jobs, "repair_job", counting_repair_job)
    run_dir = make_run(tmp_path / "run", elites=(3,))
    out = tmp_path / "ev"
    argv = [
        f"run_dir={run_dir}",
        f"out={out}",
        "T=20",
        "runs.train=1",
        "runs.eval=1",
        "exact.train=1",
        "exact.eval=1",
        "sweep.train.agents=[]",
        "sweep.eval.agents=[]",
        "sizes.shapes=[]",
        "baselines.human=false",
        "eval.workers=0",
        "progress=false",
    ]

    def evaluate() -> tuple[int, int]:
        calls.clear()
        with contextlib.redirect_stdout(io.StringIO()):
            assert evaluate_cli.main(argv) == 0
        return len(calls), len(record_lines(out, "exact_runs"))

    def figures() -> list[dict[str, str]]:  # the summary less its timings
        return [{k: v for k, v in r.items() if "seconds" not in k} for r in read(out / "summary.csv")]

    first = evaluate()
    assert first == (3, 3)  # NCA at S and S_eval, tiling at S_eval; an exact run on each
    summary = figures()
    assert len(record_lines(out, "repairs")) == 3
    assert evaluate() == (0, 3)
    assert figures() == summary
    (out / "repairs.jsonl.gz").unlink()  # as in a folder evaluated before repairs.jsonl
    assert evaluate() == (0, 3)
    assert len(record_lines(out, "repairs")) == 3
    (out / "repairs.jsonl.gz").unlink()
    broken = out / "layouts" / "nca_c3_13x18.json"
    data = json.loads(broken.read_text())
    data["layout"] = [row.replace("@", ".") for row in data["layout"]]  # no shelves left
    broken.write_text(json.dumps(data))
    assert evaluate()[0] == 1
    assert len(figures()) == len(summary)


def test_ctrl_c_during_the_screen_stops_the_exact_runs_at_once(monkeypatch):
    """The exact runs go on in a background thread while the main thread screens; Ctrl-C in
    the main thread aborts the backend (the runs stop now, not when they end) and re-raises."""
    import threading

    from nca_qd.evaluation import runs as runs_module
    from nca_qd.io import rows_to_array
    from nca_qd.layouts.warehouse import TILES

    class WaitsForAbort:
        def __init__(self):
            self.aborted = threading.Event()

        def describe(self):
            return "a backend that runs until aborted"

        def map(self, fn, *args, on_result=None):
            if not self.aborted.wait(30):
                raise AssertionError("never aborted")
            raise KeyboardInterrupt

        def abort(self):
            self.aborted.set()

    def screen_interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(runs_module, "screen_group", screen_interrupted)
    layout = rows_to_array(HUMAN_9x14, TILES)
    lay = ev.EvalLayout("human@9x14", "human", "human", "9x14", "train", layout)
    cells = {("human@9x14", 4): ev.Request("cell", "human@9x14", 4, 1, 1)}
    backend = WaitsForAbort()
    with pytest.raises(KeyboardInterrupt):
        runs_module.simulate_cells(
            cells,
            {lay.key: lay},
            "warehouse_even",
            TILES,
            20,
            0,
            backend,
            ExactSettings(20, None, 10, 5, {}),
            ev.ScreenSettings("all", 5, 17.0, None, True),
            progress=False,
        )
    assert backend.aborted.is_set()


@pytest.mark.usefixtures("ctrl_c_raises")
def test_a_signal_during_a_screened_batch_waits_until_its_runs_are_recorded(tmp_path, monkeypatch):
    """Ctrl-C (or SIGTERM, a campaign's deadline) arriving while a batch is screened stops the
    evaluation once the batch's runs are in the record file: the next call reuses them."""
    import os
    import signal

    from nca_qd.evaluation import runs as runs_module
    from nca_qd.evaluation.store import ScreenRunStore
    from nca_qd.io import rows_to_array
    from nca_qd.layouts.warehouse import TILES

    def batch_then_interrupted(group, *args, **kwargs):
        os.kill(os.getpid(), signal.SIGINT)  # arrives during the batch
        return [[RunOutcome("screen", s, 0.25, True, 20, False, 0.0) for s in range(2)] for _ in group]

    monkeypatch.setattr(runs_module, "screen_group", batch_then_interrupted)
    layout = rows_to_array(HUMAN_9x14, TILES)
    lay = ev.EvalLayout("human@9x14", "human", "human", "9x14", "train", layout)
    cells = {("human@9x14", 4): ev.Request("cell", "human@9x14", 4, 2, 0)}
    store = ScreenRunStore(tmp_path)
    args = (cells, {lay.key: lay}, "warehouse_even", TILES, 20, 0, None)
    settings = (ExactSettings(20, None, 10, 5, {}), ev.ScreenSettings("all", 5, 17.0, None, True))
    with pytest.raises(KeyboardInterrupt):
        runs_module.simulate_cells(*args, *settings, progress=False, screen_store=store)
    store.pack()
    monkeypatch.setattr(runs_module, "screen_group", lambda *a, **k: pytest.fail("screened again"))
    again = runs_module.simulate_cells(
        *args, *settings, progress=False, screen_store=ScreenRunStore(tmp_path)
    )
    assert [o.throughput for o in again[("human@9x14", 4, "screen")]] == [0.25, 0.25]


def test_another_folders_records_serve_identical_runs_and_are_copied_not_moved(tmp_path):
    """records_from: a run or repair recorded in another evaluation folder (another arm's: the
    same human layout at the same seed) serves this one; once used it is in this folder's own
    file (the folder stands alone), the other folder is not written, and what was not used is
    neither copied nor moved to this folder's superseded file."""
    from nca_qd.evaluation.store import ExactRunStore, RepairStore, ScreenRunStore
    from nca_qd.scoring.jobs import RepairOutcome

    other, here = tmp_path / "arm_a" / "evaluation", tmp_path / "arm_b" / "evaluation"
    tasks = np.arange(40, dtype=np.int32) % 3
    a = ExactRunStore(other)
    a.add("human@101x102 seed 0", RunOutcome("rhcr", 0, 0.3, False, 200, False, 90.0, None, tasks, None))
    a.add("nca of arm a", RunOutcome("rhcr", 0, 16.0, True, 5000, False, 150.0))
    a.pack()
    s = ScreenRunStore(other)
    s.add("human screened", RunOutcome("screen", 1, 0.2, False, 100, False, 0.1))
    s.pack()
    r = RepairStore(other)
    r.add("repair", RepairOutcome(np.zeros((3, 4), dtype=np.int32), "optimal", 0.9, 2, 0.1))
    r.pack()
    before = {p: p.read_bytes() for p in other.iterdir()}

    b = ExactRunStore(here, [other])
    assert len(b) == 0  # its own records: none yet
    got = b.get("human@101x102 seed 0", need_detail=True, need_visits=False)
    assert got is not None and (got.throughput, got.stop_time) == (0.3, 200)
    np.testing.assert_array_equal(got.tasks_per_step, tasks)
    assert b.get("not recorded anywhere", False) is None
    assert ScreenRunStore(here, [other]).get("human screened", False) is not None
    rep = RepairStore(here, [other]).get("repair")
    assert rep is not None and rep.hamming == 2
    assert b.prune() == 0  # only the record it used is in its file; nothing superseded
    assert [x["key"] for x in record_lines(here, "exact_runs")] == ["human@101x102 seed 0"]
    assert not (here / "exact_runs.superseded.jsonl").exists()
    assert {p: p.read_bytes() for p in other.iterdir()} == before
    alone = ExactRunStore(here)  # without records_from: the copy serves
    assert alone.get("human@101x102 seed 0", True, False) is not None


def test_records_from_must_name_folders(tmp_path):
    from nca_qd.evaluation.plan import records_from

    assert records_from(None) == [] and records_from([str(tmp_path)]) == [str(tmp_path)]
    with pytest.raises(NcaQdError, match="is not a folder"):
        records_from([str(tmp_path / "missing")])
    with pytest.raises(NcaQdError, match="must be a list"):
        records_from(str(tmp_path))
