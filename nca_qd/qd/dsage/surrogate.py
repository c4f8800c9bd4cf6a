"""DSAGE's deep surrogate: a small CNN that predicts a layout's objective and measures.

As in DSAGE (Bhatt et al. 2022, "DSAGE-only-ancillary" configuration, which the NCA paper
compares against) the model has two parts, trained together:

* an **ancillary network** (:class:`AncillaryNet`, a small ResNet at full resolution) predicts
  a per-tile map from the simulation: the maze agent's occupancy (visits per tile and episode),
  the warehouse robots' tile usage. Its loss weighs ``ancillary_weight`` (10 in DSAGE);
* a **predictor** (:class:`PredictorNet`, a DCGAN-discriminator-like pyramid of stride-2
  convolutions) reads the one-hot layout plus the predicted map and regresses the objective and
  every measure.

Differences from DSAGE's PyTorch model, and why: targets are scaled to [0, 1] by the domain's
objective and measure ranges (DSAGE regresses raw values, so the maze's path length, up to 648,
drowns the 0/1 objective in the loss); layer normalisation replaces batch normalisation (no
running statistics to carry in a functional state); layouts are padded to a multiple of 16 with
an all-zero one-hot, so any size works (DSAGE pads the maze's 16x16 to itself).

Training follows DSAGE: Adam (learning rate 1e-3), ``epochs`` passes over the ``sample_size``
most recent data points in minibatches of ``batch_size``, continuing from the previous outer
iteration's weights; each minibatch step is one jitted call.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax


class AncillaryNet(nn.Module):
    """Conv 3x3 + ``res_blocks`` residual blocks + Conv 1x1 -> one map per tile."""

    features: int = 64
    res_blocks: int = 2

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        x = nn.leaky_relu(nn.Conv(self.features, (3, 3), use_bias=False)(x), 0.2)
        for _ in range(self.res_blocks):
            y = nn.relu(nn.Conv(self.features, (3, 3), use_bias=False)(x))
            y = nn.Conv(self.features, (3, 3), use_bias=False)(y)
            x = nn.relu(x + y)
        return nn.Conv(1, (1, 1), use_bias=False)(x)[..., 0]


class PredictorNet(nn.Module):
    """Stride-2 convolutions down to 4x4 (channels doubling), then one linear head per output."""

    n_out: int
    features: int = 64

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        x = nn.leaky_relu(nn.Conv(self.features, (4, 4), strides=2, use_bias=False)(x), 0.2)
        size, feats = x.shape[-2], self.features
        while size > 4:
            feats *= 2
            x = nn.Conv(feats, (4, 4), strides=2, use_bias=False)(x)
            x = nn.leaky_relu(nn.LayerNorm()(x), 0.2)
            size = x.shape[-2]
        return nn.Dense(self.n_out)(x.reshape(x.shape[:-3] + (-1,)))


class SurrogateModel(nn.Module):
    """Layout one-hot ``[..., H, W, k]`` -> (scaled objective and measures ``[..., n_out]``,
    ancillary map ``[..., H, W]``)."""

    n_out: int
    features: int = 64
    res_blocks: int = 2
    use_ancillary: bool = True

    @nn.compact
    def __call__(self, onehot: jax.Array) -> tuple[jax.Array, jax.Array]:
        if self.use_ancillary:
            anc = AncillaryNet(self.features, self.res_blocks)(onehot)
            x = jnp.concatenate([onehot, anc[..., None]], axis=-1)
        else:
            anc = jnp.zeros(onehot.shape[:-1], onehot.dtype)
            x = onehot
        return PredictorNet(self.n_out, self.features)(x), anc


@dataclass(frozen=True)
class SurrogateConfig:
    """The surrogate's sizes and training settings (``algo.surrogate`` in the config)."""

    features: int = 64
    res_blocks: int = 2
    ancillary_weight: float = 10.0
    use_ancillary: bool = True
    epochs: int = 200
    batch_size: int = 64
    sample_size: int = 20000
    learning_rate: float = 1e-3


