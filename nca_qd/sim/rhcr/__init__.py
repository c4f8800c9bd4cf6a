"""Exact lifelong-MAPF simulation with RHCR (Li et al., AAAI 2021), compiled core; lifelong
PIBT (Okumura et al., AIJ 2022) beside it as a second planner (``planner="pibt"``: one step per
call, no window, the same task model and congestion rule; ``src/pibt.hpp``), so that a layout can
be judged under two planners.

Every ``replan`` (h) timesteps RHCR plans collision-free paths for all agents over the next
``window`` (w) timesteps with windowed Priority-Based Search (Ma et al. 2019) over a
space-time A* on a reservation table (heuristic: true distances along each agent's goal
queue), executes h steps and repeats. The planner follows RHCR's public implementation as the
paper ran it (PBS with ``prioritize_start``, a per-call time limit, LRA*-style repair of a
failed call); ``src/pbs.hpp`` lists its decisions. :data:`VERSION` changes whenever a change
alters simulated outcomes, so cached results of another planner are never reused. The work happens
in C++ (``src/``, module ``_core``),
which releases the GIL, so :func:`simulate_many` runs seeds in parallel threads.

>>> r = simulate(rows, "warehouse_even", n_agents=200, T=1000, seed=0)
>>> r.throughput, r.success
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from nca_qd import memory
from nca_qd.errors import NcaQdError, require_bool
from nca_qd.sim.result import RunResult
from nca_qd.sim.scenario import Scenario, build_scenario

try:
    from nca_qd.sim.rhcr import _core
except ImportError as exc:  # pragma: no cover - only when the package was not built
    raise ImportError(
        "nca_qd.sim.rhcr._core is not built; run `make .venv/.installed` "
        f"(pip install -e .) to compile it ({exc})"
    ) from exc

__all__ = [
    "PLANNERS",
    "planner_title",
    "PLANNER_KEYS",
    "STARTS",
    "SimResult",
    "VERSION",
    "planner_options",
    "simulate",
    "simulate_many",
    "simulate_scenario",
]

VERSION: int = int(_core.VERSION)
# RHCR's planning window w and replanning period h as the paper ran it (its appendix: w = 10,
# h = 5); the search's exact runs use them, the evaluation reads its own from evaluate.yaml.
WINDOW, REPLAN = 10, 5


@dataclass
class SimResult(RunResult):
    """Outcome of one exact RHCR run (fields of :class:`~nca_qd.sim.result.RunResult` plus the
    planner's counters)."""

    replans: int = 0
    pbs_failures: int = 0
    call_nodes: np.ndarray | None = None  # per planning call: PBS nodes expanded
    call_cpu_seconds: np.ndarray | None = None  # per planning call: CPU seconds
    call_failed: np.ndarray | None = None  # per planning call: PBS failed (repaired)
    call_expansions: np.ndarray | None = None  # per planning call: A* expansions
    pbs_nodes: int = 0
    low_level_expansions: int = 0

    def summary(self) -> dict:
        return {**super().summary(), "pbs_failures": self.pbs_failures}


def simulate(
    rows: Sequence[str], scenario: str, n_agents: int, T: int, seed: int, **options: Any
) -> SimResult:
    """Simulate ``n_agents`` agents on the layout ``rows`` for ``T`` timesteps: the layout
    becomes a :class:`Scenario` of the named task model, then :func:`simulate_scenario` runs it
    with ``options`` (the one place that names the simulator's settings).

    Raises :class:`NcaQdError` for bad input (unknown scenario or tiles, unreachable goals,
    too many agents, non-positive horizon or window)."""
    return simulate_scenario(
        build_scenario(list(rows), scenario, n_agents=n_agents), n_agents, T, seed, **options
    )


def simulate_scenario(
    scen: Scenario,
    n_agents: int,
    T: int,
    seed: int,
    window: int = WINDOW,
    replan: int = REPLAN,
    time_limit_s: float | None = None,
    record_paths: bool = False,
    pbs_max_nodes: int | str | None = "auto",
    plan_time_limit_s: float | None = 60.0,
    prioritize_start: bool = True,
    reference_starts: bool = False,
    plan_max_expansions: int | None = None,
    planner: str = "rhcr",
) -> SimResult:
    """Simulate ``n_agents`` agents on the scenario ``scen`` for ``T`` timesteps (RHCR: windowed
    PBS with space-time A*, replanning every ``replan`` steps over ``window`` steps).

    Raises :class:`NcaQdError` for bad input (unknown scenario or tiles, unreachable goals,
    too many agents, non-positive horizon or window). ``time_limit_s`` bounds the wall-clock
    time; a run that hits it stops with ``timed_out=True`` and ``success=False``.
    ``plan_time_limit_s`` bounds one planning call in CPU seconds (RHCR's cutoff, 60 s in the
    paper; ``None``: none) and ``pbs_max_nodes`` its high-level PBS nodes (``None``: none;
    ``"auto"``: 7,000,000 / ``n_agents``, at least 1,000 -- the nodes the reference RHCR
    expands within its 60 s at 1,400 agents, where it spends 6-26 ms per node; our nodes are
    10-100 times cheaper, so a time limit alone would search far longer than the paper's
    planner could). ``plan_max_expansions`` bounds a call's A* expansions (``None``: no bound),
    a bound on work that, unlike the CPU-time cutoff, stops a jammed call at the same point on
    any machine. A call that hits any of them is repaired and counted in ``pbs_failures``.
    ``planner="pibt"`` plans one step at a time with PIBT instead (``window`` and the PBS knobs
    unused; ``replan`` is the congestion rule's period, as in RHCR); ``planner="pibt_swap"``
    with PIBT with swap (LaCAM3's PIBT: two agents that must pass each other in a one-lane
    corridor back up together to a branch, where plain PIBT deadlocks).
    """
    _check_params(scen, n_agents, T, window, replan, time_limit_s)
    h, w = scen.shape
    memory.check(scen.simulation_bytes(n_agents), f"an exact simulation of the {h}x{w} map {scen.name}")
    if planner not in PLANNERS:
        raise NcaQdError(f"planner must be one of {', '.join(PLANNERS)}, got {planner!r}")
    if plan_time_limit_s is not None and not plan_time_limit_s > 0:
        raise NcaQdError(f"plan_time_limit_s must be positive or None, got {plan_time_limit_s}")
    if pbs_max_nodes == "auto":
        nodes = 0
    elif pbs_max_nodes is None:
        nodes = -1
    elif isinstance(pbs_max_nodes, (int, np.integer)) and pbs_max_nodes > 0:
        nodes = int(pbs_max_nodes)
    else:
        raise NcaQdError(f"pbs_max_nodes must be a positive integer, 'auto' or None, got {pbs_max_nodes!r}")
    if plan_max_expansions is not None and not (
        isinstance(plan_max_expansions, (int, np.integer))
        and not isinstance(plan_max_expansions, bool)
        and plan_max_expansions > 0
    ):
        raise NcaQdError(
            f"plan_max_expansions must be a positive integer or None, got {plan_max_expansions!r}"
        )
    raw = _core.run(
        np.ascontiguousarray(scen.traversable, dtype=np.uint8),
        [c.cells.tolist() for c in scen.classes],
        [c.weights.tolist() for c in scen.classes],
        [c.dwell for c in scen.classes],
        list(scen.cycle),
        n_agents,
        T,
        int(seed) % 2**64,
        window,
        replan,
        float(time_limit_s or 0.0),
        nodes,
        record_paths,
        float(plan_time_limit_s or 0.0),
        bool(prioritize_start),
        bool(reference_starts),
        int(plan_max_expansions or 0),
        planner,
    )
    width = scen.shape[1]
    offsets, cells, dwell = raw["goal_offsets"], raw["goal_cells"], raw["goal_dwell"]
    goals = [
        np.stack([cells[a:b] // width, cells[a:b] % width, dwell[a:b]], axis=1)
        for a, b in zip(offsets[:-1], offsets[1:])
    ]
    paths = None
    if record_paths:
        flat = raw["paths"]
        paths = np.stack([flat // width, flat % width], axis=-1).astype(np.int32)
    return SimResult(
        scenario=scen.name,
        seed=int(seed),
        n_agents=n_agents,
        T=T,
        throughput=float(raw["throughput"]),
        success=bool(raw["success"]),
        congested=bool(raw["congested"]),
        timed_out=bool(raw["timed_out"]),
        stop_time=int(raw["stop_time"]),
        finished_tasks=int(raw["finished_tasks"]),
        tasks_per_step=raw["tasks_per_step"],
        tile_visits=raw["tile_visits"],
        cpu_seconds=float(raw["cpu_seconds"]),
        wall_seconds=float(raw["wall_seconds"]),
        replans=int(raw["replans"]),
        pbs_failures=int(raw["pbs_failures"]),
        pbs_nodes=int(raw["pbs_nodes"]),
        low_level_expansions=int(raw["low_level_expansions"]),
        call_nodes=raw["call_nodes"],
        call_cpu_seconds=raw["call_cpu_seconds"],
        call_failed=raw["call_failed"].astype(bool),
        call_expansions=raw["call_expansions"],
        goals=goals,
        paths=paths,
    )


def simulate_many(
    rows: Sequence[str],
    scenario: str,
    n_agents: int,
    T: int,
    seeds: Sequence[int],
    threads: int | None = None,
    **kwargs,
) -> list[SimResult]:
    """Run one simulation per seed, in parallel threads (the core releases the GIL).

    ``threads`` defaults to the number of CPUs available to this process. Results come back
    in the order of ``seeds``. Extra keyword arguments go to :func:`simulate`.
    """
    scen = build_scenario(list(rows), scenario, n_agents=n_agents)
    seeds = list(seeds)
    if not seeds:
        return []
    if threads is None:
        threads = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    threads = max(1, min(int(threads), len(seeds)))
    if threads == 1:
        return [simulate_scenario(scen, n_agents, T, s, **kwargs) for s in seeds]
    with ThreadPoolExecutor(max_workers=threads) as pool:
        return list(pool.map(lambda s: simulate_scenario(scen, n_agents, T, s, **kwargs), seeds))


# The planner's knobs a config may set (the rest of a run's settings are T, seeds, w, h).
PLANNER_KEYS = (
    "planner",
    "plan_time_limit_s",
    "pbs_max_nodes",
    "plan_max_expansions",
    "prioritize_start",
    "starts",
)
# RHCR (windowed PBS, as the paper) / lifelong PIBT (one step per call) / PIBT with swap (LaCAM3's)
PLANNERS = ("rhcr", "pibt", "pibt_swap")
_TITLES = {"rhcr": "RHCR", "pibt": "PIBT", "pibt_swap": "PIBT with swap"}


def planner_title(name: str) -> str:
    """A planner's name as tables and legends print it (``pibt_swap``: "PIBT with swap")."""
    return _TITLES.get(name, name.upper())


STARTS = ("random", "reference")  # start cells drawn per seed / the reference's one configuration


def planner_options(cfg: Mapping[str, Any] | None, where: str = "") -> dict[str, Any]:
    """The planner knobs of ``cfg`` (:data:`PLANNER_KEYS`), validated, as keyword arguments of
    :func:`simulate`; a key missing from ``cfg`` keeps the simulator's default (RHCR as the
    paper ran it). ``starts: reference`` becomes ``reference_starts=True``: every seed starts from
    the one configuration the reference draws (a fixed shuffle of the traversable cells), as
    the paper's runs did; ``random`` (the default) draws the starts per seed.
    ``where`` prefixes the key in error messages (e.g. ``eval.``)."""
    cfg = cfg or {}
    out: dict[str, Any] = {}
    if "planner" in cfg:
        if cfg["planner"] not in PLANNERS:
            raise NcaQdError(f"{where}planner must be one of {', '.join(PLANNERS)}, got {cfg['planner']!r}")
        if cfg["planner"] != "rhcr":  # (absent for the default: keys of earlier runs stay valid)
            out["planner"] = cfg["planner"]
    if "plan_time_limit_s" in cfg:
        limit = cfg["plan_time_limit_s"]
        if limit is not None and (
            isinstance(limit, bool) or not isinstance(limit, (int, float)) or not limit > 0
        ):
            raise NcaQdError(f"{where}plan_time_limit_s must be a positive number or null, got {limit!r}")
        out["plan_time_limit_s"] = None if limit is None else float(limit)
    if "pbs_max_nodes" in cfg:
        nodes = cfg["pbs_max_nodes"]
        if not (
            nodes is None
            or nodes == "auto"
            or (isinstance(nodes, int) and not isinstance(nodes, bool) and nodes > 0)
        ):
            raise NcaQdError(f"{where}pbs_max_nodes must be a positive integer, auto or null, got {nodes!r}")
        out["pbs_max_nodes"] = nodes
    if cfg.get("plan_max_expansions") is not None:  # (null is the default: keys of earlier runs stay valid)
        work = cfg["plan_max_expansions"]
        if isinstance(work, bool) or not isinstance(work, int) or work <= 0:
            raise NcaQdError(f"{where}plan_max_expansions must be a positive integer or null, got {work!r}")
        out["plan_max_expansions"] = work
    if "prioritize_start" in cfg:
        # (absent for the default: keys of earlier runs stay valid)
        if not require_bool(f"{where}prioritize_start", cfg["prioritize_start"]):
            out["prioritize_start"] = False
    if "starts" in cfg:
        if cfg["starts"] not in STARTS:
            raise NcaQdError(f"{where}starts must be one of {', '.join(STARTS)}, got {cfg['starts']!r}")
        if cfg["starts"] == "reference":  # (absent for the default: keys of earlier runs stay valid)
            out["reference_starts"] = True
    return out


def _check_params(
    scen: Scenario, n_agents: int, T: int, window: int, replan: int, time_limit_s: float | None
) -> None:
    if not isinstance(T, (int, np.integer)) or T <= 0:
        raise NcaQdError(f"horizon T must be a positive integer, got {T!r}")
    if n_agents <= 0:
        raise NcaQdError(f"need at least one agent, got {n_agents}")
    if n_agents > scen.n_traversable:
        raise NcaQdError(f"{n_agents} agents but only {scen.n_traversable} traversable tiles")
    if window < 1 or replan < 1 or replan > window:
        raise NcaQdError(f"need 1 <= replan <= window, got replan={replan}, window={window}")
    if time_limit_s is not None and time_limit_s <= 0:
        raise NcaQdError(f"time_limit_s must be positive, got {time_limit_s}")
