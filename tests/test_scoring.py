"""The multi-agent scoring pipeline: exact-run selection, one QD batch (repair -> screen ->
exact RHCR) checked against independent recomputation, the memo, and the two-phase score.
Backends: test_scoring_backend; runs end to end: test_scoring_runs."""

from __future__ import annotations

import jax
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scoring_helpers import TINY_WAREHOUSE

from experiments.cli import compose_config
from nca_qd.errors import NcaQdError
from nca_qd.scoring.mapf import choose_exact
from nca_qd.scoring.settings import ScoringConfig


# ------------------------------------------------------------------------ exact selection
def test_choose_exact_takes_empty_cells_and_likely_improvements_only():
    cfg = ScoringConfig(exact_margin=0.1, exact_random_share=0.0)
    predicted = np.array([1.0, 1.0, 5.0, 4.0, 3.0])
    elite = np.array([-np.inf, 2.0, 5.2, 5.0, -np.inf])
    valid = np.array([True, True, True, True, False])
    got = choose_exact(predicted, elite, valid, cfg, np.random.default_rng(0))
    # empty cell; 1.1 < 2; 5.5 >= 5.2; 4.4 < 5; invalid never
    assert got.tolist() == [True, False, True, False, False]
    every = choose_exact(predicted, elite, valid, ScoringConfig(exact="all"), np.random.default_rng(0))
    assert every.tolist() == valid.tolist()
    share = ScoringConfig(exact_margin=0.0, exact_random_share=0.5)
    n = 4000
    picked = choose_exact(np.zeros(n), np.ones(n), np.ones(n, bool), share, np.random.default_rng(1))
    assert 0.45 < picked.mean() < 0.55


def test_screen_batches_are_padded_to_powers_of_two():
    from nca_qd.scoring.mapf import screen_bucket

    assert [screen_bucket(n) for n in (1, 2, 3, 4, 5, 8, 9, 33, 50)] == [1, 2, 4, 4, 8, 8, 16, 64, 64]
    assert [screen_bucket(n, cap=50) for n in (5, 33, 50)] == [8, 50, 50]


def test_scoring_config_rejects_bad_values():
    with pytest.raises(NcaQdError, match="eval.exact must be one of"):
        ScoringConfig.from_cfg({"exact": "sometimes"})
    with pytest.raises(NcaQdError, match="exact_random_share"):
        ScoringConfig.from_cfg({"exact_random_share": 2})
    assert ScoringConfig.from_cfg({"screen": False}).exact == "all"
    with pytest.raises(NcaQdError, match="eval.screen_empty_cells must be true or false"):
        ScoringConfig.from_cfg({"screen_empty_cells": "maybe"})
    with pytest.raises(NcaQdError, match="eval.screen must be true or false"):
        ScoringConfig.from_cfg({"screen": 3})
    with pytest.raises(NcaQdError, match="eval.screen_estimate must be one of scaled, free_flow"):
        ScoringConfig.from_cfg({"screen_estimate": "guess"})
    with pytest.raises(NcaQdError, match="eval.screen_efficiency must be in"):
        ScoringConfig.from_cfg({"screen_efficiency": 1.5})
    assert ScoringConfig.from_cfg({"screen_empty_cells": True}).screen_empty_cells
    # the uneven warehouse's traffic has a screen calibrated for it (its domain config)
    uneven = compose_config("run", ["domain=warehouse_uneven"])
    assert uneven.domain.simulation.screen_crowd_mean == 21
    assert ScoringConfig.from_cfg(uneven.eval).screen_estimate == "scaled"
    assert compose_config("run", ["domain=warehouse_even"]).eval.screen_estimate == "free_flow"
    manufacturing = compose_config("run", ["domain=manufacturing"])  # likewise, its own
    assert manufacturing.domain.simulation.screen_crowd_mean == 22
    assert ScoringConfig.from_cfg(manufacturing.eval).screen_estimate == "scaled"
    # its jammed runs stop on a work bound; the warehouses' (whose comparison arms share one
    # planner) do not
    assert ScoringConfig.from_cfg(manufacturing.eval).planner["plan_max_expansions"] == 2_000_000
    for name in ("warehouse_even", "warehouse_uneven"):
        planner = ScoringConfig.from_cfg(compose_config("run", [f"domain={name}"]).eval).planner
        assert "plan_max_expansions" not in planner, name
    from nca_qd.sim.free_flow import CONGESTED_MODEL, CONGESTED_MODEL_V3

    assert ScoringConfig.from_cfg({}).screen_congested == CONGESTED_MODEL != CONGESTED_MODEL_V3
    for bad in ([1.0, 2.0], "0.4 4.5 -2.6", [0.4, float("nan"), 1.0], [0.4, "x", 1.0]):
        with pytest.raises(NcaQdError, match="eval.screen_congested must be three finite numbers"):
            ScoringConfig.from_cfg({"screen_congested": bad})


