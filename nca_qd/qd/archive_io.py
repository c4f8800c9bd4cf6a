"""Archive files (``archive_result.npz`` / ``archive_opt.npz``) and the view readers get.

On disk an archive is its elites (:func:`nca_qd.qd.checkpoint.archive_elites`: ``cells``,
``objective``, ``measures``, ``thresholds``, ``genotypes`` one row per occupied cell) plus
its grid (``grid_cells``, ``grid_ranges``). Readers (``experiments.evaluate``, ``render``,
the notebook) index by cell: :func:`archive_view` gives dense per-cell ``objective``,
``measures`` and ``thresholds`` (a few floats per cell) and ``genotypes`` as
:class:`CellRows`, which looks up parameters by cell without materialising the dense
``cells x d`` array. Dense files of earlier versions (``genotypes`` of shape ``[cells, d]``)
still read.

An *elites record* (``elites.npz``, :func:`save_elites_record`) is an archive whose every
occupied cell keeps its objective, measures and threshold but only a chosen few keep their
parameters (``kept_cells``, ``kept_genotypes``): a run too large to ship whole (the maze's
256 x 162 archives of 1,730-parameter generators: 137 MB) ships its archive's figures and its
best generators in about a megabyte. Its view's ``genotypes`` are :class:`KeptRows`, which name
the missing cell rather than hand back zeros.
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


class KeptRows(CellRows):
    """:class:`CellRows` of an elites record: reading an occupied cell whose parameters the
    record did not keep is an error (zeros there would be a wrong generator, silently)."""

    def __init__(self, cells: np.ndarray, rows: np.ndarray, occupied: np.ndarray, source: str):
        super().__init__(cells, rows, occupied.size)
        self.occupied, self.source = np.asarray(occupied, bool), source

    def __getitem__(self, index: Any) -> np.ndarray:
        idx = np.asarray(index)
        flat = np.flatnonzero(idx) if idx.dtype == bool else idx.ravel()
        if np.all((flat >= 0) & (flat < self.n_cells)):
            lost = flat[self.occupied[flat] & (self._row_of[flat] < 0)]
            if lost.size:
                raise NcaQdError(
                    f"{self.source} keeps the generators of {self.cells.size} of "
                    f"{int(self.occupied.sum())} elites, not of cell {int(lost[0])} (kept: the "
                    "best by objective, ties spread over the archive); re-run the search from "
                    "its config.yaml to rebuild the whole archive"
                )
        return super().__getitem__(index)


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


def save_elites_record(
    path: str | Path,
    elites: Mapping[str, np.ndarray],
    kept_cells: Sequence[int],
    grid_cells: Sequence[int],
    grid_ranges: Sequence[Sequence[float]],
) -> None:
    """An elites record (see module docstring): every elite's ``cells``, ``objective``,
    ``measures`` and ``thresholds``, and the float32 parameters of the elites in ``kept_cells``
    only, atomically."""
    cells = np.asarray(elites["cells"], np.int64)
    kept = np.unique(np.asarray(kept_cells, np.int64))
    row = np.full(int(np.prod(grid_cells)), -1, np.int64)
    row[cells] = np.arange(cells.size)
    if np.any(row[kept] < 0):
        raise NcaQdError(f"{path}: kept cells {kept[row[kept] < 0][:5].tolist()} hold no elite")
    save_npz(
        path,
        {
            **{
                k: np.asarray(elites[k])
                for k in ("cells", "objective", "measures", "thresholds")
                if k in elites
            },
            "kept_cells": kept,
            "kept_genotypes": np.asarray(elites["genotypes"], np.float32)[row[kept]],
            "grid_cells": np.asarray(grid_cells, np.int64),
            "grid_ranges": np.asarray(grid_ranges, np.float64),
        },
    )


def archive_view(
    elites: Mapping[str, np.ndarray],
    grid_cells: Sequence[int],
    grid_ranges: Sequence[Sequence[float]] | None = None,
    source: str = "elites record",
) -> dict[str, Any]:
    """Per-cell arrays of a sparse archive or of an elites record (see module docstring;
    ``source`` names a record in its errors)."""
    n = int(np.prod(grid_cells))
    cells = np.asarray(elites["cells"], np.int64)
    objective = np.full(n, -np.inf, np.float32)
    objective[cells] = elites["objective"]
    measures = np.zeros((n, np.asarray(elites["measures"]).shape[1]), np.float32)
    measures[cells] = elites["measures"]
    if "kept_cells" in elites:
        genotypes: CellRows = KeptRows(
            elites["kept_cells"], elites["kept_genotypes"], np.isfinite(objective), source
        )
    else:
        genotypes = CellRows(cells, elites["genotypes"], n)
    view: dict[str, Any] = {
        "objective": objective,
        "measures": measures,
        "genotypes": genotypes,
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
    """An ``archive_*.npz`` or an elites record as :func:`archive_view` gives it (sparse files)
    or as written (dense files of earlier versions)."""
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
        return archive_view(arrays, arrays["grid_cells"].tolist(), arrays["grid_ranges"].tolist(), str(path))
    except KeyError as exc:
        raise NcaQdError(f"{path}: archive lacks {exc}") from None
