"""The unit jobs every caller of the simulators shares: repair one layout, run one layout once
with exact RHCR. The search (:mod:`nca_qd.scoring.mapf`), the evaluation
(:mod:`nca_qd.evaluation.runs`) and the benchmarks submit these same jobs, so a new planner
setting or simulator version is threaded through one place.

Plain functions of plain data (numpy arrays, dicts, strings, frozen dataclasses), importable
without JAX, so a process-pool or Dask worker runs them cheaply and returns small results. Each
catches the errors a generated layout can cause and reports them in its result instead of
raising: one bad layout must not stop a QD run (it is recorded as failed and the run goes on).
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
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
    "connectivity",
    "keep_aisles",
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


def repair_job(domain_name: str, layout: np.ndarray, options: Mapping[str, Any]) -> RepairOutcome:
    """Repair one full layout; errors become ``status='error'`` with the message."""
    from nca_qd.errors import NcaQdError
    from nca_qd.repair import repair

    t0 = time.perf_counter()
    try:
        res = repair(domain_name, np.asarray(layout), **dict(options))
    except NcaQdError as exc:
        return RepairOutcome(None, "error", 0.0, None, time.perf_counter() - t0, str(exc))
    return RepairOutcome(res.layout, res.status, float(res.similarity), res.hamming, res.seconds)


@dataclass(frozen=True)
class ExactSettings:
    """How an exact RHCR run runs, whoever asks for it: horizon ``T``, wall-clock limit (None:
    none), RHCR's planning window ``w`` and replanning period ``h``, and the validated planner
    knobs (:func:`nca_qd.sim.rhcr.planner_options`; missing: the simulator's defaults)."""

    T: int
    time_limit_s: float | None
    window: int
    replan: int
    planner: Mapping[str, Any]


@dataclass
class RunOutcome:
    """One simulation run, whichever simulator ran it (``rhcr`` or ``screen``); no paths, so it
    is small enough to ship between hosts. ``seconds``: the job's wall-clock time;
    ``cpu_seconds``: the simulator's own CPU time (exact runs); ``tasks_per_step`` and
    ``tile_visits`` only when the caller asked for the detail."""

    simulator: str
    seed: int
    throughput: float = float("nan")
    success: bool = False
    stop_time: int = 0
    timed_out: bool = False
    seconds: float = 0.0
    error: str | None = None
    tasks_per_step: np.ndarray | None = field(default=None, repr=False)
    tile_visits: np.ndarray | None = field(default=None, repr=False)
    cpu_seconds: float = 0.0

    @property
    def completed(self) -> bool:
        """The run ended (no error, no time limit): its throughput and verdict are results."""
        return self.error is None and not self.timed_out


def exact_job(
    rows: Sequence[str],
    scenario: str,
    n_agents: int,
    seed: int,
    settings: ExactSettings,
    detail: bool = False,
) -> RunOutcome:
    """One exact RHCR run; ``detail`` keeps tasks per timestep and tile visits. The layout's
    errors (unreachable goals, too many agents, ...) come back in ``error``."""
    from nca_qd.errors import NcaQdError
    from nca_qd.sim.rhcr import simulate

    t0 = time.perf_counter()
    try:
        r = simulate(
            rows,
            scenario,
            n_agents,
            settings.T,
            seed,
            window=settings.window,
            replan=settings.replan,
            time_limit_s=settings.time_limit_s,
            **dict(settings.planner),
        )
    except NcaQdError as exc:
        return RunOutcome("rhcr", seed, error=str(exc), seconds=time.perf_counter() - t0)
    return RunOutcome(
        "rhcr",
        seed,
        float(r.throughput),
        bool(r.success),
        int(r.stop_time),
        bool(r.timed_out),
        time.perf_counter() - t0,
        None,
        np.asarray(r.tasks_per_step) if detail else None,
        np.asarray(r.tile_visits) if detail else None,
        float(r.cpu_seconds),
    )
