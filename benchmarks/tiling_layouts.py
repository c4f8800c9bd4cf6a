"""Where a repair put the shelves of a tiling baseline: layouts set against the plain tiling.

    python -m benchmarks.tiling_layouts ../shared/reference/maps/warehouse/paper_cma-mae_a5_even_33x36.json \
        paper_code/maps/warehouse/human/kiva_101x102_tile_baseline_repaired.json \
        results/warehouse_even_qd/tiling_check/paper_s_tiled_101x102_ns2500.json

The tiling baseline tiles a small layout to the large size and repairs it to the large size's
shelf count; when that count is above what the tiling holds (the paper's code asks for 2,500
where the tiled 33x36 layout holds 2,251), the repair must add shelves, and many equally near
repairs place them differently. Two repairs at the same Hamming distance can then differ in
where their aisles are cut. For each layout this prints (one JSON line) its shelves, its Hamming
distance to the plain tiling of ``base`` (:func:`nca_qd.evaluation.layouts.tile_layout`, the
evaluation's own), the shelves added and removed against it, the dead ends (traversable tiles
with at most one traversable neighbour: where an aisle was cut), and both by band of
``--band`` rows from the top, so that a repair that piles its changes into one part of the map
shows as such.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from benchmarks.cli import guarded
from nca_qd.errors import NcaQdError
from nca_qd.evaluation.layouts import tile_layout
from nca_qd.io import load_map
from nca_qd.repair import tiles_of


def dead_ends(free: np.ndarray) -> np.ndarray:
    """Traversable tiles with at most one traversable 4-neighbour."""
    pad = np.pad(free, 1)
    nbrs = pad[:-2, 1:-1].astype(int) + pad[2:, 1:-1] + pad[1:-1, :-2] + pad[1:-1, 2:]
    return free & (nbrs <= 1)


def by_band(mask: np.ndarray, band: int) -> list[int]:
    return [int(mask[r : r + band].sum()) for r in range(0, mask.shape[0], band)]


def describe(path: Path, plain: np.ndarray, tiles: str, band: int) -> dict:
    layout = load_map(path, tiles).to_array(tiles)
    if layout.shape != plain.shape:
        raise NcaQdError(
            f"{path}: {layout.shape[0]}x{layout.shape[1]}, the tiling is {plain.shape[0]}x{plain.shape[1]}"
        )
    shelf = tiles.index("@")
    added = (layout == shelf) & (plain != shelf)
    removed = (layout != shelf) & (plain == shelf)
    ends = dead_ends(layout != shelf)
    return {
        "layout": path.name,
        "shelves": int((layout == shelf).sum()),
        "hamming_to_tiling": int((layout != plain).sum()),
        "shelves_added": int(added.sum()),
        "shelves_removed": int(removed.sum()),
        "dead_ends": int(ends.sum()),
        "added_by_band": by_band(added, band),
        "dead_ends_by_band": by_band(ends, band),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("base", type=Path, help="the small layout that was tiled")
    p.add_argument("layouts", nargs="+", type=Path, help="tiled and repaired layouts, all of one size")
    p.add_argument("--domain", default="warehouse_even")
    p.add_argument("--band", type=int, default=20, help="rows per band")
    args = p.parse_args(argv)
    return guarded(lambda: _describe_all(args))


def _describe_all(args: argparse.Namespace) -> None:
    if args.band < 1:
        raise NcaQdError(f"--band must be >= 1, got {args.band}")
    tiles = tiles_of(args.domain)
    small = load_map(args.base, tiles).to_array(tiles)
    size = load_map(args.layouts[0], tiles).to_array(tiles).shape
    plain = tile_layout(args.domain, small, list(size))
    shelves = int((plain == tiles.index("@")).sum())
    print(json.dumps({"layout": f"{args.base.name} tiled", "shelves": shelves}))
    for path in args.layouts:
        print(json.dumps(describe(path, plain, tiles, args.band)), flush=True)


if __name__ == "__main__":
    raise SystemExit(main())