class Surrogate:
    """Builds, applies and trains the surrogate for layouts of one shape.

    ``lows`` / ``highs``: the range of the objective followed by each measure's range; the model
    predicts values scaled to [0, 1] by them and :meth:`predict` maps back.
    """

    def __init__(
        self,
        shape: tuple[int, int],
        n_tiles: int,
        lows: Sequence[float],
        highs: Sequence[float],
        cfg: SurrogateConfig,
    ):
        self.shape, self.n_tiles, self.cfg = tuple(int(s) for s in shape), int(n_tiles), cfg
        self.n_out = len(lows)
        self.lows = jnp.asarray(lows, jnp.float32)
        self.span = jnp.maximum(jnp.asarray(highs, jnp.float32) - self.lows, 1e-6)
        h, w = self.shape
        self.padded = (-(-h // 16) * 16, -(-w // 16) * 16)
        self.model = SurrogateModel(self.n_out, cfg.features, cfg.res_blocks, cfg.use_ancillary)
        self.tx = optax.adam(cfg.learning_rate)
        self._train_step = jax.jit(self._step)
        self.predict = jax.jit(self._predict)

    # --- model ---------------------------------------------------------------------------
    def encode(self, layouts: jax.Array) -> jax.Array:
        """Tile indices ``[b, H, W]`` -> padded one-hot ``[b, H', W', k]`` (padding all zero)."""
        h, w = self.shape
        onehot = jax.nn.one_hot(jnp.asarray(layouts, jnp.int32), self.n_tiles, dtype=jnp.float32)
        ph, pw = self.padded
        return jnp.pad(onehot, ((0, 0), (0, ph - h), (0, pw - w), (0, 0)))

    def init(self, key: jax.Array) -> tuple[Any, Any]:
        """Fresh weights and Adam state."""
        params = self.model.init(key, jnp.zeros((1, *self.padded, self.n_tiles)))
        return params, self.tx.init(params)

    def _forward(self, params, layouts):
        h, w = self.shape
        scaled, anc = self.model.apply(params, self.encode(layouts))
        return scaled, anc[:, :h, :w]

    def _predict(self, params, layouts: jax.Array) -> tuple[jax.Array, jax.Array]:
        """``(objective [b], measures [b, m])`` predicted for layouts ``[b, H, W]``."""
        scaled, _ = self._forward(params, layouts)
        values = scaled * self.span + self.lows
        return values[:, 0], values[:, 1:]

    def loss(self, params, layouts, targets, ancillary, weights) -> jax.Array:
        """DSAGE's loss: mean of the per-output MSEs (scaled targets) + weight x ancillary MSE
        (over the rows whose map is known: no NaN)."""
        scaled, anc = self._forward(params, layouts)
        t = (targets - self.lows) / self.span
        w = weights / jnp.maximum(jnp.sum(weights), 1.0)
        main = jnp.sum(w * jnp.mean((scaled - t) ** 2, axis=1))
        if not self.cfg.use_ancillary:
            return main
        # a row without a map (a warehouse layout that got no exact run) trains the rest only
        known = jnp.isfinite(ancillary)
        has_map = jnp.all(known, axis=(1, 2)) * weights
        anc_err = jnp.mean((anc - jnp.where(known, ancillary, 0.0)) ** 2, axis=(1, 2))
        anc_loss = jnp.sum(has_map * anc_err) / jnp.maximum(jnp.sum(has_map), 1.0)
        return main + self.cfg.ancillary_weight * anc_loss

    # --- training --------------------------------------------------------------------------
    def _step(self, params, opt_state, layouts, targets, ancillary, valid):
        loss, g = jax.value_and_grad(self.loss)(
            params,
            layouts.astype(jnp.int32),
            targets,
            ancillary.astype(jnp.float32),
            valid.astype(jnp.float32),
        )
        updates, opt_state = self.tx.update(g, opt_state, params)
        return optax.apply_updates(params, updates), opt_state, loss

    def train(self, params, opt_state, layouts, targets, ancillary, seed: int):
        """``epochs`` passes over the ``sample_size`` most recent rows of the training data
        (numpy ``layouts [n, H, W]``, ``targets [n, n_out]``, ``ancillary [n, H, W]``, oldest
        first), in random minibatches drawn with ``seed``. Returns new params, opt state and the
        last epoch's mean loss.

        A host loop over jitted steps: XLA's CPU backend runs convolution gradients far slower
        inside a ``scan`` / ``while`` body than as a call of their own (docs/benchmarks.md, DSAGE).
        """
        cfg = self.cfg
        count = int(layouts.shape[0])
        n = min(count, cfg.sample_size)
        bs = cfg.batch_size
        rng = np.random.default_rng(seed)
        last = float("nan")
        for _ in range(cfg.epochs):
            order = count - 1 - rng.permutation(n)  # the n most recent rows, shuffled
            total, steps = 0.0, 0
            for j in range(0, n, bs):
                rows = order[j : j + bs]
                valid = np.ones(bs, bool)
                if rows.size < bs:  # a short last batch: padded and masked out of the loss
                    valid[rows.size :] = False
                    rows = np.concatenate([rows, np.full(bs - rows.size, rows[0], rows.dtype)])
                params, opt_state, loss = self._train_step(
                    params, opt_state, layouts[rows], targets[rows], ancillary[rows], valid
                )
                total, steps = total + loss, steps + 1
            last = float(total) / max(steps, 1)
        return params, opt_state, last
