"""Manufacturing domain, paper §4 and appendix B.2.

The NCA generates the whole map over ``.e012`` (empty, endpoint, three station kinds).
Measures: environment entropy (K = 5) and the number of workstations. Scoring:
:mod:`nca_qd.scoring.mapf`.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from nca_qd.domains.warehouse import place_block
from nca_qd.domains.base import Domain, Evaluator
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

    def make_evaluator(self, run_cfg: Mapping[str, Any] | None = None) -> Evaluator:
        """Repair -> screen -> exact RHCR (:class:`nca_qd.scoring.mapf.MapfScorer`)."""
        from nca_qd.scoring.mapf import MapfScorer

        return MapfScorer(self, run_cfg)