# ------------------------------------------------------------------------------ one batch
@pytest.fixture(scope="module")
def tiny_scorer():
    from nca_qd.domains import make_domain
    from nca_qd.pipeline import make_generator

    # No memo here: these tests score the same regions more than once and must see the
    # pipeline run each time (the memo has its own tests below).
    cfg = compose_config("run", TINY_WAREHOUSE + ["eval.workers=0", "eval.memo=false"])
    domain = make_domain(cfg.domain)
    gen = make_generator(domain)
    scorer = domain.make_evaluator(cfg)
    yield cfg, domain, gen, scorer
    scorer.close()


def _regions(domain, gen, b, seed):
    import jax

    sol = 0.3 * jax.random.normal(jax.random.PRNGKey(seed), (b, gen.n_params))
    return np.asarray(gen.generate(sol, domain.seed(domain.gen_shape("train")), 20))


@pytest.mark.parametrize("estimate", ["free_flow", "scaled"])
def test_batch_scores_match_independent_recomputation(tiny_scorer, estimate, monkeypatch):
    """Repaired layouts are valid (independent validator); exact throughputs equal direct RHCR
    runs with the same seeds; f_opt = f + alpha * Delta, where a layout without exact runs has
    f = the screen's prediction of RHCR (recomputed from direct screen runs with the same
    seeds); the result archive only gets layouts with exact runs; measures are those of the
    repaired layouts."""
    import dataclasses

    import jax

    from nca_qd.io import array_to_rows
    from nca_qd.repair import make_rules
    from nca_qd.repair.validator import check
    from nca_qd.scoring.mapf import ScoringContext, screen_bucket
    from nca_qd.sim.free_flow import free_flow_throughput
    from nca_qd.sim.rhcr import simulate
    from nca_qd.sim.scenario import build_scenario
    from nca_qd.sim.screen import simulate_scenarios

    cfg, domain, gen, scorer = tiny_scorer
    regions = _regions(domain, gen, 4, seed=1)
    key = jax.random.PRNGKey(7)
    # Cells 0.. are "occupied" by an unbeatable elite except where the measures fall in
    # the first entropy column: those cells are empty, so those layouts must get exact runs.
    ctx = ScoringContext(result_elite=lambda m: np.where(np.asarray(m)[:, 0] < 0.1, -np.inf, 1e9))
    saved = scorer.cfg
    # a congested-layout share of its own: the scorer must take eval.screen_congested
    scorer.cfg = dataclasses.replace(saved, screen_estimate=estimate, screen_congested=(0.2, 3.0, -1.0))
    import nca_qd.scoring.mapf as mapf

    shares = []  # the congested-layout share each estimate was made with (these layouts all flow)
    original = mapf.rhcr_estimate

    def recording_estimate(thr, ok, stop, flow, efficiency, congested):
        shares.append(congested)
        return original(thr, ok, stop, flow, efficiency, congested)

    monkeypatch.setattr(mapf, "rhcr_estimate", recording_estimate)
    import nca_qd.sim.screen as screen

    thresholds = []  # the crowding threshold of each screened batch: the domain's
    screen_batch = screen.simulate_scenarios

    def recording_screen(*args, **kwargs):
        thresholds.append(kwargs.get("crowd_mean"))
        return screen_batch(*args, **kwargs)

    monkeypatch.setattr(screen, "simulate_scenarios", recording_screen)
    try:
        efficiency = scorer.efficiency  # the prior: this scorer has seen < 50 flowing runs
        ev = scorer(regions, key, ctx)
    finally:
        scorer.cfg = saved
    assert efficiency == saved.screen_efficiency
    assert shares == ([(0.2, 3.0, -1.0)] if estimate == "free_flow" else [])
    assert thresholds == [17.0] == [scorer.crowd_mean]  # warehouse_even.yaml's screen_crowd_mean
    ex = ev.extras
    rules = make_rules("warehouse_even", ex["repaired"].shape[1:], n_shelves=20)
    seed0 = int(np.asarray(key, dtype=np.uint32).ravel()[-1] % np.uint32(2**31 - 1))
    # Direct screen runs of every screened layout in one batch, padded as the scorer pads its
    # batch (the results do not depend on the batch; the shape shares the scorer's compile).
    screened = [i for i in range(4) if not np.isnan(ex["screened"][i])]
    scens = {
        i: build_scenario(array_to_rows(ex["repaired"][i], domain.layout_tiles), "warehouse_even")
        for i in screened
    }
    batch = [scens[i] for i in screened]
    batch += batch[-1:] * (screen_bucket(len(batch)) - len(batch))
    direct_screen = dict(zip(screened, simulate_scenarios(batch, 10, 60, [seed0, seed0 + 1]), strict=False))
    for i in range(4):
        assert ev.valid[i], ex["repair_status"][i]
        assert check(ex["repaired"][i], rules) is None
        np.testing.assert_allclose(ev.measures[i], domain.measures(ex["repaired"][i][None])[0], rtol=1e-6)
        empty = ev.measures[i][0] < 0.1
        assert bool(ev.result_valid[i]) == (empty or not np.isnan(ex["exact"][i]))
        if not np.isnan(ex["exact"][i]):
            rows = array_to_rows(ex["repaired"][i], domain.layout_tiles)
            direct = np.mean(
                [simulate(rows, "warehouse_even", 10, 60, seed0 + s).throughput for s in range(2)]
            )
            assert ev.result_objective[i] == pytest.approx(direct, abs=1e-6)
            f = ex["exact"][i]
        else:
            runs = direct_screen[i]
            assert np.mean([r.throughput for r in runs]) == pytest.approx(ex["screened"][i], abs=1e-6)
            flow = free_flow_throughput(scens[i], 10)
            scaled = [saved.screen_scale * r.throughput for r in runs]
            if estimate == "free_flow":
                a, b, c = 0.2, 3.0, -1.0
                thr_ff = np.mean([r.throughput for r in runs]) / flow
                stop = np.mean([r.stop_time / 60 for r in runs])
                share = min(max(a + b * thr_ff + c * stop, 0.0), efficiency)
                f = flow * (efficiency if all(r.success for r in runs) else share)
            else:
                f = np.mean(scaled)
        assert ev.objective[i] == pytest.approx(f + 5.0 * ex["similarity"][i], rel=1e-5)
    m = ex["metrics"]
    assert m["n_exact"] == int(np.sum(~np.isnan(ex["exact"]))) and m["exact_runs"] == 2 * m["n_exact"]
    assert np.isnan(ex["exact"]).any(), "some layouts must be scored by the screen alone"
    assert (m["screen_efficiency"] == efficiency) == (estimate == "free_flow")


