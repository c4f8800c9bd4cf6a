"""Environment entropy on hand-built layouts, and the wall count."""

import math

import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from nca_qd.measures import batch_entropy, entropy, tile_count


def test_uniform_layout_has_zero_entropy():
    assert float(entropy(jnp.zeros((6, 7), jnp.int32), 2)) == 0.0
    assert float(entropy(jnp.full((5, 5), 2, jnp.int32), 3)) == 0.0


def test_known_mixture_matches_hand_computation():
    # 2x3 layout, K=2: two 2x2 windows, [[0,1],[0,1]] and [[1,0],[1,0]] -> two patterns, p=1/2 each.
    layout = jnp.array([[0, 1, 0], [0, 1, 0]], jnp.int32)
    expected = -(2 * 0.5 * math.log(0.5)) / math.log(2**4)  # = log 2 / log 16 = 0.25
    assert abs(float(entropy(layout, 2)) - expected) < 1e-6
    assert abs(expected - 0.25) < 1e-12


def test_three_patterns_with_unequal_counts():
    # 2x4 layout, K=3: windows [[0,0],[0,0]], [[0,2],[0,2]], [[2,0],[2,0]] -> p = 1/3 each.
    layout = jnp.array([[0, 0, 2, 0], [0, 0, 2, 0]], jnp.int32)
    expected = math.log(3) / math.log(3**4)
    assert abs(float(entropy(layout, 3)) - expected) < 1e-6


@settings(max_examples=25, deadline=None)
@given(st.integers(2, 5), st.integers(2, 8), st.integers(2, 8), st.integers(0, 10_000))
def test_entropy_is_in_unit_interval(k, h, w, seed):
    layout = np.random.default_rng(seed).integers(0, k, size=(h, w))
    value = float(entropy(jnp.asarray(layout), k))
    assert -1e-6 <= value <= 1 + 1e-6


def test_batch_entropy_and_tile_count():
    layouts = jnp.stack([jnp.zeros((4, 4), jnp.int32), jnp.eye(4, dtype=jnp.int32)])
    np.testing.assert_allclose(np.asarray(tile_count(layouts, 1)), [0, 4])
    ent = np.asarray(batch_entropy(layouts, 2))
    assert ent[0] == 0 and ent[1] > 0
