"""DSAGE: the surrogate learns, the inner loop fills its archive, downsampling keeps one elite
per block, a tiny maze run ends and resumes to the same end, bad settings get one line."""

import csv

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import TINY_MAZE
from hypothesis import given, settings
from hypothesis import strategies as st

from experiments.cli import compose_config
from nca_qd.errors import NcaQdError
from nca_qd.experiment import Experiment
from nca_qd.qd.archive import ThresholdRepertoire, grid_cell_indices
from nca_qd.qd.dsage.surrogate import Surrogate, SurrogateConfig
from nca_qd.qd.dsage.tiles import downsample, make_inner_loop, mutate

SHAPE = (8, 8)


def _toy_targets(layouts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A known function of a binary 8x8 layout: objective = wall share, measures = walls in
    the top half and walls on the border; ancillary = the wall map itself."""
    walls = layouts.astype(np.float32)
    objective = walls.mean(axis=(1, 2))
    top = walls[:, :4].sum(axis=(1, 2))
    border = walls.sum(axis=(1, 2)) - walls[:, 1:-1, 1:-1].sum(axis=(1, 2))
    return np.stack([objective, top, border], axis=1), walls


def test_the_surrogate_learns_a_known_function_on_held_out_layouts():
    rng = np.random.default_rng(0)
    density = rng.uniform(0.1, 0.9, size=(1200, 1, 1))
    layouts = (rng.random((1200, *SHAPE)) < density).astype(np.int8)
    targets, anc = _toy_targets(layouts)
    cfg = SurrogateConfig(features=16, res_blocks=1, epochs=12, batch_size=64, sample_size=1000)
    model = Surrogate(SHAPE, 2, [0, 0, 0], [1, 32, 28], cfg)
    params, opt = model.init(jax.random.PRNGKey(0))
    train = slice(0, 1000)
    params, opt, loss = model.train(
        params, opt, layouts[train], targets[train], anc[train].astype(np.float16), seed=0
    )
    objective, measures = model.predict(params, jnp.asarray(layouts[1000:]))
    pred = np.concatenate([np.asarray(objective)[:, None], np.asarray(measures)], axis=1)
    truth = targets[1000:]
    err = np.abs(pred - truth).mean(axis=0)
    baseline = np.abs(truth - truth.mean(axis=0)).mean(axis=0)  # predicting the mean
    assert np.all(err < 0.35 * baseline), (err, baseline)
    assert np.isfinite(loss)


def _exact_predict(params, layouts):
    """A stand-in surrogate that is exact: objective 1 - wall share, measures = walls, walls
    in the left half."""
    walls = layouts.astype(jnp.float32)
    return 1.0 - walls.mean(axis=(1, 2)), jnp.stack(
        [walls.sum(axis=(1, 2)), walls[:, :, : SHAPE[1] // 2].sum(axis=(1, 2))], axis=1
    )


CELLS, RANGES = (16, 8), ((0, 64), (0, 32))


def test_the_inner_loop_fills_its_archive_with_consistent_elites():
    def run(iterations):
        inner = make_inner_loop(_exact_predict, SHAPE, 2, CELLS, RANGES, iterations, 2, 10, 20, 3)
        return inner(None, jax.random.PRNGKey(1))

    random_only, searched = run(1), run(40)
    assert int(jnp.sum(searched.occupied)) > 2 * int(jnp.sum(random_only.occupied))
    occ = np.asarray(searched.occupied)
    genotypes = np.asarray(searched.genotypes)[occ]
    assert np.array_equal(genotypes, np.rint(genotypes)) and genotypes.min() >= 0 and genotypes.max() <= 1
    # every elite sits in the cell of its own (exact) prediction, with its objective
    objective, measures = _exact_predict(None, jnp.asarray(genotypes.reshape(-1, *SHAPE)))
    cells = np.asarray(grid_cell_indices(measures, CELLS, RANGES))
    np.testing.assert_array_equal(cells, np.flatnonzero(occ))
    np.testing.assert_allclose(np.asarray(searched.fitnesses[occ, 0]), np.asarray(objective), rtol=1e-6)


@settings(max_examples=12, deadline=None)
@given(st.integers(0, 2**31 - 1), st.sampled_from([1, 10, 64]))
def test_a_mutation_changes_at_most_k_tiles_and_stays_in_the_alphabet(seed, k):
    parents = jnp.asarray(np.random.default_rng(seed).integers(0, 3, (6, 64)), jnp.float32)
    children = np.asarray(mutate(jax.random.PRNGKey(seed), parents, k, 3))
    changed = (children != np.asarray(parents)).sum(axis=1)
    assert np.all(changed <= k)
    assert set(np.unique(children)) <= {0.0, 1.0, 2.0}


_add = jax.jit(lambda a, g, m, f: a.add_with_info(g, m, f)[0])
_downsample = jax.jit(downsample, static_argnums=2)


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(0.0, 1.0))
def test_downsampling_keeps_one_elite_of_each_occupied_block(seed, share):
    rng = np.random.default_rng(seed)
    archive = ThresholdRepertoire.create(4, CELLS, RANGES)
    n = archive.fitnesses.shape[0]
    occupied = rng.random(n) < share
    grid = np.stack(np.unravel_index(np.arange(n), CELLS), axis=1).astype(np.float32)
    measures = (grid + 0.5) / np.asarray(CELLS) * np.asarray([r[1] for r in RANGES])
    # every cell gets a candidate (fixed shapes: one compile); unoccupied ones at -inf
    archive = _add(
        archive,
        jnp.asarray(np.repeat(np.arange(n)[:, None], 4, axis=1), jnp.float32),
        jnp.asarray(measures),
        jnp.asarray(np.where(occupied, rng.random(n), -np.inf), jnp.float32),
    )
    coarse = (4, 2)
    genotypes, objective, picked_measures, selected = _downsample(archive, jax.random.PRNGKey(seed), coarse)
    selected = np.asarray(selected)
    block_of = (grid // (np.asarray(CELLS) // np.asarray(coarse))).astype(int)
    block_id = block_of[:, 0] * coarse[1] + block_of[:, 1]
    expected = np.zeros(8, bool)
    expected[np.unique(block_id[occupied])] = True
    np.testing.assert_array_equal(selected, expected)
    picked = np.asarray(genotypes)[selected, 0].astype(int)  # the genotype names its cell
    assert occupied[picked].all()
    np.testing.assert_array_equal(block_id[picked], np.flatnonzero(selected))
    np.testing.assert_allclose(np.asarray(picked_measures)[selected], measures[picked], rtol=1e-6)


TINY_DSAGE = [
    *[a for a in TINY_MAZE if not a.startswith("qd.n_evals")],
    "algo=dsage",
    "domain.agent.kind=shortest_path",
    "algo.initial_solutions=20",
    "algo.inner.iterations=6",
    "algo.inner.emitters=2",
    "algo.inner.batch_size=8",
    "algo.inner.initial_population=8",
    "algo.surrogate.features=8",
    "algo.surrogate.res_blocks=1",
    "algo.surrogate.epochs=2",
    "domain.dsage.downsample=[8,6]",
    "output.pictures=false",
]


def _rows(run_dir):
    with open(run_dir / "metrics.csv") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.parametrize("resume_from", ["checkpoint", "snapshot"])
def test_a_tiny_dsage_run_ends_and_resumes_to_the_same_end(tmp_path, resume_from):
    """Resumed from the full checkpoint, or on a "fresh clone" from the portable snapshot
    alone (the checkpoint deleted), the run ends where the uninterrupted one ends."""
    whole = tmp_path / "whole"
    state = Experiment(compose_config("run", [*TINY_DSAGE, "qd.n_evals=90"]), whole).run()
    assert int(state.evaluations) == 90
    rows = _rows(whole)
    assert int(rows[0]["n_real"]) == 20 and sum(int(r["n_real"]) for r in rows) == 90
    assert all(0 < int(r["n_real"]) <= 48 for r in rows[1:])  # at most one per 8 x 6 block
    assert np.isfinite(float(rows[-1]["surrogate_loss"]))
    archive = np.load(whole / "archive_result.npz")
    assert archive["genotypes"].shape[1] == 256  # the layouts themselves
    assert np.array_equal(archive["genotypes"], np.rint(archive["genotypes"]))

    # interrupted after the second outer iteration (its budget ends there, nothing is cut)
    parts = tmp_path / "parts"
    first = int(rows[1]["evaluations"])
    snap = ["snapshot.enabled=true"] if resume_from == "snapshot" else []
    Experiment(compose_config("run", [*TINY_DSAGE, f"qd.n_evals={first}", *snap]), parts).run()
    assert (parts / "dsage_data.npz").is_file()
    if resume_from == "snapshot":
        (parts / "checkpoint.npz").unlink()
        assert (parts / "snapshot.npz").is_file()
    cfg = compose_config("run", [*TINY_DSAGE, "qd.n_evals=90", *snap])
    resumed = Experiment(cfg, parts).run(resume=True)
    assert int(resumed.evaluations) == 90
    for a, b in zip(_rows(whole), _rows(parts)):
        for col in ("evaluations", "qd_score", "coverage", "n_real", "surrogate_loss"):
            assert a[col] == b[col], (col, a[col], b[col])


@pytest.mark.parametrize(
    "extra,message",
    [
        (["domain.dsage.downsample=[7,6]"], "algo.downsample must give one divisor"),
        (["algo.inner.mutation_k=300"], "algo.inner.mutation_k must be at most 256"),
        (["algo.inner.iterations=-1"], "algo.inner.iterations must be a positive integer"),
    ],
)
def test_bad_dsage_settings_are_one_clear_error(extra, message, tmp_path):
    with pytest.raises(NcaQdError, match=message):
        Experiment(compose_config("run", [*TINY_DSAGE, "qd.n_evals=40", *extra]), tmp_path)


def test_a_dsage_layout_does_not_grow_to_the_evaluation_size():
    from nca_qd.domains import make_domain
    from nca_qd.pipeline import generate, make_generator

    cfg = compose_config("run", TINY_DSAGE)
    domain = make_domain(cfg.domain)
    gen = make_generator(domain, "dsage")
    region = generate(domain, gen, np.ones((1, 256), np.float32) * 1.4)
    assert region.shape == (1, 16, 16) and (region == 1).all()
    with pytest.raises(NcaQdError, match="cannot be generated at 64x64"):
        generate(domain, gen, np.zeros((1, 256), np.float32), "eval")


def test_the_maze_scorers_occupancy_map_counts_every_step_on_empty_tiles_only():
    from nca_qd.domains import make_domain

    cfg = compose_config("run", [*TINY_DSAGE, "domain.agent.kind=wall_follower"])
    domain = make_domain(cfg.domain)
    evaluator = domain.make_evaluator(cfg)
    rng = np.random.default_rng(0)
    regions = (rng.random((6, 16, 16)) < 0.3).astype(np.int32)
    regions[0] = 1  # no empty tile: nothing simulated
    ev = evaluator(jnp.asarray(regions), jax.random.PRNGKey(0))
    occupancy = np.asarray(ev.extras["ancillary"])
    lengths = np.asarray(ev.extras["episode_lengths"])
    assert occupancy.shape == (6, 16, 16)
    # one visit per action taken: per maze the visits add up to the mean episode length
    np.testing.assert_allclose(occupancy.sum(axis=(1, 2))[1:], lengths.mean(axis=1)[1:], rtol=1e-5)
    assert occupancy[0].sum() == 0
    assert (occupancy[regions == 1] == 0).all()


def test_the_warehouse_scorers_tile_usage_counts_every_robot_and_no_shelf(tmp_path):
    from test_scoring import TINY_WAREHOUSE

    from nca_qd.domains import make_domain
    from nca_qd.scoring.memo import MEMO_FILE, EvalMemo

    cfg = compose_config("run", [*TINY_WAREHOUSE, "algo=dsage", "eval.workers=0"])
    domain = make_domain(cfg.domain)
    scorer = domain.make_evaluator(cfg)
    regions = np.stack([domain.seed(domain.gen_shape("train"))] * 2)
    regions[1, 2:4, 3:8] = 1  # another layout: more shelves to repair around
    ev = scorer(regions, jax.random.PRNGKey(3))
    usage = np.asarray(ev.extras["ancillary"], float)
    repaired = np.asarray(ev.extras["repaired"])
    assert usage.shape == regions.shape and np.isfinite(usage).all()
    region = domain.layout.region(repaired)
    assert (usage[region == 1] == 0).all()  # nobody stands on a shelf
    # mean robots per step over the generated region: at most all 10, most of them
    assert np.all(usage.sum(axis=(1, 2)) <= 10 + 1e-6) and np.all(usage.sum(axis=(1, 2)) > 3)
    # remembered with the exact runs: a second call reuses them, maps included
    scorer.save_state(tmp_path)
    memo = EvalMemo.load(tmp_path / MEMO_FILE, scorer.fingerprint)
    scorer.memo = memo
    again = scorer(regions, jax.random.PRNGKey(3))
    assert again.extras["metrics"]["exact_runs"] == 0
    np.testing.assert_allclose(np.asarray(again.extras["ancillary"], float), usage, atol=2e-3)
    scorer.close()
