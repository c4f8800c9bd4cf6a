"""Unit jobs of the MAPF pipeline: repair one layout, simulate one layout with exact RHCR.

Plain functions of plain data (numpy arrays, dicts, strings), importable without JAX, so a
process-pool or Dask worker runs them cheaply and returns small results. Each catches the
errors a generated layout can cause and reports them in its result instead of raising: one bad
layout must not stop a QD run (it is recorded as failed and the run goes on).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

# The domain config's repair keys that :func:`nca_qd.repair.repair` takes as options.
REPAIR_OPTIONS = (
    "method",
    "tie_break",
    "time_limit_s",
    "improve_time_s",
    "improve_windows",
    "window",
    "window_time_s",
    "max_window_cells",
    "max_violation_fraction",
    "threads",
    "seed",
    "milp_time_s",
)


def repair_options(domain_cfg: Mapping[str, Any], which: str = "train") -> dict[str, Any]:
    """Keyword arguments of :func:`nca_qd.repair.repair` for the domain at size ``which``
    (``train`` or ``eval``): its repair block, N_s of that size (warehouse) and the agent
    count of that size (manufacturing needs as many traversable tiles). An option may differ by
    size: ``method: {train: hybrid, eval: neighbourhood}``."""
    rep = domain_cfg["repair"]
    opts = {}
    for k in REPAIR_OPTIONS:
        value = rep.get(k)
        if isinstance(value, Mapping):
            value = value.get(which)
        if value is not None:
            opts[k] = value
    n_shelves = rep.get("n_shelves")
    if n_shelves is not None and n_shelves.get(which) is not None:
        opts["n_shelves"] = int(n_shelves[which])
    opts["n_agents"] = int(domain_cfg["n_agents"][which])
    return opts


@dataclass
class RepairOutcome:
    """What a repair job returns: the layout (None when no valid layout was found)."""

    layout: np.ndarray | None
    status: str
    similarity: float
    hamming: int | None
    seconds: float
    error: str | None = None


def repair_task(domain_name: str, layout: np.ndarray, options: Mapping[str, Any]) -> RepairOutcome:
    """Repair one full layout; errors become ``status='error'`` with the message."""
    from nca_qd.errors import NcaQdError
    from nca_qd.repair import repair

    t0 = time.perf_counter()
    try:
        res = repair(domain_name, np.asarray(layout), **dict(options))
    except NcaQdError as exc:
        return RepairOutcome(None, "error", 0.0, None, time.perf_counter() - t0, str(exc))
    return RepairOutcome(res.layout, res.status, float(res.similarity), res.hamming, res.seconds)


@dataclass
class ExactOutcome:
    """What an exact-simulation job returns (no paths: small enough to ship between hosts)."""

    seed: int
    throughput: float
    success: bool
    stop_time: int
    cpu_seconds: float
    tasks_per_step: np.ndarray | None = None
    tile_visits: np.ndarray | None = None
    error: str | None = None


def rhcr_task(
    rows: list[str],
    scenario: str,
    n_agents: int,
    T: int,
    seed: int,
    time_limit_s: float | None = None,
    detail: bool = False,
    planner: Mapping[str, Any] | None = None,
) -> ExactOutcome:
    """One exact RHCR run; ``detail`` adds tasks per timestep and tile visits; ``planner``
    holds validated planner knobs (:func:`nca_qd.sim.rhcr.planner_options`)."""
    from nca_qd.errors import NcaQdError
    from nca_qd.sim.rhcr import simulate

    try:
        r = simulate(rows, scenario, n_agents, T, seed, time_limit_s=time_limit_s, **dict(planner or {}))
    except NcaQdError as exc:
        return ExactOutcome(seed, 0.0, False, 0, 0.0, error=str(exc))
    return ExactOutcome(
        seed,
        r.throughput,
        r.success,
        r.stop_time,
        r.cpu_seconds,
        r.tasks_per_step if detail else None,
        r.tile_visits if detail else None,
    )
