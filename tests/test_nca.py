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


def _numpy_nca(kernels: list[np.ndarray], biases: list[np.ndarray], seed: np.ndarray, n_iters: int):
    """The paper's MazeNCA restated in numpy (``env_search/maze/generator/nca_generator.py``:
    3x3 conv with zero padding, ReLU, 1x1, ReLU, 1x1, sigmoid; the continuous state fed back;
    argmax over channels, ties to the lower index), looping over the 3x3 offsets by hand so that
    nothing of the code under test (matmul path, Flax conv) is reused. Kernels are
    ``[kh, kw, in, out]``."""
    n = kernels[0].shape[2]
    h, w = seed.shape
    s = np.eye(n)[seed]  # [H, W, n]
    for _ in range(n_iters):
        p = np.pad(s, ((1, 1), (1, 1), (0, 0)))
        z = sum(p[dy : dy + h, dx : dx + w] @ kernels[0][dy, dx] for dy in range(3) for dx in range(3))
        z = np.maximum(z + biases[0], 0.0)
        z = np.maximum(z @ kernels[1][0, 0] + biases[1], 0.0)
        s = 1.0 / (1.0 + np.exp(-(z @ kernels[2][0, 0] + biases[2])))
    return np.argmax(s, axis=-1)


def test_generation_matches_an_independent_numpy_nca():
    """Independent checker: the paper's architecture in float64 numpy gives the same layouts as
    the jitted batch, on a non-square seed with border cells (zero padding) in play."""
    gen = NCAGenerator(2)
    params = _params(gen, 4, key=11)
    seed = np.zeros((9, 12), np.int32)
    seed[4:6, 5:7] = 1
    batch = np.asarray(gen.generate(params, seed, 12))
    for i in range(4):
        p = gen.unflatten(params[i])["params"]
        names = ("conv3x3", "conv1x1_a", "conv1x1_b")
        kernels = [np.asarray(p[k]["kernel"], np.float64) for k in names]
        biases = [np.asarray(p[k]["bias"], np.float64) for k in names]
        np.testing.assert_array_equal(batch[i], _numpy_nca(kernels, biases, seed, 12))


def test_near_zero_generators_draw_uniform_mazes():
    """Why MAP-Elites from the paper's start (x0 = 0, sigma_iso = 0.01) spends a seed-dependent
    share of its budget on near-uniform mazes (results/maze_qd/README.md): at that scale the
    biases of the last layer outweigh every spatial term, so each generator draws an all-floor
    or an all-wall maze; at sigma 0.2 most do not."""
    gen = NCAGenerator(2)
    seed = np.zeros((16, 16), np.int32)
    seed[7:9, 7:9] = 1
    for sigma, most_uniform in ((0.01, True), (0.2, False)):
        params = sigma * jax.random.normal(jax.random.PRNGKey(5), (64, gen.n_params))
        walls = np.asarray(gen.generate(params, seed, 50)).reshape(64, -1).sum(1)
        uniform = int(((walls == 0) | (walls == 256)).sum())
        assert (uniform == 64) if most_uniform else (uniform < 48), (sigma, uniform)
