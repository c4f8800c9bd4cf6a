"""Archives on top of QDax's :class:`MapElitesRepertoire`.

Two archives, as CMA-MAE (Fontaine & Nikolaidis 2023) needs them:

* the *result archive*: a plain elitist archive (each cell keeps its best solution);
* the *optimisation archive*: :class:`ThresholdRepertoire`, a QDax ``MapElitesRepertoire`` plus one
  acceptance threshold ``t_e`` per cell. QDax has no thresholds or archive learning rate, so
  the insertion rule is written here, with pyribs' ``GridArchive`` semantics:

  - an empty cell's threshold is ``threshold_min``;
  - a solution *can be inserted* when ``f > t_e`` (``t_e`` taken before the batch);
  - its improvement value is ``f - t_e`` (``f - threshold_min`` for an empty cell, and
    ``f - 0`` when ``threshold_min = -inf``, CMA-ME's convention);
  - with ``n_e`` solutions of one batch insertable into cell ``e``:
    ``t_e <- (1 - a)^n_e * t_e + (1 - (1 - a)^n_e) * mean(f of those)``;
    with ``threshold_min = -inf`` the threshold is the elite's objective (plain MAP-Elites);
  - the best insertable solution (first one on ties) replaces the cell's occupant, even when it
    is worse than the occupant (that is what makes the optimisation archive "soft").

With ``learning_rate=1`` and ``threshold_min=-inf`` the same class is the plain result archive
(QDax's own ``add`` would do too, but looks cells up by nearest centroid over all cells, which
costs O(cells) per solution; both archives here share :func:`grid_cell_indices`).

Cells are regular grid cells (:func:`grid_cell_indices`, the same mapping for both archives and
pyribs' ``GridArchive``); measures outside the ranges land in the nearest border cell.
"""

from __future__ import annotations

from collections.abc import Sequence

import chex
import flax.struct
import jax
import jax.numpy as jnp
from qdax.core.containers.mapelites_repertoire import MapElitesRepertoire


class AddInfo(flax.struct.PyTreeNode):
    """Per-solution outcome of :meth:`ThresholdRepertoire.add` (pyribs' ``add_info``)."""

    status: jax.Array  # [b] int32: 0 not added, 1 improved an occupied cell, 2 new cell
    value: jax.Array  # [b] improvement f - t_e against the pre-batch threshold
    cell: jax.Array  # [b] cell index


def grid_centroids(cells: Sequence[int], ranges: Sequence[Sequence[float]]) -> jax.Array:
    """Centroids ``[prod(cells), m]`` of a regular grid over ``ranges``, row-major.

    QDax's ``compute_euclidean_centroids`` uses ``meshgrid``'s "xy" indexing (first two axes
    swapped); we enumerate cells row-major ("ij") so that a cell's index is the C-order ravel of
    its grid coordinates, which :func:`grid_cell_indices` computes directly and archive
    heatmaps reshape to ``cells``.
    """
    axes = [(jnp.arange(c) + 0.5) / c * (r[1] - r[0]) + r[0] for c, r in zip(cells, ranges)]
    mesh = jnp.meshgrid(*axes, indexing="ij")
    return jnp.stack([m.ravel() for m in mesh], axis=-1).astype(jnp.float32)


def grid_cell_indices(
    measures: jax.Array, cells: Sequence[int], ranges: Sequence[Sequence[float]]
) -> jax.Array:
    """Cell index of each measure vector on a regular grid, by direct binning.

    Equivalent to QDax's nearest-centroid ``get_cells_indices`` on :func:`grid_centroids` (up to
    ties on bin edges) but O(m) per solution instead of O(cells), which matters for 41,472-cell
    archives.

    The offset is scaled by the cell count before dividing by the width: for integer measures
    (shelf components, workstations, walls) ``(m - lo) * cells`` is exact, so a value on a cell's
    lower edge lands in that cell. Dividing first rounds ``7 / 100 * 100`` to 6.9999995 in
    float32 and sends 22 of the 100 shelf-component counts in [140, 240) into the cell below,
    leaving 19 rows of the warehouse archive unreachable.
    """
    cells_arr = jnp.asarray(cells, dtype=jnp.int32)
    lo = jnp.asarray([r[0] for r in ranges], dtype=jnp.float32)
    hi = jnp.asarray([r[1] for r in ranges], dtype=jnp.float32)
    idx = jnp.floor((measures - lo) * cells_arr / (hi - lo)).astype(jnp.int32)
    idx = jnp.clip(idx, 0, cells_arr - 1)
    # compute_euclidean_centroids enumerates with the first axis varying slowest.
    strides = jnp.concatenate([jnp.cumprod(cells_arr[::-1])[::-1][1:], jnp.ones(1, jnp.int32)])
    return jnp.sum(idx * strides, axis=-1)


