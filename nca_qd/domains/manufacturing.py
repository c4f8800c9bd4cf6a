"""Manufacturing domain, paper §4 and appendix B.2.

The NCA generates the whole map over ``.e012`` (empty, endpoint, three station kinds).
Measures: environment entropy (K = 5) and the number of workstations. Scoring needs the
simulators (issue 6).
"""

from __future__ import annotations

import numpy as np

from nca_qd.domains.warehouse import place_block
from nca_qd.domains.base import Domain, Evaluator
from nca_qd.errors import NcaQdError
from nca_qd.repair import manufacturing as layout

SEED_BLOCK = ["eeee", "0221", "eeee"]
SEED_OFFSETS = {(33, 36): (15, 16), (101, 102): (50, 49)}


class ManufacturingDomain(Domain):
    name = "manufacturing"
    gen_tiles = layout.TILES
    layout_tiles = layout.TILES
    palette = layout.PALETTE

    def seed(self, shape: tuple[int, int]) -> np.ndarray:
        return place_block(shape, SEED_BLOCK, self.gen_tiles, SEED_OFFSETS)

    def assemble(self, region: np.ndarray) -> np.ndarray:
        return np.asarray(region).copy()

    def measures(self, layouts: np.ndarray) -> np.ndarray:
        """``[b, H, W]`` layouts -> ``[b, 2]``: entropy, number of workstations."""
        from nca_qd.measures import batch_entropy, station_count

        layouts = np.asarray(layouts)
        ent = np.asarray(batch_entropy(layouts, len(self.gen_tiles)))
        return np.stack([ent, station_count(layouts, layout.STATIONS)], axis=-1)

    def make_evaluator(self) -> Evaluator:
        raise NcaQdError(f"the {self.name} QD evaluation needs the lifelong-MAPF simulators "
                         "(issue 6); repair, render and measures are available")
