"""What the parts of the screen benchmark share: the paper's 33x36 maps, the synthetic layout
set (:mod:`nca_qd.calibration.layout_set`, drawn with seed 1 here: held out from the screen's
calibration) and exact RHCR's node budget and the free-flow estimate's constants.

``BENCH_SCREEN_PBS_MAX_NODES`` sets exact RHCR's per-call node budget (default RHCR's ``auto``;
2000 is the search's, which reaches the same verdicts at a fraction of the cost);
``BENCH_SCREEN_EFFICIENCY`` RHCR's share of free-flow throughput where it flows (default 0.932,
measured on 278 layouts of the warehouse search's memo).
"""

from __future__ import annotations

import os
from pathlib import Path

from nca_qd.calibration import layout_set
from nca_qd.calibration.layout_set import SCENARIO, SEEDS

MAPS = Path("/work/shared/reference/maps/warehouse")
_NODES = os.environ.get("BENCH_SCREEN_PBS_MAX_NODES", "auto")
PBS_MAX_NODES: int | str = int(_NODES) if _NODES.isdigit() else _NODES
# RHCR's share of free-flow throughput where it flows (warehouse even, 33x36, 200 agents),
# measured on the warehouse search's memo; the screen's scale for congested runs.
EFFICIENCY = float(os.environ.get("BENCH_SCREEN_EFFICIENCY", 0.932))
CONGESTED_SCALE = 1.3  # the scaled screen's (eval.screen_scale)


def _maps() -> Path | None:
    """The folder of the paper's 33x36 warehouse maps (``NCA_QD_MAPS``/warehouse, else the
    shared reference copy), or None."""
    env = os.environ.get("NCA_QD_MAPS")
    for d in ([Path(env) / "warehouse"] if env else []) + [MAPS]:
        if (d / "human_33x36.json").is_file():
            return d
    return None


def _load(name: str) -> list[str] | None:
    maps = _maps()
    return None if maps is None else layout_set._load(maps, name)


def make_layouts(n_min: int = 40, seed: int = 1) -> list[tuple[str, list[str]]]:
    return layout_set.make_layouts(_maps(), n_min, seed)


def rhcr_figures(layouts, cache: str | None, seeds: list[int] = SEEDS, scenario: str = SCENARIO) -> dict:
    return layout_set.rhcr_figures(layouts, cache, seeds, scenario, PBS_MAX_NODES)


def _planners() -> list[str]:
    return [p for p in os.environ.get("BENCH_SCREEN_PLANNERS", "pibt,windowed").split(",") if p]