def test_empty_cells_skip_the_screen(tiny_scorer):
    """A layout whose result cell is empty goes exact whatever the screen says, so (with no
    random check share) it is not screened; occupied cells are screened; screen_empty_cells
    screens every layout."""
    import dataclasses

    import jax

    from nca_qd.scoring.mapf import ScoringContext

    _, domain, gen, scorer = tiny_scorer
    saved = scorer.cfg
    scorer.cfg = dataclasses.replace(saved, exact_random_share=0.0)
    try:
        regions = _regions(domain, gen, 4, seed=1)
        seen = {}

        def result_elite(m):
            """Cells below the batch's median first measure are empty, the others held by an
            unbeatable elite (the batch's own measures: no separate scoring pass needed)."""
            m = np.asarray(m)
            seen["empty"] = m[:, 0] < np.median(m[:, 0])
            return np.where(seen["empty"], -np.inf, 1e9)

        ev = scorer(regions, jax.random.PRNGKey(7), ScoringContext(result_elite=result_elite))
    finally:
        scorer.cfg = saved
    empty = seen["empty"]
    assert empty.any() and (~empty).any()
    np.testing.assert_array_equal(
        empty, np.asarray(ev.measures)[:, 0] < np.median(np.asarray(ev.measures)[:, 0])
    )
    ex = ev.extras
    assert np.isfinite(ex["exact"][empty]).all()  # empty cells: exact
    assert np.isfinite(ex["screened"][~empty]).all()  # occupied: screened ...
    assert np.isnan(ex["exact"][~empty]).all()  # ... and unbeatable: no exact
    assert np.isnan(ex["screened"][empty]).all()
    assert ev.valid.all() and (ev.result_valid == empty).all()
    # Which layouts the screen gets under the other settings (no simulation needed).
    valid = np.array([True, True, True, False])
    elite = np.array([-np.inf, 1.0, -np.inf, 1.0])
    rng = np.random.default_rng(0)
    for cfg, want in [
        (dict(exact_random_share=0.0), [False, True, False, False]),
        (dict(exact_random_share=1.0), [True, True, True, False]),
        (dict(screen_empty_cells=True), [True, True, True, False]),
        (dict(exact="all"), [True, True, True, False]),
        (dict(screen=False, exact="all"), [False, False, False, False]),
    ]:
        scorer.cfg = dataclasses.replace(saved, **cfg)
        try:
            assert scorer._to_screen(valid, elite, rng).tolist() == want, cfg
            # No result archive yet (every cell empty): nothing screened without a check share.
            if cfg.get("exact_random_share") == 0.0:
                assert not scorer._to_screen(valid, np.full(4, -np.inf), rng).any()
        finally:
            scorer.cfg = saved


