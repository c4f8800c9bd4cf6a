"""The ``eval`` block of a search's run config as typed settings of its scoring (validated once).

:class:`ScoringConfig` is what :class:`nca_qd.scoring.mapf.MapfScorer` reads: whether to screen,
which layouts get exact runs, how the screen's prediction is formed, and the exact planner's
knobs. A bad value is one clear line (:class:`~nca_qd.errors.NcaQdError`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from nca_qd.errors import NcaQdError, require_bool
from nca_qd.sim.free_flow import CONGESTED_MODEL
from nca_qd.sim.rhcr import planner_options

EXACT_POLICIES = ("selective", "all")
SCREEN_ESTIMATES = ("scaled", "free_flow")


@dataclass(frozen=True)
class ScoringConfig:
    """The ``eval`` block of a run config, validated (backend keys are read by the backend)."""

    screen: bool = True
    exact: str = "selective"
    screen_scale: float = 1.3
    # scaled: screened throughput x screen_scale; free_flow: nca_qd.sim.free_flow.rhcr_estimate.
    # Defaults here are the YAML's (experiments/conf/run.yaml, tested); a run saved before a key
    # existed is read through nca_qd.run_dir.migrate, not through a differing default.
    screen_estimate: str = "free_flow"
    screen_efficiency: float = 0.932
    # (free_flow) a + b * screened throughput / free flow + c * stop time / T: RHCR's share of
    # free flow on a layout with a congested screened run
    screen_congested: tuple[float, float, float] = CONGESTED_MODEL
    exact_margin: float = 0.1
    exact_random_share: float = 0.1
    exact_time_limit_s: float | None = None
    screen_empty_cells: bool = False
    memo: bool = True
    # exact planner knobs (nca_qd.sim.rhcr.PLANNER_KEYS, each named in run.yaml) for the search's
    # runs, as planner_options keys them: a knob at RHCR's own behaviour is left out, so keys and
    # memo fingerprints of runs made before it was named stay valid
    planner: dict[str, Any] = field(default_factory=dict)
    # NCA phases scored per generator, C .. C + phases - 1; it gets the lowest (1: the paper's)
    phases: int = 1

    @classmethod
    def from_cfg(cls, cfg: Mapping[str, Any] | None) -> ScoringConfig:
        cfg = dict(cfg or {})
        exact = str(cfg.get("exact", cls.exact))
        if exact not in EXACT_POLICIES:
            raise NcaQdError(f"eval.exact must be one of {', '.join(EXACT_POLICIES)}, got {exact!r}")
        estimate = str(cfg.get("screen_estimate", cls.screen_estimate))
        if estimate not in SCREEN_ESTIMATES:
            raise NcaQdError(
                f"eval.screen_estimate must be one of {', '.join(SCREEN_ESTIMATES)}, got {estimate!r}"
            )
        for name in ("screen", "screen_empty_cells", "memo"):
            if name in cfg:
                require_bool(f"eval.{name}", cfg[name])
        screen = bool(cfg.get("screen", cls.screen))
        out = cls(
            screen=screen,
            exact=exact if screen else "all",
            screen_scale=float(cfg.get("screen_scale", cls.screen_scale)),
            screen_estimate=estimate,
            screen_efficiency=float(cfg.get("screen_efficiency", cls.screen_efficiency)),
            screen_congested=_three_numbers(cfg.get("screen_congested", cls.screen_congested)),
            exact_margin=float(cfg.get("exact_margin", cls.exact_margin)),
            exact_random_share=float(cfg.get("exact_random_share", cls.exact_random_share)),
            exact_time_limit_s=(
                None if cfg.get("exact_time_limit_s") is None else float(cfg["exact_time_limit_s"])
            ),
            screen_empty_cells=bool(cfg.get("screen_empty_cells", cls.screen_empty_cells)),
            memo=bool(cfg.get("memo", cls.memo)),
            planner=planner_options(cfg, "eval."),
            phases=_phases(cfg.get("phases", cls.phases)),
        )
        if not 0.0 <= out.exact_random_share <= 1.0:
            raise NcaQdError(f"eval.exact_random_share must be in [0, 1], got {out.exact_random_share}")
        if out.screen_scale <= 0:
            raise NcaQdError(f"eval.screen_scale must be positive, got {out.screen_scale}")
        if not 0.0 < out.screen_efficiency <= 1.0:
            raise NcaQdError(f"eval.screen_efficiency must be in (0, 1], got {out.screen_efficiency}")
        return out


def _three_numbers(value: Any) -> tuple[float, float, float]:
    """``eval.screen_congested`` as ``(a, b, c)``: three finite numbers."""
    try:
        out = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        out = ()
    if len(out) != 3 or not all(np.isfinite(out)):
        raise NcaQdError(f"eval.screen_congested must be three finite numbers [a, b, c], got {value!r}")
    return out  # type: ignore[return-value]


def _phases(value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise NcaQdError(f"eval.phases must be an integer >= 1, got {value!r}")
    return value
