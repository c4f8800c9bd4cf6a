"""Lifelong-MAPF scenarios: which tiles agents may stand on, and where their goals come from.

A scenario turns a layout (row strings) into the simulator's inputs, independent of any
particular simulator (the compiled RHCR core uses it, and so will a later JAX screening
simulator):

* ``traversable`` -- bool ``[H, W]``: the tiles agents may occupy;
* ``classes`` -- goal classes, each a set of cells with sampling weights and a dwell time
  (timesteps an agent stays on the cell after arriving before the goal counts as done);
* ``cycle`` -- the order in which an agent's goals cycle through the classes.

Scenarios (Zhang et al., NeurIPS 2023, appendix A):

``warehouse_even`` / ``warehouse_uneven``
    Tiles ``.`` empty, ``@`` shelf, ``e`` endpoint, ``w`` workstation; everything but shelves
    is traversable. Goals alternate endpoint (uniform) and workstation. Workstation weights are
    all 1 (even), or 5 for workstations in the left half of the map and 1 elsewhere (uneven:
    the paper's "left border workstations are 5 times more likely").
``manufacturing``
    Tiles ``.`` empty, ``e`` endpoint, ``0`` ``1`` ``2`` stations; only ``.`` and ``e`` are
    traversable. Goals cycle through station kinds 0 -> 1 -> 2; a kind-k goal is an endpoint
    4-adjacent to a kind-k station (uniform), where the agent stays 2, 5 or 10 timesteps.

Validation raises :class:`~nca_qd.errors.NcaQdError` with one-line messages: unknown scenario,
unknown tiles, an empty goal class, traversable tiles that are not all connected (some goal
would be unreachable for some agent), more agents than traversable tiles.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from nca_qd.errors import NcaQdError
from nca_qd.io import rows_to_array

WAREHOUSE_TILES = ".@ew"
MANUFACTURING_TILES = ".e012"
MANUFACTURING_DWELL = (2, 5, 10)
UNEVEN_LEFT_WEIGHT = 5.0
SCENARIOS = ("warehouse_even", "warehouse_uneven", "manufacturing")


@dataclass(frozen=True)
class GoalClass:
    """One kind of goal: candidate cells (flat row-major indices), weights, dwell time."""

    name: str
    cells: np.ndarray  # int32 [k]
    weights: np.ndarray  # float64 [k], positive
    dwell: int


@dataclass(frozen=True)
class Scenario:
    """A validated layout plus task model, ready for a simulator."""

    name: str
    rows: tuple[str, ...]
    traversable: np.ndarray  # bool [H, W]
    classes: tuple[GoalClass, ...]
    cycle: tuple[int, ...]

    @property
    def shape(self) -> tuple[int, int]:
        return self.traversable.shape  # type: ignore[return-value]

    @property
    def n_traversable(self) -> int:
        return int(self.traversable.sum())


def tiles_for(scenario: str) -> str:
    """The tile alphabet of a scenario's layouts."""
    check_name(scenario)
    return MANUFACTURING_TILES if scenario == "manufacturing" else WAREHOUSE_TILES


def check_name(scenario: str) -> None:
    if scenario not in SCENARIOS:
        raise NcaQdError(f"unknown scenario {scenario!r} (expected one of {', '.join(SCENARIOS)})")


def build_scenario(rows: list[str] | tuple[str, ...], scenario: str, n_agents: int | None = None,
                   source: str = "layout") -> Scenario:
    """Validate ``rows`` for ``scenario`` and derive traversable tiles and goal classes.

    ``n_agents`` (if given) is checked against the number of traversable tiles.
    """
    tiles = tiles_for(scenario)
    rows = tuple(rows)
    if not rows or not rows[0] or len({len(r) for r in rows}) != 1:
        raise NcaQdError(f"{source}: layout must be non-empty rows of equal length")
    grid = np.array([list(r) for r in rows])
    rows_to_array(list(rows), tiles, source=source)  # unknown characters -> MapFormatError
    width = grid.shape[1]

    if scenario == "manufacturing":
        traversable = np.isin(grid, ["." , "e"])
        endpoints = grid == "e"
        classes = []
        for kind, dwell in enumerate(MANUFACTURING_DWELL):
            near = endpoints & _adjacent_to(grid == str(kind))
            cells = np.flatnonzero(near).astype(np.int32)
            if cells.size == 0:
                raise NcaQdError(f"{source}: no endpoint next to a kind-{kind} station "
                                 "(manufacturing needs one for each of 0, 1, 2)")
            classes.append(GoalClass(f"station{kind}", cells, np.ones(cells.size), dwell))
        cycle = (0, 1, 2)
    else:
        traversable = grid != "@"
        ends = np.flatnonzero(grid == "e").astype(np.int32)
        stations = np.flatnonzero(grid == "w").astype(np.int32)
        if ends.size == 0:
            raise NcaQdError(f"{source}: the warehouse has no endpoint ('e')")
        if stations.size == 0:
            raise NcaQdError(f"{source}: the warehouse has no workstation ('w')")
        weights = np.ones(stations.size)
        if scenario == "warehouse_uneven":
            weights[(stations % width) < width / 2] = UNEVEN_LEFT_WEIGHT
        classes = [GoalClass("endpoint", ends, np.ones(ends.size), 0),
                   GoalClass("workstation", stations, weights, 0)]
        cycle = (0, 1)

    _check_connected(traversable, source)
    n_free = int(traversable.sum())
    if n_agents is not None:
        if n_agents <= 0:
            raise NcaQdError(f"need at least one agent, got {n_agents}")
        if n_agents > n_free:
            raise NcaQdError(f"{source}: {n_agents} agents but only {n_free} traversable tiles")
    return Scenario(scenario, rows, traversable, tuple(classes), cycle)


def _adjacent_to(mask: np.ndarray) -> np.ndarray:
    """Tiles with a 4-neighbour in ``mask``."""
    out = np.zeros_like(mask)
    out[1:, :] |= mask[:-1, :]
    out[:-1, :] |= mask[1:, :]
    out[:, 1:] |= mask[:, :-1]
    out[:, :-1] |= mask[:, 1:]
    return out


def _check_connected(traversable: np.ndarray, source: str) -> None:
    """All traversable tiles must form one 4-connected region, so every goal is reachable
    from every possible start cell."""
    free = np.argwhere(traversable)
    if free.size == 0:
        raise NcaQdError(f"{source}: no traversable tile")
    h, w = traversable.shape
    seen = np.zeros_like(traversable)
    start = tuple(free[0])
    seen[start] = True
    queue = deque([start])
    while queue:
        r, c = queue.popleft()
        for rr, cc in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)):
            if 0 <= rr < h and 0 <= cc < w and traversable[rr, cc] and not seen[rr, cc]:
                seen[rr, cc] = True
                queue.append((rr, cc))
    cut_off = np.argwhere(traversable & ~seen)
    if cut_off.size:
        r, c = cut_off[0]
        raise NcaQdError(f"{source}: traversable tiles are not all connected (tile at row {r}, "
                         f"column {c} cannot be reached from row {start[0]}, column {start[1]}), "
                         "so some goal is unreachable for some agent")
