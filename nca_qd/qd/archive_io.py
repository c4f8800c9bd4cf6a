"""Archive files (``archive_result.npz`` / ``archive_opt.npz``) and the view readers get.

On disk an archive is its elites (:func:`nca_qd.qd.checkpoint.archive_elites`: ``cells``,
``objective``, ``measures``, ``thresholds``, ``genotypes`` one row per occupied cell) plus
its grid (``grid_cells``, ``grid_ranges``). Readers (``experiments.evaluate``, ``render``,
the notebook) index by cell: :func:`archive_view` gives dense per-cell ``objective``,
``measures`` and ``thresholds`` (a few floats per cell) and ``genotypes`` as
:class:`CellRows`, which looks up parameters by cell without materialising the dense
``cells x d`` array. Dense files of earlier versions (``genotypes`` of shape ``[cells, d]``)
still read.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from nca_qd.errors import NcaQdError
from nca_qd.io import save_npz


class CellRows:
    """Parameters of an archive's elites, indexed by cell like a dense ``[cells, d]`` array
    (rows of empty cells read as zeros, as in the dense archive)."""

    def __init__(self, cells: np.ndarray, rows: np.ndarray, n_cells: int):
        self.cells, self.rows, self.n_cells = np.asarray(cells, np.int64), np.asarray(rows), int(n_cells)
        self._row_of = np.full(self.n_cells, -1, np.int64)
        self._row_of[self.cells] = np.arange(self.cells.size)

    @property
    def shape(self) -> tuple[int, int]:
        return self.n_cells, self.rows.shape[1]

    @property
    def dtype(self):
        return self.rows.dtype

    def __len__(self) -> int:
        return self.n_cells

    def __getitem__(self, index: Any) -> np.ndarray:
        idx = np.asarray(index)
        if idx.dtype == bool:
            idx = np.flatnonzero(idx)
        if np.any((idx < 0) | (idx >= self.n_cells)):
            raise IndexError(f"cell index out of range 0..{self.n_cells - 1}")
        rows = self._row_of[idx]
        out = np.zeros(rows.shape + (self.rows.shape[1],), self.rows.dtype)
        out[rows >= 0] = self.rows[rows[rows >= 0]]
        return out

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        dense = self[np.arange(self.n_cells)]
        return dense if dtype is None else dense.astype(dtype)


def grid_centroids_np(cells: Sequence[int], ranges: Sequence[Sequence[float]]) -> np.ndarray:
    """Row-major cell centres (numpy twin of :func:`nca_qd.qd.archive.grid_centroids`)."""
    axes = [(np.arange(c) + 0.5) / c * (r[1] - r[0]) + r[0] for c, r in zip(cells, ranges)]
    mesh = np.meshgrid(*axes, indexing="ij")
    return np.stack([m.ravel() for m in mesh], axis=-1).astype(np.float32)


def save_archive(
    path: str | Path,
    elites: Mapping[str, np.ndarray],
    grid_cells: Sequence[int],
    grid_ranges: Sequence[Sequence[float]],
) -> None:
    """An archive's elites and grid as one ``.npz``, atomically."""
    save_npz(
        path,
        {
            **elites,
            "grid_cells": np.asarray(grid_cells, np.int64),
            "grid_ranges": np.asarray(grid_ranges, np.float64),
        },
    )


def archive_view(
    elites: Mapping[str, np.ndarray],
    grid_cells: Sequence[int],
    grid_ranges: Sequence[Sequence[float]] | None = None,
) -> dict[str, Any]:
    """Per-cell arrays of a sparse archive (see module docstring)."""
    n = int(np.prod(grid_cells))
    cells = np.asarray(elites["cells"], np.int64)
    objective = np.full(n, -np.inf, np.float32)
    objective[cells] = elites["objective"]
    measures = np.zeros((n, np.asarray(elites["measures"]).shape[1]), np.float32)
    measures[cells] = elites["measures"]
    view: dict[str, Any] = {
        "objective": objective,
        "measures": measures,
        "genotypes": CellRows(cells, elites["genotypes"], n),
        "cells": cells,
        "grid_cells": np.asarray(grid_cells),
    }
    if "thresholds" in elites:
        thresholds = np.full(n, np.nan, np.float32)
        thresholds[cells] = elites["thresholds"]
        view["thresholds"] = thresholds
    if grid_ranges is not None:
        view["centroids"] = grid_centroids_np(grid_cells, grid_ranges)
    return view


def read_archive(path: str | Path) -> dict[str, Any]:
    """An ``archive_*.npz`` as :func:`archive_view` gives it (sparse files) or as written
    (dense files of earlier versions)."""
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except (OSError, ValueError) as exc:
        raise NcaQdError(f"{path}: not a readable archive ({exc})") from None
    if "cells" not in arrays:  # dense, as written before sparse archives
        if "objective" not in arrays or "genotypes" not in arrays:
            raise NcaQdError(f"{path}: not an archive (no objective / genotypes)")
        return arrays
    try:
        return archive_view(arrays, arrays["grid_cells"].tolist(), arrays["grid_ranges"].tolist())
    except KeyError as exc:
        raise NcaQdError(f"{path}: archive lacks {exc}") from None
