"""experiments.evaluate's records: each keys on every input of what it holds, packs narrow, serves
identical runs (also from another folder), survives Ctrl-C and signals; a failed repair is a row
without runs."""

from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import pytest
from evaluate_helpers import SCREEN_ONLY, TINY_RUN, HUMAN_9x14, load_map_rows, make_run, read, record_lines

from experiments import evaluate as evaluate_cli
from nca_qd import evaluation as ev
from nca_qd.errors import NcaQdError
from nca_qd.scoring.jobs import ExactSettings, RunOutcome


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
                    *SCREEN_ONLY,
                    "runs.train=2",
                    "runs.eval=2",
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


def test_a_reused_record_is_named_by_the_file_it_was_read_from(tmp_path):
    """The log line of reused runs names the folder a record came from: another arm's
    (records_from), this folder's superseded file or its own, with counts when they differ, not
    this folder's file for every one (it is only copied there)."""
    from nca_qd.evaluation.store import ExactRunStore

    other, here = tmp_path / "arm_a" / "evaluation", tmp_path / "arm_b" / "evaluation"
    a = ExactRunStore(other)
    for k in ("h0", "h1"):
        a.add(k, RunOutcome("rhcr", 0, 0.3, False, 200, False, 1.0))
    a.pack()
    first = ExactRunStore(here)
    for k in ("mine", "old"):
        first.add(k, RunOutcome("rhcr", 0, 16.0, True, 5000, False, 1.0))
    first.pack()
    own = ExactRunStore(here)
    assert own.get("mine", False) is not None
    assert own.prune() == 1  # "old" was not used: it moves to the superseded file

    b = ExactRunStore(here, [other])
    for k in ("h0", "h1", "mine", "old"):
        assert b.get(k, False) is not None
    theirs, mine = str(other / "exact_runs.jsonl"), str(here / "exact_runs.jsonl")
    assert b.sources(["h0", "h1"]) == theirs
    assert b.sources(["mine"]) == mine
    assert b.sources(["old"]) == str(here / "exact_runs.superseded.jsonl")
    assert b.sources(["h0", "mine", "h1"]) == f"{theirs} (2), {mine} (1)"
    # copied into this folder's file, the record still names where it was read from
    assert "h0" in {x["key"] for x in record_lines(here, "exact_runs")}
    assert b.sources(["h0"]) == theirs


def test_records_from_must_name_folders(tmp_path):
    from nca_qd.evaluation.plan import records_from

    assert records_from(None) == [] and records_from([str(tmp_path)]) == [str(tmp_path)]
    with pytest.raises(NcaQdError, match="is not a folder"):
        records_from([str(tmp_path / "missing")])
    with pytest.raises(NcaQdError, match="must be a list"):
        records_from(str(tmp_path))
