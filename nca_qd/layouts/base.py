"""What the pipeline knows about one kind of multi-agent layout, as one object.

A :class:`LayoutKind` holds every fact of a layout family that more than one stage needs: its
tile alphabet and which part the NCA generates, the fixed frame around that part, the seed block,
the picture colours, the task model the simulators follow (blocked tiles, goal kinds with their
dwell times, their cycle), the repair's constraints and how its greedy construction reads them,
the measures, and evaluation defaults. The stages read it by name through the registry
(:func:`nca_qd.layouts.get_layout`); none of them branches on a layout's name.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from nca_qd.errors import NcaQdError
from nca_qd.layouts.rules import Rules


@dataclass(frozen=True)
class GoalKind:
    """One kind of goal of the task model.

    tile: the tile a goal cell holds (``e`` endpoint, ``w`` workstation).
    next_to: if set, a goal cell must also have a 4-neighbour of this tile (manufacturing: an
        endpoint next to a station of the kind).
    dwell: timesteps an agent stays on the goal after arriving before it counts as done.
    left_weight: sampling weight of goal cells in the left half of the map (1: uniform; the
        uneven warehouse's left workstations are 5 times as likely).
    """

    name: str
    tile: str
    next_to: str | None = None
    dwell: int = 0
    left_weight: float = 1.0


@dataclass(frozen=True)
class TaskModel:
    """Lifelong MAPF on a layout: agents stand on every tile but ``blocked``; each agent's goals
    cycle through ``goals`` in order, its first goal being of the first kind."""

    blocked: str
    goals: tuple[GoalKind, ...]


@dataclass(frozen=True)
class Construction:
    """How the repair's greedy construction reads this layout (:mod:`nca_qd.repair.heuristic`):
    ``anchors`` block movement and need an ``endpoint`` neighbour; other cells become ``empty``.
    ``exact_count``: the anchors' count is fixed by a count rule (warehouse shelves); otherwise
    anchors are added while they save distance and each kind must occur (manufacturing)."""

    anchors: tuple[int, ...]
    endpoint: int
    empty: int
    exact_count: bool


class LayoutKind:
    """Facts of one multi-agent layout family; subclasses set the attributes and methods."""

    name: str
    family: str  # subdirectory of the reference maps (warehouse, manufacturing)
    tiles: str  # alphabet of the full layout
    gen_tiles: str  # alphabet of the generated region (a prefix of ``tiles``)
    palette: Mapping[str, str]
    task: TaskModel
    construction: Construction
    seed_block: tuple[str, ...]
    seed_offsets: Mapping[tuple[int, int], tuple[int, int]]  # region shape -> block offset
    eval_agent_step: int  # agent-count step of the S_eval throughput sweep (the paper's)
    frame_cols: int = 0  # fixed columns on each side of the generated region

    # --- shapes and frame ------------------------------------------------------------------
    def full_shape(self, region_shape: tuple[int, int]) -> tuple[int, int]:
        """Full-map shape of a generated region of ``region_shape``."""
        return int(region_shape[0]), int(region_shape[1]) + 2 * self.frame_cols

    def region_shape(self, full_shape: tuple[int, int]) -> tuple[int, int]:
        """The generated region of a full map of ``full_shape``."""
        h, w = int(full_shape[0]), int(full_shape[1])
        if w <= 2 * self.frame_cols:
            raise NcaQdError(f"a {h}x{w} {self.family} map has no generated region")
        return h, w - 2 * self.frame_cols

    def frame(self, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray | None]:
        """``(fixed_mask, fixed_layout)`` of a full map: what repair may not change
        (``fixed_layout`` is None when nothing is fixed)."""
        return np.zeros(shape, dtype=bool), None

    def assemble(self, region: np.ndarray) -> np.ndarray:
        """Generated region(s) ``[..., h, w]`` -> full map(s) with the fixed frame."""
        return np.asarray(region).copy()

    def region(self, layout: np.ndarray) -> np.ndarray:
        """Full map(s) -> the generated region(s)."""
        layout = np.asarray(layout)
        if not self.frame_cols:
            return layout
        return layout[..., :, self.frame_cols : -self.frame_cols]

    def check_frame(self, layout: np.ndarray, source: str) -> None:
        """Raise :class:`NcaQdError` naming ``source`` if the fixed frame is not as required."""

    def seed(self, region_shape: tuple[int, int]) -> np.ndarray:
        """The NCA's initial region: all empty (tile 0) with the seed block at its known offset
        (the public seed maps' at the paper's sizes) or centred."""
        block = self.seed_block
        bh, bw = len(block), len(block[0])
        h, w = int(region_shape[0]), int(region_shape[1])
        if h < bh or w < bw:
            raise NcaQdError(f"a {h}x{w} region cannot hold the {bh}x{bw} seed block")
        r0, c0 = self.seed_offsets.get((h, w), ((h - bh) // 2, (w - bw) // 2))
        out = np.zeros((h, w), dtype=np.int32)
        for i, row in enumerate(block):
            for j, ch in enumerate(row):
                out[r0 + i, c0 + j] = self.gen_tiles.index(ch)
        return out

    # --- repair and measures ---------------------------------------------------------------
    def rules(self, shape: tuple[int, int], *, n_shelves: int | None = None, n_agents: int = 200) -> Rules:
        """Validity of a full map of ``shape`` (the repair's constraints)."""
        raise NotImplementedError

    def aisles(self, layout: np.ndarray) -> np.ndarray | None:
        """``[h, w]`` bool: the cells of ``layout``'s aisles that ``repair(keep_aisles=True)``
        holds as drawn; None where the family has no such notion."""
        return None

    def measures(self, layouts: np.ndarray) -> np.ndarray:
        """``[b, H, W]`` repaired full layouts -> ``[b, m]`` measures."""
        raise NotImplementedError
