"""Search directly over tile layouts: DSAGE's inner loop and its downsampling.

Solutions are flat layouts ``[d = H * W]`` of tile indices (stored as float32 in the archives,
like every other genotype of the project). The variation is the DSAGE papers' MAP-Elites:
uniformly random layouts for the first ``initial_population`` solutions, then a uniformly
chosen elite with ``mutation_k`` distinct positions set to uniformly random tiles.

:func:`make_inner_loop` runs that MAP-Elites for ``iterations`` batches on the surrogate's
predictions in one jitted call; :func:`downsample` picks one random elite per block of cells, the
solutions DSAGE then evaluates for real.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from functools import partial

import jax
import jax.numpy as jnp

from nca_qd.qd.archive import ThresholdRepertoire, grid_cell_indices
from nca_qd.qd.emitters import sample_elites


def random_layouts(key: jax.Array, n: int, dim: int, n_tiles: int) -> jax.Array:
    """``n`` uniformly random flat layouts ``[n, dim]`` (float32 tile indices)."""
    return jax.random.randint(key, (n, dim), 0, n_tiles).astype(jnp.float32)


def mutate(key: jax.Array, parents: jax.Array, k: int, n_tiles: int) -> jax.Array:
    """Each row with ``k`` distinct positions replaced by uniformly random tiles."""
    b, d = parents.shape
    k_pos, k_val = jax.random.split(key)
    pos = jnp.argsort(jax.random.uniform(k_pos, (b, d)), axis=1)[:, :k]
    vals = jax.random.randint(k_val, (b, k), 0, n_tiles).astype(parents.dtype)
    return parents.at[jnp.arange(b)[:, None], pos].set(vals)


def make_inner_loop(
    predict: Callable[[object, jax.Array], tuple[jax.Array, jax.Array]],
    shape: tuple[int, int],
    n_tiles: int,
    cells: Sequence[int],
    ranges: Sequence[Sequence[float]],
    iterations: int,
    emitters: int,
    batch_size: int,
    initial_population: int,
    mutation_k: int,
) -> Callable[[object, jax.Array], ThresholdRepertoire]:
    """``inner(params, key) -> archive``: MAP-Elites on the surrogate, from an empty archive
    (iteration ``i`` draws from ``fold_in(key, i)``).

    ``predict(params, layouts [b, H, W]) -> (objective [b], measures [b, m])``. Each iteration
    asks ``emitters x batch_size`` layouts (DSAGE: 5 x 30); the first ``ceil(initial_population
    / batch_size)`` iterations are random, as each of DSAGE's emitters emits random layouts until
    it has emitted ``initial_population``. The emitters differ only in their random draws, so
    one batch of all of them is the same search.
    """
    h, w = shape
    dim = h * w
    n_random = max(1, math.ceil(initial_population / batch_size))
    batch_size = emitters * batch_size

    @partial(jax.jit, donate_argnums=(1,))  # the archive is updated in place
    def one(i, archive, params, key):
        k_rand, k_par, k_mut = jax.random.split(jax.random.fold_in(key, i), 3)
        children = mutate(k_mut, sample_elites(archive, k_par, batch_size), mutation_k, n_tiles)
        sols = jnp.where(i < n_random, random_layouts(k_rand, batch_size, dim, n_tiles), children)
        objective, measures = predict(params, sols.reshape(batch_size, h, w))
        archive, _ = archive.add_with_info(
            sols, measures, objective, grid_cell_indices(measures, cells, ranges)
        )
        return archive

    def inner(params, key):
        # A host loop over jitted iterations: XLA's CPU backend runs the surrogate's
        # convolutions much slower inside a while loop (see surrogate.Surrogate.train).
        archive = ThresholdRepertoire.create(dim, cells, ranges)
        for i in range(iterations):
            archive = one(jnp.asarray(i, jnp.int32), archive, params, key)
        return archive

    return inner


def downsample(
    archive: ThresholdRepertoire, key: jax.Array, coarse: Sequence[int]
) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """One uniformly chosen elite per block of cells of a ``coarse`` grid over the same ranges
    (block ``i`` of axis ``a`` holds fine cells ``[s_a i, s_a (i + 1))``, ``s_a = fine_a //
    coarse_a``; fine cells past ``s_a coarse_a`` are left out, as in DSAGE).

    Returns ``(genotypes [n, d], objective [n], measures [n, m], selected [n])`` over the
    ``n = prod(coarse)`` blocks, row-major; ``selected`` is False where a block holds no elite.
    """
    fine = jnp.asarray(archive.grid_cells, jnp.int32)
    coarse_arr = jnp.asarray(coarse, jnp.int32)
    scale = fine // coarse_arr
    n_fine = archive.fitnesses.shape[0]
    n_coarse = math.prod(int(c) for c in coarse)
    idx = jnp.stack(jnp.unravel_index(jnp.arange(n_fine), tuple(archive.grid_cells)), axis=1)
    block = idx // scale
    inside = jnp.all(block < coarse_arr, axis=1)
    strides = jnp.asarray([math.prod(int(c) for c in coarse[i + 1 :]) for i in range(len(coarse))])
    block_id = jnp.where(inside, jnp.sum(jnp.minimum(block, coarse_arr - 1) * strides, axis=1), n_coarse)
    prio = jnp.where(archive.occupied & inside, jax.random.uniform(key, (n_fine,)), -1.0)
    best = jax.ops.segment_max(prio, block_id, num_segments=n_coarse + 1)[:n_coarse]
    winner_mask = (prio >= 0) & (prio == best[jnp.minimum(block_id, n_coarse - 1)]) & inside
    winner = jax.ops.segment_min(
        jnp.where(winner_mask, jnp.arange(n_fine), n_fine), block_id, num_segments=n_coarse + 1
    )[:n_coarse]
    selected = winner < n_fine
    row = jnp.minimum(winner, n_fine - 1)
    return archive.genotypes[row], archive.fitnesses[row, 0], archive.descriptors[row], selected