class ThresholdRepertoire(MapElitesRepertoire):
    """A MAP-Elites repertoire with CMA-MAE acceptance thresholds (see module docstring).

    ``fitnesses`` hold the occupant's objective (``-inf`` where empty), ``thresholds`` the
    acceptance threshold ``t_e`` (``threshold_min`` where empty).
    """

    thresholds: jax.Array = None  # type: ignore[assignment]
    learning_rate: float = flax.struct.field(pytree_node=False, default=1.0)
    threshold_min: float = flax.struct.field(pytree_node=False, default=-jnp.inf)
    grid_cells: tuple = flax.struct.field(pytree_node=False, default=())
    grid_ranges: tuple = flax.struct.field(pytree_node=False, default=())

    @classmethod
    def create(
        cls,
        genotype_dim: int,
        cells: Sequence[int],
        ranges: Sequence[Sequence[float]],
        learning_rate: float = 1.0,
        threshold_min: float = -jnp.inf,
    ) -> ThresholdRepertoire:
        """An empty archive for flat genotypes of size ``genotype_dim`` on a regular grid.

        ``learning_rate=1, threshold_min=-inf`` (the defaults) is a plain elitist MAP-Elites
        archive: the result archive of CMA-MAE and the archive of the baselines.
        """
        centroids = grid_centroids(cells, ranges)
        n = centroids.shape[0]
        return cls(
            genotypes=jnp.zeros((n, genotype_dim), jnp.float32),
            fitnesses=jnp.full((n, 1), -jnp.inf, jnp.float32),
            descriptors=jnp.zeros_like(centroids),
            centroids=centroids,
            extra_scores={},
            keys_extra_scores=(),
            thresholds=jnp.full((n,), threshold_min, jnp.float32),
            learning_rate=float(learning_rate),
            threshold_min=float(threshold_min),
            grid_cells=tuple(int(c) for c in cells),
            grid_ranges=tuple((float(r[0]), float(r[1])) for r in ranges),
        )

    @property
    def occupied(self) -> jax.Array:
        return self.fitnesses[:, 0] > -jnp.inf

    def add_with_info(
        self,
        genotypes: jax.Array,
        descriptors: jax.Array,
        fitnesses: jax.Array,
        cells: jax.Array | None = None,
    ) -> tuple[ThresholdRepertoire, AddInfo]:
        """Insert a batch; returns the new archive and per-solution :class:`AddInfo`."""
        chex.assert_rank([genotypes, descriptors, fitnesses], [2, 2, 1])
        n = self.centroids.shape[0]
        if cells is None:
            cells = grid_cell_indices(descriptors, self.grid_cells, self.grid_ranges)
        fitnesses = fitnesses.astype(jnp.float32)
        occupied = self.occupied[cells]
        cur_thr = jnp.where(occupied, self.thresholds[cells], self.threshold_min)
        can_insert = fitnesses > cur_thr
        is_new = can_insert & ~occupied
        status = jnp.where(is_new, 2, jnp.where(can_insert, 1, 0)).astype(jnp.int32)
        # Improvement of a new cell is measured from threshold_min (0 for CMA-ME's -inf).
        base = 0.0 if self.threshold_min == -jnp.inf else self.threshold_min
        value = fitnesses - jnp.where(is_new, base, cur_thr)

        # Batch threshold update over the insertable solutions of each cell.
        ins = can_insert.astype(jnp.float32)
        count = jax.ops.segment_sum(ins, cells, num_segments=n)
        total = jax.ops.segment_sum(jnp.where(can_insert, fitnesses, 0.0), cells, num_segments=n)
        best = jax.ops.segment_max(jnp.where(can_insert, fitnesses, -jnp.inf), cells, num_segments=n)
        touched = count > 0
        if self.threshold_min == -jnp.inf:
            new_thr = best  # plain archive: the threshold is the elite's objective
        else:
            ratio = (1.0 - self.learning_rate) ** count
            old = jnp.where(self.occupied, self.thresholds, self.threshold_min)
            new_thr = ratio * old + (1.0 - ratio) * total / jnp.maximum(count, 1.0)
        thresholds = jnp.where(touched, new_thr, self.thresholds)

        # Winner per cell: the first insertable solution with the cell's best objective.
        b = fitnesses.shape[0]
        is_best = can_insert & (fitnesses == best[cells])
        first = jax.ops.segment_min(jnp.where(is_best, jnp.arange(b), b), cells, num_segments=n)
        winner = is_best & (jnp.arange(b) == first[cells])
        target = jnp.where(winner, cells, n)  # n = out of bounds -> dropped
        archive = self.replace(
            genotypes=self.genotypes.at[target].set(genotypes, mode="drop"),
            fitnesses=self.fitnesses.at[target, 0].set(fitnesses, mode="drop"),
            descriptors=self.descriptors.at[target].set(descriptors, mode="drop"),
            thresholds=thresholds,
        )
        return archive, AddInfo(status=status, value=value, cell=cells)


def archive_stats(archive: MapElitesRepertoire, offset: float) -> dict[str, jax.Array]:
    """QD-score (sum over occupied cells of ``f - offset``), coverage, best objective, size."""
    f = archive.fitnesses[:, 0]
    occ = f > -jnp.inf
    return {
        "qd_score": jnp.sum(jnp.where(occ, f - offset, 0.0)),
        "coverage": jnp.mean(occ.astype(jnp.float32)),
        "best_objective": jnp.max(jnp.where(occ, f, -jnp.inf)),
        "n_elites": jnp.sum(occ),
    }
