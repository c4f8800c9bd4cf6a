"""Lifelong-MAPF scenarios: which tiles agents may stand on, and where their goals come from.

A scenario turns a layout (row strings) into the simulator's inputs, independent of any
particular simulator (the compiled RHCR core uses it, and so will a later JAX screening
simulator):

* ``traversable`` -- bool ``[H, W]``: the tiles agents may occupy;
* ``classes`` -- goal classes, each a set of cells with sampling weights and a dwell time
  (timesteps an agent stays on the cell after arriving before the goal counts as done);
* ``cycle`` -- the order in which an agent's goals cycle through the classes.

The task models (blocked tiles, goal kinds, dwell times, cycle) are facts of each layout
family, read from :mod:`nca_qd.layouts` (``warehouse_even``, ``warehouse_uneven``,
``manufacturing``; Zhang et al., NeurIPS 2023, appendix A): a goal of a kind is a cell holding
its tile (and, where it says so, next to a given tile), drawn with weight ``left_weight`` in the
left half of the map and 1 elsewhere.

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
from nca_qd.layouts import get_layout, layout_names

SCENARIOS = layout_names()


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

    @property
    def n_goal_cells(self) -> int:
        """Distinct cells any goal can be on (each gets a distance table in the simulators)."""
        return int(np.unique(np.concatenate([c.cells for c in self.classes])).size)

    def simulation_bytes(self, n_agents: int) -> int:
        """Estimated peak memory of one exact simulation of this scenario (nca_qd.memory)."""
        from nca_qd.memory import simulation_bytes

        h, w = self.shape
        return simulation_bytes(h * w, self.n_goal_cells, n_agents)


def tiles_for(scenario: str) -> str:
    """The tile alphabet of a scenario's layouts."""
    return get_layout(scenario, "scenario").tiles


def check_name(scenario: str) -> None:
    get_layout(scenario, "scenario")


def build_scenario(
    rows: list[str] | tuple[str, ...], scenario: str, n_agents: int | None = None, source: str = "layout"
) -> Scenario:
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

    task = get_layout(scenario).task
    traversable = ~np.isin(grid, list(task.blocked))
    left = (np.arange(grid.size) % width) < width / 2
    classes = []
    for kind in task.goals:
        where = grid == kind.tile
        if kind.next_to is not None:
            where &= _adjacent_to(grid == kind.next_to)
        cells = np.flatnonzero(where).astype(np.int32)
        if cells.size == 0:
            near = f" next to a {kind.next_to!r} tile" if kind.next_to is not None else ""
            raise NcaQdError(
                f"{source}: no {kind.name} goal: no {kind.tile!r} tile{near} "
                f"({scenario} needs one for each of "
                f"{', '.join(g.name for g in task.goals)})"
            )
        weights = np.where(left[cells], kind.left_weight, 1.0)
        classes.append(GoalClass(kind.name, cells, weights, kind.dwell))
    cycle = tuple(range(len(task.goals)))

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
        raise NcaQdError(
            f"{source}: traversable tiles are not all connected (tile at row {r}, "
            f"column {c} cannot be reached from row {start[0]}, column {start[1]}), "
            "so some goal is unreachable for some agent"
        )
