"""Manufacturing layouts (paper §4 and appendix B.2): every fact of the family in one place.

The NCA generates the whole map (nothing is fixed) over ``.`` empty, ``e`` endpoint and ``0 1 2``
workstations of three kinds. Valid: empty and endpoint tiles 4-connected (stations block);
every endpoint next to a station and every station next to an endpoint; at least one station of
each kind; at least as many traversable tiles as agents. Task model: goals cycle through the
station kinds 0 -> 1 -> 2; a kind-k goal is an endpoint next to a kind-k station, where the
agent stays 2, 5 or 10 timesteps. Measures: environment entropy (K = 5) and the number of
workstations.
"""

from __future__ import annotations

import numpy as np

from nca_qd.layouts.base import Construction, GoalKind, LayoutKind, TaskModel
from nca_qd.layouts.rules import AdjacencyRule, CountRule, Rules

TILES = ".e012"
EMPTY, ENDPOINT = 0, 1
STATIONS = (2, 3, 4)
STATION_WEIGHT = 5  # p_i where the unrepaired tile is a station (paper appendix C)
DWELL = (2, 5, 10)  # t_r, t_g, t_y: timesteps at an endpoint next to a station of kind 0, 1, 2


def rules(shape: tuple[int, int], n_agents: int = 200) -> Rules:
    """Validity of a manufacturing map of ``shape`` for ``n_agents`` robots."""
    stations = frozenset(STATIONS)
    return Rules(
        tiles=TILES,
        passable=frozenset({EMPTY, ENDPOINT}),
        reach_only=frozenset(),
        free_tiles=tuple(range(len(TILES))),
        adjacency=(
            AdjacencyRule(frozenset({ENDPOINT}), stations, "endpoint without a station"),
            AdjacencyRule(stations, frozenset({ENDPOINT}), "station without an endpoint"),
        ),
        counts=tuple(CountRule(frozenset({s}), ">=", 1, f"stations of kind {TILES[s]}") for s in STATIONS)
        + (CountRule(frozenset({EMPTY, ENDPOINT}), ">=", int(n_agents), "traversable tiles"),),
        fixed=np.zeros(shape, dtype=bool),
        fixed_layout=None,
        weight_of_input=(1, 1, STATION_WEIGHT, STATION_WEIGHT, STATION_WEIGHT),
    )


# Paper colours: empty white, endpoints blue, stations red / green / yellow (kinds 0, 1, 2).
PALETTE = {".": "white", "e": "#3b6fd6", "0": "#d62728", "1": "#2ca02c", "2": "#f2d024"}

SEED_BLOCK = ("eeee", "0221", "eeee")
SEED_OFFSETS = {(33, 36): (15, 16), (101, 102): (50, 49)}


class Manufacturing(LayoutKind):
    name = "manufacturing"
    family = "manufacturing"
    tiles = TILES
    gen_tiles = TILES
    palette = PALETTE
    task = TaskModel(
        blocked="012",
        goals=tuple(GoalKind(f"kind-{k} station", "e", next_to=str(k), dwell=d) for k, d in enumerate(DWELL)),
    )
    construction = Construction(anchors=STATIONS, endpoint=ENDPOINT, empty=EMPTY, exact_count=False)
    seed_block = SEED_BLOCK
    seed_offsets = SEED_OFFSETS
    eval_agent_step = 50

    def rules(self, shape, *, n_shelves=None, n_agents=200):
        return rules(shape, n_agents=n_agents)

    def measures(self, layouts):
        """Entropy and the number of workstations ``[b, 2]``."""
        from nca_qd.measures import batch_entropy, station_count

        layouts = np.asarray(layouts)
        ent = np.asarray(batch_entropy(layouts, len(TILES)))
        return np.stack([ent, station_count(layouts, STATIONS)], axis=-1)


MANUFACTURING = Manufacturing()
