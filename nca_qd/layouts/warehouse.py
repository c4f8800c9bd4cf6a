"""Warehouse layouts (paper §4 and appendix B.1): every fact of the family in one place.

The full warehouse map is the NCA's storage area (tiles ``.@e``) with two fixed columns on each
side: workstations ``w`` in the outer column at rows i with (i - 1) mod 3 == 0 (first and last
row excluded) and an empty column next to them (the human layouts). The repair keeps that frame
unchanged and may change every storage cell; a valid layout has exactly N_s shelves, every
shelf next to an endpoint and every endpoint next to a shelf, and its traversable tiles
connected. Task model: everything but shelves is traversable; goals alternate endpoint
(uniform) and workstation (uniform in ``warehouse_even``; in ``warehouse_uneven`` the left
workstations are 5 times as likely). Measures: environment entropy of the storage area (K = 3)
and the number of 4-connected shelf components.
"""

from __future__ import annotations

import numpy as np

from nca_qd import memory
from nca_qd.errors import NcaQdError
from nca_qd.layouts.base import Construction, GoalKind, LayoutKind, TaskModel
from nca_qd.layouts.rules import AdjacencyRule, CountRule, Rules

TILES = ".@ew"  # layout alphabet; the storage area (NCA) uses the first three
GEN_TILES = ".@e"
EMPTY, SHELF, ENDPOINT, WORKSTATION = range(4)
FRAME = 2  # fixed columns on each side

# Shelves of the human-designed layout of each full-map size (N_s of the paper and its appendix).
SHELVES_BY_SIZE: dict[tuple[int, int], int] = {
    (33, 36): 240,
    (45, 47): 440,
    (57, 58): 700,
    (69, 69): 1020,
    (81, 80): 1400,
    (93, 91): 1840,
    (101, 102): 2250,
}


def full_shape(storage_shape: tuple[int, int]) -> tuple[int, int]:
    return storage_shape[0], storage_shape[1] + 2 * FRAME