def test_a_failed_repair_is_recorded_and_the_batch_goes_on(tiny_scorer):
    import jax

    _, domain, gen, scorer = tiny_scorer
    saved = scorer.repair_opts
    scorer.repair_opts = {**saved, "n_shelves": 10_000}  # impossible: more shelves than tiles
    try:
        ev = scorer(_regions(domain, gen, 3, seed=2), jax.random.PRNGKey(0))
    finally:
        scorer.repair_opts = saved
    assert not ev.valid.any() and not ev.result_valid.any()
    assert set(ev.extras["repair_status"]) <= {"infeasible", "no_solution", "error"}
    assert ev.extras["metrics"]["n_exact"] == 0


# ------------------------------------------------------------------------------ memo
@given(st.lists(st.sampled_from([b"a", b"b", b"c", b"d"]), max_size=20))
def test_first_of_each_indexes_every_key_by_its_first_copy(keys):
    from nca_qd.scoring.memo import first_of_each

    first, inverse = first_of_each(keys)
    assert [keys[i] for i in first] == list(dict.fromkeys(keys))  # distinct, in order
    assert [keys[first[j]] for j in inverse] == keys
    assert all(first[inverse[i]] <= i for i in range(len(keys)))


def test_layout_key_tells_layouts_apart_by_tiles_and_shape():
    from nca_qd.scoring.keys import layout_key

    a = np.zeros((4, 6), np.int32)
    b = a.copy()
    b[3, 5] = 1
    assert layout_key(a) == layout_key(a.astype(np.int8)) != layout_key(b)
    assert layout_key(a) != layout_key(a.reshape(6, 4))


