"""The constraints a repaired layout must satisfy, as data shared by the MILP, heuristic and validator.

A :class:`Rules` object describes one domain's validity on a full layout (indices into
``tiles``): which tiles robots can pass, which must merely be reachable, which cells are fixed,
the 4-neighbour adjacency rules ("every A tile has a B neighbour") and the tile-count rules.
Keeping the rules as data means the MILP builder (:mod:`nca_qd.repair.milp`), the greedy
construction (:mod:`nca_qd.repair.heuristic`) and the independent graph-search validator
(:mod:`nca_qd.repair.validator`) cannot drift apart on what "valid" means.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# 4-neighbour offsets, in a fixed order (determinism of everything built on them).
NEIGHBOURS: tuple[tuple[int, int], ...] = ((-1, 0), (0, 1), (1, 0), (0, -1))


@dataclass(frozen=True)
class AdjacencyRule:
    """Every tile in ``tiles`` needs a 4-neighbour in ``needs`` (both are sets of tile indices)."""

    tiles: frozenset[int]
    needs: frozenset[int]
    name: str


@dataclass(frozen=True)
class CountRule:
    """``count(tiles) <op> value`` over the whole layout; ``op`` is ``"=="`` or ``">="``."""

    tiles: frozenset[int]
    op: str
    value: int
    name: str


@dataclass
class Rules:
    """Validity of one domain's layouts.

    tiles: the layout alphabet (``layout[i, j]`` indexes it).
    passable: tiles robots move through; all passable tiles form one 4-connected component.
    reach_only: tiles that must be reachable (a passable 4-neighbour) but block movement.
    free_tiles: tiles a non-fixed cell may take.
    fixed: ``[h, w]`` bool, cells that must keep ``fixed_layout``'s tile; ``fixed_layout`` is
        ``None`` when nothing is fixed.
    weights: per-cell Hamming weights are ``weight_of_input[input tile]`` (paper's p_i).
    tie_costs: optional ``[h, w]`` extra cost of changing each cell, summing to less than 1 over
        the layout: the solvers minimise ``weights + tie_costs``, so it only decides between
        layouts equally near in weighted Hamming distance (see ``repair(tie_break=)``).
    """

    tiles: str
    passable: frozenset[int]
    reach_only: frozenset[int]
    free_tiles: tuple[int, ...]
    adjacency: tuple[AdjacencyRule, ...]
    counts: tuple[CountRule, ...]
    fixed: np.ndarray
    fixed_layout: np.ndarray | None
    weight_of_input: tuple[int, ...] = field(default=())
    tie_costs: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.fixed.shape)  # type: ignore[return-value]

    def cell_weights(self, layout_in: np.ndarray) -> np.ndarray:
        """``[h, w]`` integer weights p_i of each cell given the unrepaired layout."""
        if not self.weight_of_input:
            return np.ones(layout_in.shape, dtype=np.int64)
        return np.asarray(self.weight_of_input, dtype=np.int64)[layout_in]

    def objective_weights(self, layout_in: np.ndarray) -> np.ndarray:
        """What the solvers minimise per changed cell: the weights p_i plus the tie costs."""
        weights = self.cell_weights(layout_in)
        return weights if self.tie_costs is None else weights + self.tie_costs

    def passable_mask(self, layout: np.ndarray) -> np.ndarray:
        return np.isin(layout, list(self.passable))


def neighbours(r: int, c: int, h: int, w: int):
    """In-map 4-neighbours of ``(r, c)`` in :data:`NEIGHBOURS` order."""
    for dr, dc in NEIGHBOURS:
        rr, cc = r + dr, c + dc
        if 0 <= rr < h and 0 <= cc < w:
            yield rr, cc


def has_neighbour_in(mask: np.ndarray) -> np.ndarray:
    """``[h, w]`` bool: the cell has a 4-neighbour where ``mask`` is True."""
    out = np.zeros_like(mask, dtype=bool)
    out[1:, :] |= mask[:-1, :]
    out[:-1, :] |= mask[1:, :]
    out[:, 1:] |= mask[:, :-1]
    out[:, :-1] |= mask[:, 1:]
    return out


def dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    """Chebyshev dilation of a bool mask by ``radius`` cells (a square neighbourhood)."""
    out = mask.copy()
    for _ in range(radius):
        grown = out.copy()
        grown[1:, :] |= out[:-1, :]
        grown[:-1, :] |= out[1:, :]
        out = grown
        grown = out.copy()
        grown[:, 1:] |= out[:, :-1]
        grown[:, :-1] |= out[:, 1:]
        out = grown
    return out
