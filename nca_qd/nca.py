"""Neural cellular automaton (NCA) generators, batched over a whole CMA-MAE batch.

Architecture as the paper's public code has it (its text says three 3x3 layers; the code and the
paper's parameter counts say otherwise): one-hot input with ``n`` tile types; Conv 3x3 (n->32) +
ReLU, Conv 1x1 (32->32) + ReLU, Conv 1x1 (32->n) + sigmoid; zero padding. The continuous output
is fed back as the next input with no re-one-hot in between; after ``C`` iterations the
environment is the argmax over channels. Parameter counts: n=2: 1,730; n=3: 2,051; n=5: 2,693.
Being fully convolutional, the same weights generate any ``H x W``.

Search algorithms work on flat parameter vectors ``[d]``; :class:`NCAGenerator` converts with
``ravel_pytree`` and vmaps generation over a batch ``[b, d]`` in one jitted call.
"""

from __future__ import annotations

import chex
import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree


class NCA(nn.Module):
    """One NCA update step on a ``[H, W, n]`` (or batched ``[..., H, W, n]``) tile-probability map."""

    n_tiles: int
    hidden: int = 32

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        x = nn.relu(nn.Conv(self.hidden, (3, 3), padding="SAME", name="conv3x3")(x))
        x = nn.relu(nn.Conv(self.hidden, (1, 1), name="conv1x1_a")(x))
        return nn.sigmoid(nn.Conv(self.n_tiles, (1, 1), name="conv1x1_b")(x))