def _memo_entries(memo):
    from nca_qd.scoring.jobs import RepairOutcome

    lay = np.arange(12, dtype=np.int32).reshape(3, 4) % 3
    memo.put_repair(b"\x00" * 20, RepairOutcome(lay, "repaired", 0.9, 2, 1.0), iteration=1)
    memo.put_repair(b"\x01" * 19 + b"\x00", RepairOutcome(None, "infeasible", 0.0, None, 1.0), 2)
    memo.put_repair(b"\x02" * 20, RepairOutcome(None, "error", 0.0, None, 1.0, "boom"), 2)
    memo.put_exact(b"\x03" * 20, np.array([5.0, 6.0]), iteration=1)
    memo.put_exact(b"\x04" * 20, np.array([5.0, 7.0]), iteration=3)
    memo.put_exact(b"\x05" * 20, np.array([5.0, np.nan]), iteration=1)
    return lay


def test_memo_survives_a_file_and_a_resume_drops_later_entries(tmp_path):
    from nca_qd.scoring.memo import EvalMemo

    memo = EvalMemo("settings A")
    lay = _memo_entries(memo)
    # errors and failed runs are not remembered: they may succeed when tried again
    assert memo.repair(b"\x02" * 20) is None and memo.exact(b"\x05" * 20) is None
    memo.save(tmp_path / "m.npz")
    back = EvalMemo.load(tmp_path / "m.npz", "settings A")
    rep = back.repair(b"\x00" * 20)  # digests ending in zero bytes keep them
    np.testing.assert_array_equal(rep.layout, lay)
    assert (rep.status, rep.similarity, rep.hamming) == ("repaired", 0.9, 2)
    none = back.repair(b"\x01" * 19 + b"\x00")
    assert none.layout is None and none.status == "infeasible" and none.hamming is None
    np.testing.assert_array_equal(back.exact(b"\x04" * 20), [5.0, 7.0])
    cut = EvalMemo.load(tmp_path / "m.npz", "settings A", upto_iteration=1)
    assert cut.repair(b"\x01" * 19 + b"\x00") is None and cut.exact(b"\x04" * 20) is None
    assert cut.exact(b"\x03" * 20) is not None and len(cut) == 2
    assert len(EvalMemo.load(tmp_path / "m.npz", "settings B")) == 0  # other settings: unused
    assert len(EvalMemo.load(tmp_path / "missing.npz", "settings A")) == 0
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    assert len(EvalMemo.load(tmp_path / "bad.npz", "settings A")) == 0


def test_free_flow_efficiency_is_calibrated_on_flowing_exact_runs_and_survives_a_resume(tmp_path):
    """The memo keeps each exact run's verdict and the layout's free flow; the scorer's
    efficiency is the mean share of the flowing runs once there are 50 of them (the prior
    before), counting only the entries up to a resumed checkpoint's iteration."""
    from nca_qd.domains import make_domain
    from nca_qd.scoring.mapf import MIN_CALIBRATION_RUNS
    from nca_qd.scoring.memo import MEMO_FILE, EvalMemo

    cfg = compose_config("run", TINY_WAREHOUSE + ["eval.workers=0", "eval.screen_efficiency=0.5"])
    scorer = make_domain(cfg.domain).make_evaluator(cfg)
    try:
        memo = EvalMemo(scorer.memo.fingerprint)
        for i in range(30):  # 30 flowing runs at 0.9 of free flow, 30 congested ones
            memo.put_exact(bytes([1, i]) * 10, np.array([9.0, 3.0]), 1, success=[True, False], free_flow=10.0)
        for i in range(20):  # 40 flowing runs at 0.8, later
            memo.put_exact(bytes([2, i]) * 10, np.array([8.0, 8.0]), 5, success=[True, True], free_flow=10.0)
        memo.put_exact(b"\x07" * 20, np.array([1.0, 1.0]), 1)  # no verdicts recorded: not counted
        memo.save(tmp_path / MEMO_FILE)
        assert MIN_CALIBRATION_RUNS == 50
        scorer.restore_state(tmp_path, iteration=4)
        assert scorer.memo.flowing_shares().size == 30 and scorer.efficiency == 0.5
        scorer.restore_state(tmp_path, iteration=5)
        np.testing.assert_allclose(np.sort(scorer.memo.flowing_shares()), [0.8] * 40 + [0.9] * 30)
        assert scorer.efficiency == pytest.approx((30 * 0.9 + 40 * 0.8) / 70)
        assert len(scorer.memo.to_arrays()["exact_success"]) == 51
    finally:
        scorer.close()


