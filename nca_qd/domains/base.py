"""What the core needs to know about a domain.

A domain says which tiles exist, which region of the layout the NCA generates (and the fixed
frame around it), the initial (seed) environment for any size, and how a batch of generated
regions is scored (objective and measures). Sizes, NCA iterations, archive dimensions and other
numbers live in the domain's Hydra config (``experiments/conf/domain/<name>.yaml``); the class
holds the behaviour.

Layouts are ``int`` arrays of indices into an alphabet string. ``gen_tiles`` is the alphabet of
the generated region (what the NCA's channels mean); ``layout_tiles`` is the alphabet of the full
layout and starts with ``gen_tiles`` (so a generated index keeps its meaning in the layout), then
adds fixed-only tiles (the warehouse's workstation ``w``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import Any

import numpy as np

from nca_qd.interfaces import EvalBatch, Evaluator, wants_ancillary

__all__ = ["Domain", "EvalBatch", "Evaluator", "wants_ancillary"]


class Domain(ABC):
    """Behaviour of one domain; numbers come from its config (``cfg``)."""

    name: str
    gen_tiles: str
    layout_tiles: str
    # Tile character -> colour (matplotlib colour string) for pictures.
    palette: Mapping[str, str]

    def __init__(self, cfg: Mapping[str, Any]):
        self.cfg = cfg

    @property
    def n_tiles(self) -> int:
        """Number of NCA channels (tile types of the generated region)."""
        return len(self.gen_tiles)

    def gen_shape(self, which: str = "train") -> tuple[int, int]:
        """Shape of the generated region at the training (``train``) or evaluation size."""
        return tuple(self.cfg["size"][which])  # type: ignore[return-value]

    def nca_iters(self, which: str = "train") -> int:
        return int(self.cfg["nca_iters"][which])

    @abstractmethod
    def seed(self, shape: tuple[int, int]) -> np.ndarray:
        """Initial environment ``[h, w]`` (indices into ``gen_tiles``) of the generated region."""

    @abstractmethod
    def assemble(self, region: np.ndarray) -> np.ndarray:
        """Generated region(s) ``[..., h, w]`` -> full layout(s) in ``layout_tiles`` indices."""

    @abstractmethod
    def make_evaluator(self, run_cfg: Mapping[str, Any] | None = None) -> Evaluator:
        """A batched scorer for generated regions, built once (jit compile happens here).
        ``run_cfg`` is the whole run config (its ``eval`` block: evaluation backend, screening)."""

    @property
    def measure_names(self) -> list[str]:
        return list(self.cfg["measures"]["names"])
