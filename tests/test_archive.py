"""The CMA-MAE threshold archive: hand-computed updates and agreement with pyribs."""

import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nca_qd.qd.archive import ThresholdRepertoire, archive_stats, grid_cell_indices

CELLS, RANGES = (4, 4), ((0.0, 1.0), (0.0, 1.0))


def _archive(lr=0.5, tmin=0.0, dim=2):
    return ThresholdRepertoire.create(dim, CELLS, RANGES, lr, tmin)


def test_threshold_update_on_a_hand_computed_example():
    a = _archive(lr=0.5, tmin=0.0)
    m = jnp.array([[0.1, 0.1]] * 3)  # all three land in cell 0
    sol = jnp.arange(6.0).reshape(3, 2)
    a, info = a.add_with_info(sol, m, jnp.array([1.0, 3.0, -1.0]))
    # two beat threshold_min=0: t = 0.5^2 * 0 + (1 - 0.5^2) * mean(1, 3) = 1.5
    assert float(a.thresholds[0]) == pytest.approx(1.5)
    np.testing.assert_array_equal(np.asarray(info.status), [2, 2, 0])
    np.testing.assert_allclose(np.asarray(info.value), [1.0, 3.0, -1.0])
    assert float(a.fitnesses[0, 0]) == 3.0 and np.allclose(a.genotypes[0], [2.0, 3.0])
    # next batch: 2.0 beats t=1.5 (but not the occupant 3.0) and still replaces it
    a, info = a.add_with_info(jnp.ones((1, 2)), m[:1], jnp.array([2.0]))
    assert int(info.status[0]) == 1 and float(info.value[0]) == pytest.approx(0.5)
    assert float(a.thresholds[0]) == pytest.approx(0.5 * 1.5 + 0.5 * 2.0)
    assert float(a.fitnesses[0, 0]) == 2.0


def test_plain_archive_keeps_the_best():
    a = _archive(lr=1.0, tmin=-np.inf)
    m = jnp.array([[0.9, 0.9]] * 2)
    a, info = a.add_with_info(jnp.zeros((2, 2)), m, jnp.array([5.0, 7.0]))
    a, info2 = a.add_with_info(jnp.zeros((1, 2)), m[:1], jnp.array([6.0]))
    assert float(a.fitnesses[15, 0]) == 7.0 and int(info2.status[0]) == 0
    stats = archive_stats(a, offset=0.0)
    assert float(stats["qd_score"]) == 7.0 and float(stats["coverage"]) == 1 / 16


def test_out_of_range_measures_land_in_border_cells():
    cells = np.asarray(grid_cell_indices(jnp.array([[-5.0, 0.5], [2.0, 2.0]]), CELLS, RANGES))
    np.testing.assert_array_equal(cells, [0 * 4 + 2, 15])


@pytest.mark.parametrize(
    "cells, ranges, values",
    [
        ((100, 100), ((0.0, 1.0), (140.0, 240.0)), np.arange(140, 240)),  # warehouse shelf components
        ((100, 100), ((0.0, 1.0), (0.0, 600.0)), np.arange(0, 600)),  # manufacturing workstations
        ((256, 162), ((0.0, 256.0), (0.0, 648.0)), np.arange(0, 648)),  # maze path length
    ],
)
def test_integer_measures_land_in_the_cell_whose_lower_edge_they_sit_on(cells, ranges, values):
    lo, hi = ranges[1]
    m = jnp.stack([jnp.full(values.size, 0.5), jnp.asarray(values, jnp.float32)], axis=1)
    got = np.asarray(grid_cell_indices(m, cells, ranges)) % cells[1]
    # integer arithmetic, no rounding: the cell of v is floor((v - lo) * n / (hi - lo))
    want = ((values - int(lo)) * cells[1]) // int(hi - lo)
    np.testing.assert_array_equal(got, want)
    ribs_archives = pytest.importorskip("ribs.archives")
    ribs = ribs_archives.GridArchive(solution_dim=1, dims=list(cells), ranges=list(ranges))
    np.testing.assert_array_equal(np.asarray(ribs.int_to_grid_index(ribs.index_of(m)))[:, 1], want)


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 10_000), st.sampled_from([0.01, 0.3, 1.0]), st.sampled_from([0.0, -np.inf]))
def test_matches_pyribs_grid_archive_on_identical_batches(seed, lr, tmin):
    ribs_archives = pytest.importorskip("ribs.archives")
    if tmin == -np.inf and lr != 1.0:
        lr = 1.0  # pyribs requires learning_rate=1 without threshold_min
    rng = np.random.default_rng(seed)
    ref = ribs_archives.GridArchive(
        solution_dim=2, dims=list(CELLS), ranges=list(RANGES), learning_rate=lr, threshold_min=tmin
    )
    ours = _archive(lr=lr, tmin=tmin)
    for _ in range(4):
        b = 12
        sol = rng.normal(size=(b, 2)).astype(np.float32)
        # few distinct measure points so that cells receive several solutions per batch
        meas = rng.choice(np.linspace(0.05, 0.95, 5), size=(b, 2)).astype(np.float32)
        obj = rng.normal(size=b).astype(np.float32)
        info_ref = ref.add(sol, obj, meas)
        ours, info = ours.add_with_info(jnp.asarray(sol), jnp.asarray(meas), jnp.asarray(obj))
        np.testing.assert_array_equal(np.asarray(info.status), info_ref["status"])
        np.testing.assert_allclose(np.asarray(info.value), info_ref["value"], rtol=1e-5, atol=1e-5)
    data = ref.data()
    occ = np.asarray(ours.occupied)
    assert sorted(np.flatnonzero(occ)) == sorted(data["index"].tolist())
    order = np.argsort(data["index"])
    idx = data["index"][order]
    np.testing.assert_allclose(np.asarray(ours.fitnesses[idx, 0]), data["objective"][order], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(ours.genotypes[idx]), data["solution"][order], rtol=1e-6)
    if tmin != -np.inf:
        np.testing.assert_allclose(
            np.asarray(ours.thresholds[idx]), data["threshold"][order], rtol=1e-5, atol=1e-6
        )
