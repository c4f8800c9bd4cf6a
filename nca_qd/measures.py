"""Measures shared by domains (batched, jit-able).

Environment entropy (paper §3): every overlapping 2x2 window of a layout with K tile types is one
of K^4 patterns; the entropy of the pattern distribution, counted over all K^4 patterns (zeros
included), in log base K^4, lies in [0, 1]. 0 means one pattern everywhere (most regular).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def pattern_ids(layout: jax.Array, n_tiles: int) -> jax.Array:
    """Index in ``[0, K^4)`` of every overlapping 2x2 window of ``layout [H, W]`` -> ``[H-1, W-1]``."""
    k = n_tiles
    return layout[:-1, :-1] * k**3 + layout[:-1, 1:] * k**2 + layout[1:, :-1] * k + layout[1:, 1:]


def entropy(layout: jax.Array, n_tiles: int) -> jax.Array:
    """Environment entropy of one layout ``[H, W]`` (ints in ``[0, K)``), normalised to [0, 1]."""
    n_patterns = n_tiles**4
    ids = pattern_ids(layout.astype(jnp.int32), n_tiles).ravel()
    counts = jnp.zeros(n_patterns, jnp.float32).at[ids].add(1.0)
    p = counts / ids.shape[0]
    plogp = jnp.where(p > 0, p * jnp.log(jnp.where(p > 0, p, 1.0)), 0.0)
    return -jnp.sum(plogp) / jnp.log(float(n_patterns))


def batch_entropy(layouts: jax.Array, n_tiles: int) -> jax.Array:
    """:func:`entropy` over a batch ``[b, H, W]`` -> ``[b]``."""
    return jax.vmap(lambda l: entropy(l, n_tiles))(layouts)


def tile_count(layouts: jax.Array, tile: int) -> jax.Array:
    """Number of tiles of type ``tile`` in each layout of ``[b, H, W]`` -> ``[b]`` (e.g. walls)."""
    return jnp.sum(layouts == tile, axis=(-2, -1)).astype(jnp.float32)


def shelf_components(layouts, shelf: int):
    """Number of 4-connected components of ``shelf`` tiles in each layout ``[b, H, W]`` -> ``[b]``.

    Host-side (scipy labelling, not jit-able): it runs once per repaired layout, after the MILP.
    """
    import numpy as np
    from scipy import ndimage

    layouts = np.asarray(layouts)
    four = ndimage.generate_binary_structure(2, 1)
    flat = layouts.reshape((-1,) + layouts.shape[-2:])
    out = np.array([ndimage.label(lay == shelf, structure=four)[1] for lay in flat], dtype=np.float32)
    return out.reshape(layouts.shape[:-2])


def station_count(layouts, stations) -> jax.Array:
    """Number of tiles whose type is any of ``stations`` in each layout ``[b, H, W]`` -> ``[b]``."""
    layouts = jnp.asarray(layouts)
    return sum(tile_count(layouts, int(s)) for s in stations)