def test_results_of_another_planner_are_never_reused(tiny_scorer, tmp_path):
    """The memo's fingerprint names the exact simulator's version: a memo written under
    another version is not loaded."""
    import json

    from nca_qd.scoring.memo import EvalMemo
    from nca_qd.sim.rhcr import VERSION

    scorer = tiny_scorer[3]
    settings = json.loads(scorer.fingerprint)
    assert settings["rhcr_version"] == VERSION
    old = EvalMemo(json.dumps({**settings, "rhcr_version": VERSION - 1}, sort_keys=True))
    _memo_entries(old)
    old.save(tmp_path / "m.npz")
    assert EvalMemo.load(tmp_path / "m.npz", scorer.fingerprint).exact(b"\x03" * 20) is None
    assert EvalMemo.load(tmp_path / "m.npz", old.fingerprint).exact(b"\x03" * 20) is not None


def test_memo_repairs_and_simulates_each_distinct_layout_once(tiny_scorer):
    """Copies in one batch share one repair and one set of exact runs; a later batch takes
    remembered results without any job; each copy scores exactly as its original."""
    import jax

    from nca_qd.scoring.mapf import ScoringContext
    from nca_qd.scoring.memo import EvalMemo

    _, domain, gen, scorer = tiny_scorer
    calls = {"repair": [], "exact": []}
    repair, exact = scorer.repair, scorer._exact_runs

    def count_repair(layouts):
        calls["repair"].append(len(layouts))
        return repair(layouts)

    def count_exact(rows, seeds):
        calls["exact"].append(len(rows))
        return exact(rows, seeds)

    base = _regions(domain, gen, 2, seed=3)
    regions = np.concatenate([base, base[::-1]])  # 4 layouts, 2 distinct
    empty = ScoringContext(result_elite=lambda m: np.full(len(m), -np.inf), iteration=1)
    scorer.memo, scorer.repair, scorer._exact_runs = EvalMemo("test"), count_repair, count_exact
    try:
        ev = scorer(regions, jax.random.PRNGKey(7), empty)
        m = ev.extras["metrics"]
        assert ev.valid.all(), ev.extras["repair_status"]
        assert calls == {"repair": [2], "exact": [2]}
        assert (m["repair_reused"], m["exact_reused"], m["exact_runs"]) == (2, 2, 2 * scorer.n_runs)
        for i, j in ((0, 3), (1, 2)):
            np.testing.assert_array_equal(ev.extras["repaired"][i], ev.extras["repaired"][j])
            assert ev.objective[i] == ev.objective[j]
            assert ev.result_objective[i] == ev.result_objective[j]
        # a later batch, other seeds: every result is remembered, no job runs
        again = scorer(
            regions,
            jax.random.PRNGKey(8),
            ScoringContext(result_elite=lambda m: np.full(len(m), 1e9), iteration=2),
        )
        assert calls == {"repair": [2], "exact": [2]}
        np.testing.assert_array_equal(again.objective, ev.objective)
        np.testing.assert_array_equal(again.result_objective, ev.result_objective)
        assert again.result_valid.all() and np.isnan(again.extras["screened"]).all()
        m2 = again.extras["metrics"]
        assert (m2["repair_reused"], m2["exact_reused"], m2["exact_runs"]) == (4, 4, 0)
    finally:
        scorer.memo, scorer.repair, scorer._exact_runs = None, repair, exact


