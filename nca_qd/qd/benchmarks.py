"""The linear-projection sphere benchmark of the CMA-ME / CMA-MAE papers.

Objective: the sphere function shifted to ``5.12 * 0.4`` and scaled to [0, 100]; measures: the
sums of the two halves of the solution after clipping each coordinate to [-5.12, 5.12] (values
outside are folded as ``5.12 / x``). Archive 100 x 100 over ``[-5.12 n/2, 5.12 n/2]^2``. The
CMA-MAE paper (n=100, 15 emitters x 36, 10,000 iterations, alpha=0.01) reports QD-score 64.86
(normalised: the mean over all cells of the objective, empty cells 0) and coverage 83 %.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from nca_qd.interfaces import EvalBatch
from nca_qd.qd.loop import ArchiveSpec

BOUND = 5.12


def sphere_objective(solutions: jax.Array, key: jax.Array | None = None) -> EvalBatch:
    """Batched linear-projection sphere: ``[b, n]`` -> objective ``[b]`` in [0, 100], measures ``[b, 2]``."""
    n = solutions.shape[1]
    shift = BOUND * 0.4
    worst = (-BOUND - shift) ** 2 * n
    raw = jnp.sum(jnp.square(solutions - shift), axis=1)
    objective = (raw - worst) / (0.0 - worst) * 100.0
    outside = jnp.abs(solutions) > BOUND
    clipped = jnp.where(outside, BOUND / jnp.where(outside, solutions, 1.0), solutions)
    half = n // 2
    measures = jnp.stack([clipped[:, :half].sum(1), clipped[:, half:].sum(1)], axis=1)
    return EvalBatch(objective=objective, measures=measures)


def sphere_batch_objective():
    """:func:`sphere_objective` jitted, in the QD loop's ``(solutions, key, context)`` form."""
    jitted = jax.jit(sphere_objective)

    def objective(solutions: jax.Array, key: jax.Array, context=None) -> EvalBatch:
        return jitted(solutions)

    return objective


def sphere_spec(
    n: int = 100, learning_rate: float = 0.01, threshold_min: float = 0.0, cells: int = 100
) -> ArchiveSpec:
    r = BOUND * n / 2
    return ArchiveSpec(
        cells=[cells, cells],
        ranges=[[-r, r], [-r, r]],
        learning_rate=learning_rate,
        threshold_min=threshold_min,
        qd_offset=0.0,
    )


def normalised_qd_score(qd_score: float, n_cells: int) -> float:
    """The papers' normalised QD-score: sum of objectives (0..100) over the number of cells."""
    return qd_score / n_cells
