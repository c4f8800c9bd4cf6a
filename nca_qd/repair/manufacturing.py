"""Manufacturing layouts: repair rules (the NCA generates the whole map, nothing is fixed).

Tiles ``.`` empty, ``e`` endpoint, ``0 1 2`` workstations of three kinds (paper appendix B.2).
Valid: empty and endpoint tiles 4-connected (stations block); every endpoint next to a station
and every station next to an endpoint; at least one station of each kind; at least as many
traversable tiles as agents.
"""

from __future__ import annotations

import numpy as np

from nca_qd.repair.rules import AdjacencyRule, CountRule, Rules

TILES = ".e012"
EMPTY, ENDPOINT = 0, 1
STATIONS = (2, 3, 4)
STATION_WEIGHT = 5  # p_i where the unrepaired tile is a station (paper appendix C)


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
        counts=tuple(CountRule(frozenset({s}), ">=", 1, f"stations of kind {TILES[s]}")
                     for s in STATIONS)
        + (CountRule(frozenset({EMPTY, ENDPOINT}), ">=", int(n_agents), "traversable tiles"),),
        fixed=np.zeros(shape, dtype=bool),
        fixed_layout=None,
        weight_of_input=(1, 1, STATION_WEIGHT, STATION_WEIGHT, STATION_WEIGHT),
    )


# Paper colours: empty white, endpoints blue, stations red / green / yellow (kinds 0, 1, 2).
PALETTE = {".": "white", "e": "#3b6fd6", "0": "#d62728", "1": "#2ca02c", "2": "#f2d024"}