class NCAGenerator:
    """Turns flat parameter vectors into environments.

    >>> gen = NCAGenerator(n_tiles=2)
    >>> gen.n_params
    1730
    """

    def __init__(self, n_tiles: int, hidden: int = 32):
        self.n_tiles = n_tiles
        self.module = NCA(n_tiles=n_tiles, hidden=hidden)
        # Only the parameters' shapes are needed here: abstract evaluation, not Flax's init, which
        # would run (and compile) every initialiser op by op in every process (docs/benchmarks.md).
        shapes = jax.eval_shape(self.module.init, jax.random.PRNGKey(0), jnp.zeros((1, 3, 3, n_tiles)))
        template = jax.tree.map(lambda s: np.zeros(s.shape, s.dtype), shapes)
        flat, self._unravel = ravel_pytree(template)
        self.n_params = int(flat.shape[0])
        self._generate = jax.jit(self._generate_impl, static_argnames=("n_iters",))
        self._trajectory = jax.jit(self._trajectory_impl, static_argnames=("n_iters", "extra"))

    def unflatten(self, flat: jax.Array):
        """Flat ``[d]`` vector -> Flax params pytree."""
        return self._unravel(flat)

    def init_flat(self, key: jax.Array) -> jax.Array:
        """Flax's default initialisation, flattened (useful for tests and random generators)."""
        params = self.module.init(key, jnp.zeros((1, 3, 3, self.n_tiles)))
        return ravel_pytree(params)[0]

    def rollout_probs(self, flat: jax.Array, seed: jax.Array, n_iters: int) -> jax.Array:
        """Continuous NCA state ``[H, W, n]`` after ``n_iters`` steps from the int ``seed`` ``[H, W]``."""
        params = self.unflatten(flat)
        x0 = jax.nn.one_hot(seed, self.n_tiles, dtype=jnp.float32)[None]

        def step(x, _):
            return self.module.apply(params, x), None

        x, _ = jax.lax.scan(step, x0, None, length=n_iters)
        return x[0]

    def _step_fn(self, flat_batch: jax.Array, shape: tuple[int, int]):
        """One NCA step of every member on a channels-first ``[b, n, H, W]`` state.

        Written as batched matmuls rather than a vmapped Flax conv, which XLA's CPU backend
        runs as a grouped convolution about 3x slower (docs/benchmarks.md);
        ``tests/test_nca.py`` checks both paths agree."""
        params = jax.vmap(self.unflatten)(flat_batch)["params"]
        b, n = flat_batch.shape[0], self.n_tiles
        h, w = shape

        def weights(name: str) -> tuple[jax.Array, jax.Array]:
            kernel = params[name]["kernel"]  # [b, kh, kw, in, out]
            mat = kernel.reshape(b, -1, kernel.shape[-1])  # rows ordered (dy, dx, in)
            return jnp.swapaxes(mat, 1, 2), params[name]["bias"][:, :, None]

        (w1, b1), (w2, b2), (w3, b3) = (weights(k) for k in ("conv3x3", "conv1x1_a", "conv1x1_b"))

        def step(x):
            xp = jnp.pad(x, ((0, 0), (0, 0), (1, 1), (1, 1)))  # zero padding, as the conv's SAME
            patches = jnp.concatenate(
                [xp[:, :, dy : dy + h, dx : dx + w] for dy in range(3) for dx in range(3)], axis=1
            ).reshape(b, 9 * n, h * w)
            z = jax.nn.relu(jnp.einsum("bok,bkp->bop", w1, patches) + b1)
            z = jax.nn.relu(jnp.einsum("bok,bkp->bop", w2, z) + b2)
            out = jax.nn.sigmoid(jnp.einsum("bok,bkp->bop", w3, z) + b3)
            return out.reshape(b, n, h, w)

        return step

    def _x0(self, b: int, seed: jax.Array) -> jax.Array:
        x0 = jnp.moveaxis(jax.nn.one_hot(seed, self.n_tiles, dtype=jnp.float32), -1, 0)
        return jnp.broadcast_to(x0, (b, self.n_tiles, *seed.shape))

    def _generate_impl(self, flat_batch: jax.Array, seed: jax.Array, n_iters: int) -> jax.Array:
        step = self._step_fn(flat_batch, seed.shape)
        x, _ = jax.lax.scan(
            lambda x, _: (step(x), None), self._x0(flat_batch.shape[0], seed), None, length=n_iters
        )
        return jnp.argmax(x, axis=1).astype(jnp.int32)

    def _trajectory_impl(self, flat_batch: jax.Array, seed: jax.Array, n_iters: int, extra: int):
        step = self._step_fn(flat_batch, seed.shape)
        x, _ = jax.lax.scan(
            lambda x, _: (step(x), None), self._x0(flat_batch.shape[0], seed), None, length=n_iters
        )

        def keep(x, _):
            x = step(x)
            return x, jnp.argmax(x, axis=1).astype(jnp.int8)

        _, later = jax.lax.scan(keep, x, None, length=extra)
        first = jnp.argmax(x, axis=1).astype(jnp.int8)
        top2 = jax.lax.top_k(jnp.moveaxis(x, 1, -1), 2)[0]
        tied = (top2[..., 0] == top2[..., 1]).mean(axis=(1, 2))
        return jnp.concatenate([first[None], later], axis=0).swapaxes(0, 1), tied

    def trajectory(self, flat_batch, seed, n_iters: int, extra: int) -> tuple[np.ndarray, np.ndarray]:
        """Layouts ``[b, extra + 1, H, W]`` at iterations ``n_iters .. n_iters + extra`` and, per
        member, the fraction of cells whose two largest channels are exactly equal at
        ``n_iters`` (a saturated sigmoid gives 1.0 twice; the argmax then picks by index)."""
        flat_batch = jnp.asarray(flat_batch, dtype=jnp.float32)
        chex.assert_axis_dimension(flat_batch, 1, self.n_params)
        layouts, tied = self._trajectory(
            flat_batch, jnp.asarray(seed, dtype=jnp.int32), n_iters=int(n_iters), extra=int(extra)
        )
        return np.asarray(layouts), np.asarray(tied)

    def generate(self, flat_batch: jax.Array, seed: np.ndarray | jax.Array, n_iters: int) -> jax.Array:
        """Environments ``[b, H, W]`` (tile indices) from parameters ``[b, d]`` and a seed ``[H, W]``."""
        flat_batch = jnp.asarray(flat_batch, dtype=jnp.float32)
        seed = jnp.asarray(seed, dtype=jnp.int32)
        chex.assert_rank(flat_batch, 2)
        chex.assert_axis_dimension(flat_batch, 1, self.n_params)
        chex.assert_rank(seed, 2)
        return self._generate(flat_batch, seed, n_iters=int(n_iters))