def _scorer(extra):
    from nca_qd.domains import make_domain

    cfg = compose_config("run", TINY_WAREHOUSE + ["eval.workers=0", *extra])
    domain = make_domain(cfg.domain)
    return domain, domain.make_evaluator(cfg)


def test_two_phases_give_each_generator_the_lower_of_its_phases_scores():
    """eval.phases=2: each generator is scored by its layouts at C and C + 1 and gets the
    lower objective; its measures are its C layout's. Checked against the one-phase scorer on
    the same layouts and key (each exact, so both score every layout the same way)."""
    domain, two = _scorer(["eval.phases=2", "eval.exact=all"])
    _, one = _scorer(["eval.exact=all"])
    try:
        rng = np.random.default_rng(3)
        h, w = domain.gen_shape("train")
        regions = rng.integers(0, domain.n_tiles, (3, 2, h, w))
        regions[0, 1] = regions[0, 0]  # a generator that settled: both phases alike
        key = jax.random.PRNGKey(7)
        ev2 = two(regions, key)
        ev1 = one(regions.reshape(6, h, w), key)
        f1 = np.asarray(ev1.objective).reshape(3, 2)
        ok1 = np.asarray(ev1.valid).reshape(3, 2)
        np.testing.assert_array_equal(ev2.valid, ok1.all(1))
        want = np.where(ok1.all(1), f1.min(1), 0.0)
        np.testing.assert_allclose(ev2.objective, want, rtol=1e-6)
        np.testing.assert_allclose(
            ev2.result_objective,
            np.where(
                np.asarray(ev1.result_valid).reshape(3, 2).all(1),
                np.asarray(ev1.result_objective).reshape(3, 2).min(1),
                0.0,
            ),
            rtol=1e-6,
        )
        np.testing.assert_array_equal(ev2.measures, np.asarray(ev1.measures)[::2])
        np.testing.assert_allclose(ev2.extras["phase_objective"], f1, rtol=1e-6)
        assert len(ev2.extras["repair_status"]) == 3 and np.shape(ev2.extras["repaired"])[0] == 3
        assert ev2.valid[0] and ev2.objective[0] == pytest.approx(f1[0, 0])  # settled: as one phase
        with pytest.raises(ValueError, match="eval.phases is 2"):
            two(regions[:, 0], key)
    finally:
        two.close()
        one.close()


def test_a_two_phase_search_scores_the_layouts_at_c_and_c_plus_1(tmp_path, monkeypatch):
    """The objective grows each generator's layouts at C and C + 1 (the NCA's own trajectory)."""
    from nca_qd.domains import make_domain
    from nca_qd.pipeline import make_generator, make_objective

    cfg = compose_config("run", TINY_WAREHOUSE + ["eval.workers=0", "eval.phases=2"])
    domain = make_domain(cfg.domain)
    generator = make_generator(domain)
    objective = make_objective(domain, generator, cfg)
    seen = []
    monkeypatch.setattr(objective, "evaluator", lambda regions, key, context=None: seen.append(regions))
    objective.metric_names = ()  # (hand the regions straight to the stand-in scorer)
    genomes = np.asarray(jax.random.normal(jax.random.PRNGKey(0), (2, generator.n_params))) * 0.5
    objective(genomes, jax.random.PRNGKey(1))
    seed, c = domain.seed(domain.gen_shape("train")), domain.nca_iters("train")
    np.testing.assert_array_equal(seen[0][:, 0], np.asarray(generator.generate(genomes, seed, c)))
    np.testing.assert_array_equal(seen[0][:, 1], np.asarray(generator.generate(genomes, seed, c + 1)))
