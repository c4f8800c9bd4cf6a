"""Warehouse domains (even and uneven task assignment), paper §4 and appendix B.1.

The NCA generates the storage area over ``.@e``; :func:`assemble` adds the fixed workstation
columns. Measures: environment entropy of the storage area (K = 3) and the number of
4-connected shelf components. The two variants differ only in the simulator's task assigner
(left workstations 5x as likely in ``uneven``). Scoring: :mod:`nca_qd.scoring.mapf`.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from nca_qd.domains.base import Domain, Evaluator
from nca_qd.errors import NcaQdError
from nca_qd.repair import warehouse as layout

# Seed blocks and their offsets at the paper's sizes are those of the public seed maps, which do
# not centre the rows the same way at both sizes; any other size is centred.
SEED_BLOCK = ["ee", "@@", "ee"]
SEED_OFFSETS = {(33, 32): (15, 15), (101, 98): (50, 48)}


def place_block(shape: tuple[int, int], block: list[str], tiles: str,
                known: dict[tuple[int, int], tuple[int, int]]) -> np.ndarray:
    """An all-empty region of ``shape`` (tile 0) with ``block`` at the centre (or known offset)."""
    bh, bw = len(block), len(block[0])
    h, w = int(shape[0]), int(shape[1])
    if h < bh or w < bw:
        raise NcaQdError(f"a {h}x{w} region cannot hold the {bh}x{bw} seed block")
    r0, c0 = known.get((h, w), ((h - bh) // 2, (w - bw) // 2))
    out = np.zeros((h, w), dtype=np.int32)
    for i, row in enumerate(block):
        for j, ch in enumerate(row):
            out[r0 + i, c0 + j] = tiles.index(ch)
    return out


class WarehouseDomain(Domain):
    """Warehouse with even task assignment (``warehouse_even``)."""

    name = "warehouse_even"
    gen_tiles = layout.GEN_TILES
    layout_tiles = layout.TILES
    palette = layout.PALETTE

    def seed(self, shape: tuple[int, int]) -> np.ndarray:
        return place_block(shape, SEED_BLOCK, self.gen_tiles, SEED_OFFSETS)

    def assemble(self, region: np.ndarray) -> np.ndarray:
        return layout.assemble(region)

    def measures(self, layouts: np.ndarray) -> np.ndarray:
        """``[b, H, W]`` full layouts -> ``[b, 2]``: storage-area entropy, shelf components."""
        from nca_qd.measures import batch_entropy, shelf_components

        layouts = np.asarray(layouts)
        store = layout.storage(layouts)
        ent = np.asarray(batch_entropy(store, len(self.gen_tiles)))
        comps = shelf_components(layouts, layout.SHELF)
        return np.stack([ent, comps], axis=-1)

    def make_evaluator(self, run_cfg: Mapping[str, Any] | None = None) -> Evaluator:
        """Repair -> screen -> exact RHCR (:class:`nca_qd.scoring.mapf.MapfScorer`)."""
        from nca_qd.scoring.mapf import MapfScorer

        return MapfScorer(self, run_cfg)


class WarehouseUnevenDomain(WarehouseDomain):
    """Warehouse whose left workstations are 5x as likely as the right ones (``warehouse_uneven``)."""

    name = "warehouse_uneven"
