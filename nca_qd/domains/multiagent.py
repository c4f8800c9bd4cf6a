"""The multi-agent domains (warehouse even / uneven, manufacturing; paper §4, appendix B).

One class serves them all: what differs between them is data, the layout family's facts in
:mod:`nca_qd.layouts` (tiles, frame, seed block, palette, measures, task model, repair rules),
and the numbers in ``experiments/conf/domain/<name>.yaml``. Scoring: repair -> screen -> exact
RHCR (:class:`nca_qd.scoring.mapf.MapfScorer`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from nca_qd.domains.base import Domain, Evaluator
from nca_qd.layouts import LayoutKind, get_layout


class MultiAgentDomain(Domain):
    """A domain whose layouts robots work in: the registered :class:`LayoutKind` of ``name``."""

    def __init__(self, cfg: Mapping[str, Any]):
        super().__init__(cfg)
        self.layout: LayoutKind = get_layout(str(cfg["name"]), "domain")
        self.name = self.layout.name
        self.gen_tiles = self.layout.gen_tiles
        self.layout_tiles = self.layout.tiles
        self.palette = self.layout.palette
        # The training size only: every evaluation of a search repairs there. At S_eval an
        # impossible count is a row of the evaluation's summary ("infeasible"), not an error.
        if cfg.get("size") is not None and cfg["size"].get("train") is not None:
            self._check_possible(cfg, "train")

    def _check_possible(self, cfg: Mapping[str, Any], which: str) -> None:
        """Refuse sizes where no valid layout exists (every repair would fail and a search
        would run to its end with an empty archive): more tiles required than the map holds."""
        from nca_qd.errors import NcaQdError
        from nca_qd.repair import count_shortfall, make_rules

        shape = self.assemble(np.zeros(self.gen_shape(which), dtype=np.int32)).shape
        rep = cfg.get("repair") or {}
        n_shelves = (rep.get("n_shelves") or {}).get(which)
        n_agents = int((cfg.get("n_agents") or {}).get(which) or 1)
        short = count_shortfall(make_rules(self.name, shape, n_shelves=n_shelves, n_agents=n_agents))
        if short is not None:
            rule, room = short
            names = "".join(self.layout_tiles[int(t)] for t in rule.tiles)
            raise NcaQdError(
                f"domain.size.{which}={list(self.gen_shape(which))}: no valid layout exists "
                f"({rule.value} tiles of {names!r} required, room for {room})"
            )

    @classmethod
    def for_layout(cls, name: str) -> type[MultiAgentDomain]:
        """A subclass whose class attributes (tiles, palette) are those of layout ``name``, for
        readers that need them without a config (``domain_class``)."""
        kind = get_layout(name, "domain")
        return type(
            f"MultiAgentDomain[{name}]",
            (cls,),
            {
                "name": kind.name,
                "gen_tiles": kind.gen_tiles,
                "layout_tiles": kind.tiles,
                "palette": kind.palette,
            },
        )

    def seed(self, shape: tuple[int, int]) -> np.ndarray:
        return self.layout.seed(shape)

    def assemble(self, region: np.ndarray) -> np.ndarray:
        return self.layout.assemble(region)

    def measures(self, layouts: np.ndarray) -> np.ndarray:
        """``[b, H, W]`` repaired full layouts -> ``[b, m]`` (the layout family's measures)."""
        return self.layout.measures(layouts)

    def make_evaluator(self, run_cfg: Mapping[str, Any] | None = None) -> Evaluator:
        """Repair -> screen -> exact RHCR (:class:`nca_qd.scoring.mapf.MapfScorer`)."""
        from nca_qd.scoring.mapf import MapfScorer

        return MapfScorer(self, run_cfg)
