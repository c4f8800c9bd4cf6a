"""The NCA generator: parameter counts, size invariance, batched == one at a time."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nca_qd.nca import NCAGenerator


@pytest.mark.parametrize("n_tiles,expected", [(2, 1730), (3, 2051), (5, 2693)])
def test_parameter_counts_match_the_paper(n_tiles, expected):
    assert NCAGenerator(n_tiles).n_params == expected


def _params(gen, b, key=0):
    return 0.2 * jax.random.normal(jax.random.PRNGKey(key), (b, gen.n_params))


def test_same_weights_generate_any_size():
    gen = NCAGenerator(3)
    params = _params(gen, 2)
    for shape in [(5, 7), (16, 16), (33, 32)]:
        seed = np.zeros(shape, np.int32)
        seed[shape[0] // 2, shape[1] // 2] = 1
        out = np.asarray(gen.generate(params, seed, 10))
        assert out.shape == (2, *shape)
        assert out.min() >= 0 and out.max() < 3


@pytest.mark.parametrize("n_tiles", [2, 5])
def test_batched_generation_equals_one_generator_at_a_time(n_tiles):
    """The batched matmul path against the Flax module applied to each generator alone."""
    gen = NCAGenerator(n_tiles)
    params = _params(gen, 5, key=3)
    seed = np.zeros((16, 13), np.int32)
    seed[7:9, 6:8] = 1
    batch = np.asarray(gen.generate(params, seed, 20))
    for i in range(5):
        probs = gen.rollout_probs(params[i], jnp.asarray(seed), 20)
        np.testing.assert_array_equal(batch[i], np.asarray(jnp.argmax(probs, -1)))
        single = np.asarray(gen.generate(params[i : i + 1], seed, 20))[0]
        np.testing.assert_array_equal(batch[i], single)


def test_generation_is_the_argmax_of_the_fed_back_continuous_state():
    """C steps fed back without re-one-hot, then argmax (checked against a manual rollout)."""
    gen = NCAGenerator(2)
    flat = _params(gen, 1, key=7)[0]
    seed = np.zeros((6, 6), np.int32)
    seed[2:4, 2:4] = 1
    x = jax.nn.one_hot(seed, 2)[None]
    variables = gen.unflatten(flat)
    for _ in range(4):
        x = gen.module.apply(variables, x)
    expected = np.asarray(jnp.argmax(x[0], -1))
    np.testing.assert_array_equal(np.asarray(gen.generate(flat[None], seed, 4))[0], expected)


def test_wrong_parameter_width_is_rejected():
    gen = NCAGenerator(2)
    with pytest.raises(AssertionError):
        gen.generate(jnp.zeros((2, 10)), np.zeros((4, 4), np.int32), 2)