def frame(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """``(fixed_mask, fixed_layout)`` of a full map of ``shape``: the workstation columns."""
    h, w = shape
    fixed = np.zeros(shape, dtype=bool)
    fixed[:, :FRAME] = True
    fixed[:, w - FRAME :] = True
    lay = np.full(shape, EMPTY, dtype=np.int32)
    rows = [i for i in range(1, h - 1) if (i - 1) % 3 == 0]
    lay[rows, 0] = WORKSTATION
    lay[rows, w - 1] = WORKSTATION
    return fixed, lay


def assemble(region: np.ndarray) -> np.ndarray:
    """Storage area(s) ``[..., h, w]`` -> full map(s) ``[..., h, w + 4]`` with the frame."""
    region = np.asarray(region)
    h, w = region.shape[-2:]
    _, lay = frame(full_shape((h, w)))
    out = np.broadcast_to(lay, region.shape[:-2] + lay.shape).copy()
    out[..., :, FRAME : FRAME + w] = region
    return out


def storage(layout: np.ndarray) -> np.ndarray:
    """Full map(s) -> storage area(s) (the NCA's region)."""
    return np.asarray(layout)[..., :, FRAME:-FRAME]


def aisle_rows(layout: np.ndarray) -> np.ndarray:
    """``[h, w]`` bool: the storage cells of the rows that hold no shelf (the corridors that
    lead to the workstation columns), for ``repair(keep_aisles=True)``."""
    layout = np.asarray(layout)
    mask = np.zeros(layout.shape, dtype=bool)
    mask[~(storage(layout) == SHELF).any(axis=1), FRAME:-FRAME] = True
    return mask


def human_layout(shape: tuple[int, int]) -> np.ndarray:
    """The human-designed warehouse of any full-map size, as the paper's appendix draws them:
    the frame (workstation columns), then rows repeating [aisle, endpoints, shelves, endpoints]
    from the first row (rows after the last aisle that cannot hold a whole block stay aisles)
    and, across, shelf blocks 10 cells long between one-cell aisles (a last block may be
    shorter). It reproduces the paper's seven human maps, 33x36 ... 101x102, cell for cell."""
    h, w = int(shape[0]), int(shape[1])
    if h < 5 or w < 2 * FRAME + 1:
        raise NcaQdError(
            f"a human-designed warehouse needs at least 5 rows and {2 * FRAME + 1} columns, got {h}x{w}"
        )
    memory.check(memory.human_bytes(h * w), f"a {h}x{w} human-designed warehouse")
    _, lay = frame((h, w))
    cols = np.arange(FRAME, w - FRAME)
    cols = cols[(cols - FRAME) % 11 != 10]
    for r in range(1, 4 * ((h - 1) // 4)):
        if r % 4:
            lay[r, cols] = SHELF if r % 4 == 2 else ENDPOINT
    return lay


def default_shelves(shape: tuple[int, int]) -> int:
    """N_s for a full map of ``shape``: the human-designed layout's shelf count at the paper's
    sizes. Elsewhere the caller names it (the error says what :func:`human_layout` holds there):
    a repair that silently took a count the user did not choose would move their layout."""
    key = (int(shape[0]), int(shape[1]))
    if key not in SHELVES_BY_SIZE:
        sizes = ", ".join(f"{h}x{w}" for h, w in SHELVES_BY_SIZE)
        human = ""
        if key[0] >= 5 and key[1] >= 2 * FRAME + 1:
            human = (
                f"; the human-designed layout of that size holds {int((human_layout(key) == SHELF).sum())}"
            )
        raise NcaQdError(
            f"no default shelf count for a {key[0]}x{key[1]} warehouse (known sizes: {sizes}); "
            f"give n_shelves=<N>{human}"
        )
    return SHELVES_BY_SIZE[key]


def rules(shape: tuple[int, int], n_shelves: int | None = None) -> Rules:
    """Validity of a full warehouse map of ``shape`` with ``n_shelves`` shelves (None: by size)."""
    if shape[1] <= 2 * FRAME or shape[0] < 3:
        raise NcaQdError(
            f"a warehouse map needs at least 3 rows and {2 * FRAME + 1} columns, got {shape[0]}x{shape[1]}"
        )
    n = default_shelves(shape) if n_shelves is None else int(n_shelves)
    fixed, lay = frame(shape)
    return Rules(
        tiles=TILES,
        passable=frozenset({EMPTY, ENDPOINT}),
        reach_only=frozenset({WORKSTATION}),
        free_tiles=(EMPTY, SHELF, ENDPOINT),
        adjacency=(
            AdjacencyRule(frozenset({SHELF}), frozenset({ENDPOINT}), "shelf without an endpoint"),
            AdjacencyRule(frozenset({ENDPOINT}), frozenset({SHELF}), "endpoint without a shelf"),
        ),
        counts=(CountRule(frozenset({SHELF}), "==", n, "shelves"),),
        fixed=fixed,
        fixed_layout=lay,
    )


def check_frame(layout: np.ndarray, source: str) -> None:
    """Raise :class:`NcaQdError` naming ``source`` if the workstation columns are not as required."""
    fixed, lay = frame(layout.shape)
    bad = np.argwhere(fixed & (layout != lay))
    if len(bad):
        r, c = bad[0]
        raise NcaQdError(
            f"{source}: workstation column not as the warehouse requires at row {r}, "
            f"column {c}: {TILES[layout[r, c]]!r}, expected {TILES[lay[r, c]]!r}"
        )
    inner = np.argwhere(~fixed & (layout == WORKSTATION))
    if len(inner):
        r, c = inner[0]
        raise NcaQdError(f"{source}: workstation 'w' inside the storage area at row {r}, column {c}")


# Paper colours: shelves black, endpoints blue, workstations pink, empty white.
PALETTE = {".": "white", "@": "black", "e": "#3b6fd6", "w": "#f29ec8"}

# The NCA's seed: this block on an empty storage area, at the public seed maps' offsets at the
# paper's sizes (they do not centre the rows the same way at both sizes); centred elsewhere.
SEED_BLOCK = ("ee", "@@", "ee")
SEED_OFFSETS = {(33, 32): (15, 15), (101, 98): (50, 48)}
UNEVEN_LEFT_WEIGHT = 5.0


class Warehouse(LayoutKind):
    """A warehouse with even or uneven workstation traffic (``left_weight``)."""

    family = "warehouse"
    tiles = TILES
    gen_tiles = GEN_TILES
    palette = PALETTE
    construction = Construction(anchors=(SHELF,), endpoint=ENDPOINT, empty=EMPTY, exact_count=True)
    seed_block = SEED_BLOCK
    seed_offsets = SEED_OFFSETS
    eval_agent_step = 25
    frame_cols = FRAME

    def __init__(self, name: str, left_weight: float = 1.0):
        self.name = name
        self.task = TaskModel(
            blocked="@",
            goals=(GoalKind("endpoint", "e"), GoalKind("workstation", "w", left_weight=left_weight)),
        )

    def frame(self, shape):
        return frame(shape)

    def assemble(self, region):
        return assemble(region)

    def check_frame(self, layout, source):
        check_frame(layout, source)

    def rules(self, shape, *, n_shelves=None, n_agents=200):
        return rules(shape, n_shelves=n_shelves)

    def aisles(self, layout):
        return aisle_rows(layout)

    def measures(self, layouts):
        """Storage-area entropy and shelf components ``[b, 2]``."""
        from nca_qd.measures import batch_entropy, shelf_components

        layouts = np.asarray(layouts)
        ent = np.asarray(batch_entropy(storage(layouts), len(GEN_TILES)))
        return np.stack([ent, shelf_components(layouts, SHELF)], axis=-1)


EVEN = Warehouse("warehouse_even")
UNEVEN = Warehouse("warehouse_uneven", left_weight=UNEVEN_LEFT_WEIGHT)
