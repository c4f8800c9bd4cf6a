"""Simulate a layout over several seeds and print throughput figures.

    python -m experiments.simulate domain=warehouse_even layout=map.json agents=200 T=1000 seeds=5

Prints one JSON line per run (seed, throughput, success, stop_time, cpu_seconds, ...) in seed
order, then a summary line (mean and standard error of throughput over all runs, success
rate). ``usage_out=<file.png>`` also draws where the agents were: per tile, the share of
timesteps (1..stop_time) an agent stood on it, averaged over the runs (divided by each run's own
length, so that a run stopped by a jam and one that ran to T weigh alike and a jam shows as
tiles held nearly all the time), with the figures in a ``.csv`` beside it.

Simulators are entries of :data:`SIMULATORS`; ``simulator=rhcr`` (default) is the exact RHCR
simulator, ``simulator=screen`` the JAX screening approximation (all seeds as one vmapped
batch); another simulator is one more entry there.
"""

from __future__ import annotations

import io
import json
import math
import os
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from omegaconf import DictConfig, OmegaConf

from experiments.cli import check_writable, compose_config, main_guard, take_domain
from nca_qd import memory
from nca_qd.errors import NcaQdError
from nca_qd.io import atomic_write_bytes, load_map
from nca_qd.sim.scenario import Scenario, build_scenario, tiles_for

# A simulator takes the validated scenario, the run settings and the seeds, and yields one
# result per seed, in seed order. Results need ``summary()`` (a JSON-friendly dict with at
# least seed, throughput, success, stop_time, cpu_seconds) and, for paths_out, ``paths``.
Simulator = Callable[[Scenario, "RunSettings", list[int]], Iterator]


class RunSettings:
    """The simulator-independent settings of a simulate run, validated."""

    def __init__(self, cfg: DictConfig):
        self.agents = _int(cfg, "agents", minimum=1)
        self.T = _int(cfg, "T", minimum=1)
        self.window = _int(cfg, "window", minimum=1)
        self.replan = _int(cfg, "replan", minimum=1)
        if self.replan > self.window:
            raise NcaQdError(f"replan ({self.replan}) must not exceed window ({self.window})")
        self.time_limit_s = None if cfg.time_limit_s is None else _float(cfg, "time_limit_s")
        threads = None if cfg.threads is None else _int(cfg, "threads", minimum=1)
        self.threads = threads or len(os.sched_getaffinity(0))
        self.record_paths = cfg.paths_out is not None
        if self.record_paths:
            check_writable(cfg.paths_out, "paths_out")
        self.usage_out = cfg.get("usage_out")
        if self.usage_out is not None:
            if not str(self.usage_out).endswith(".png"):
                raise NcaQdError(f"usage_out={self.usage_out}: must name a .png file")
            check_writable(self.usage_out, "usage_out")
        self.rhcr = rhcr_options(cfg)
        self.crowd_mean = screen_crowd_mean(cfg) if cfg.simulator == "screen" else None


def screen_crowd_mean(cfg: DictConfig) -> float:
    """(``simulator=screen``) the crowding rule's threshold: ``screen_crowd_mean``, else the
    domain's (``simulation.screen_crowd_mean`` of experiments/conf/domain/<domain>.yaml)."""
    from nca_qd.sim.screen import crowd_mean_for

    if cfg.get("screen_crowd_mean") is not None:
        return crowd_mean_for({}, cfg.screen_crowd_mean)
    domain_cfg = compose_config("run", [f"domain={cfg.domain}"]).domain
    return crowd_mean_for(OmegaConf.to_container(domain_cfg, resolve=True))


def rhcr_options(cfg: DictConfig) -> dict:
    """The exact planner's knobs (``plan_time_limit_s``, ``pbs_max_nodes``,
    ``plan_max_expansions``, ``prioritize_start``), validated; keys missing from ``cfg`` keep
    the simulator's defaults (RHCR as the paper ran it)."""
    from nca_qd.sim.rhcr import PLANNER_KEYS, planner_options

    return planner_options({k: cfg[k] for k in PLANNER_KEYS if k in cfg})


def exact_run(scen: Scenario, s: RunSettings, seed: int):
    """One exact run (RHCR or PIBT, ``planner``) of the scenario with these settings."""
    from nca_qd.sim.rhcr import simulate_scenario

    return simulate_scenario(
        scen,
        s.agents,
        s.T,
        seed,
        window=s.window,
        replan=s.replan,
        time_limit_s=s.time_limit_s,
        record_paths=s.record_paths,
        **s.rhcr,
    )


def _rhcr(scen: Scenario, s: RunSettings, seeds: list[int]) -> Iterator:
    with ThreadPoolExecutor(max_workers=max(1, min(s.threads, len(seeds)))) as pool:
        # the core releases the GIL: runs are parallel
        yield from pool.map(lambda seed: exact_run(scen, s, seed), seeds)


def _screen(scen: Scenario, s: RunSettings, seeds: list[int]) -> Iterator:
    # JAX screening simulator: all seeds as one vmapped batch (window and time limit unused).
    from nca_qd.sim.screen import simulate_scenarios

    yield from simulate_scenarios(
        [scen], s.agents, s.T, seeds, replan=s.replan, record_paths=s.record_paths, crowd_mean=s.crowd_mean
    )[0]


# name -> loader returning the simulator (a loader may refuse with a one-line NcaQdError).
SIMULATORS: dict[str, Callable[[], Simulator]] = {
    "rhcr": lambda: _rhcr,
    "screen": lambda: _screen,
}


def main(argv: list[str]) -> int:
    argv, domain_override = take_domain(argv)
    cfg = compose_config("simulate", argv)
    if domain_override is not None:
        cfg.domain = domain_override
    if cfg.simulator not in SIMULATORS:
        raise NcaQdError(f"unknown simulator {cfg.simulator!r} (expected one of {', '.join(SIMULATORS)})")
    simulator = SIMULATORS[cfg.simulator]()
    if OmegaConf.is_missing(cfg, "layout") or not cfg.layout:
        raise NcaQdError("layout=<map.json> is required")
    domain = str(cfg.domain)
    tiles = tiles_for(domain)  # unknown scenario -> one-line error
    settings = RunSettings(cfg)
    n_runs = _int(cfg, "seeds", minimum=1)
    first = _int(cfg, "seed", minimum=0)
    mapfile = load_map(str(cfg.layout), tiles=tiles)
    scen = build_scenario(mapfile.rows, domain, n_agents=settings.agents, source=str(cfg.layout))
    seeds = list(range(first, first + n_runs))
    if cfg.simulator == "rhcr":  # its runs in parallel threads, each with its distance tables
        parallel = max(1, min(settings.threads, n_runs))
        memory.check(
            parallel * scen.simulation_bytes(settings.agents),
            f"{parallel} exact simulation(s) at once of the {scen.shape[0]}x{scen.shape[1]} map {cfg.layout}",
            hint="use fewer threads=, or a smaller map",
        )

    results, recorded, occupancy = [], {}, []
    for res in simulator(scen, settings, seeds):
        print(json.dumps(res.summary()), flush=True)
        results.append(res.summary())
        if settings.record_paths:
            recorded[res.seed] = res
        if settings.usage_out is not None:
            occupancy.append(np.asarray(res.tile_visits, dtype=float) / max(1, res.stop_time))
    print(json.dumps(summarize(results)), flush=True)
    if settings.record_paths:
        _write_paths(str(cfg.paths_out), recorded)
    if settings.usage_out is not None:
        usage = (scen, mapfile.rows, settings, results, occupancy)
        _write_usage(str(settings.usage_out), str(cfg.layout), *usage)
    return 0


def _write_usage(
    path: str, layout: str, scen: Scenario, rows: list[str], s: RunSettings, results: list, occupancy: list
) -> None:
    """The tile-usage picture of ``usage_out`` and its ``.csv`` (row, col, tile, occupancy)."""
    from nca_qd.evaluation.plots import plot_tile_usage

    mean = np.mean(np.stack(occupancy), axis=0)
    flowed = sum(bool(r["success"]) for r in results)
    title = f"{Path(layout).name}: {s.agents} agents, T = {s.T}, {len(results)} run(s), {flowed} flowed to T"
    plot_tile_usage(path, [(title, mean, scen.traversable)], label="share of timesteps occupied")
    lines = ["row,col,tile,occupancy"] + [
        f"{i},{j},{rows[i][j]},{mean[i, j]:.6f}" for i in range(mean.shape[0]) for j in range(mean.shape[1])
    ]
    atomic_write_bytes(str(Path(path).with_suffix(".csv")), ("\n".join(lines) + "\n").encode())


def summarize(runs: list[dict]) -> dict:
    """Mean and standard error of throughput over all runs, and the success rate."""
    thr = np.array([r["throughput"] for r in runs], dtype=float)
    se = float(thr.std(ddof=1) / math.sqrt(len(thr))) if len(thr) > 1 else 0.0
    return {
        "summary": True,
        "runs": len(runs),
        "throughput_mean": round(float(thr.mean()), 9),
        "throughput_se": round(se, 9),
        "success_rate": round(float(np.mean([r["success"] for r in runs])), 6),
        "cpu_seconds_mean": round(float(np.mean([r["cpu_seconds"] for r in runs])), 3),
    }


def _write_paths(path: str, recorded: dict) -> None:
    """One .npz: per seed, paths [S+1, N, 2] (row, col) and goals (row, col, dwell) with offsets."""
    arrays = {}
    for seed, res in recorded.items():
        arrays[f"paths_seed{seed}"] = res.paths
        arrays[f"goals_seed{seed}"] = np.concatenate(res.goals) if res.goals else np.zeros((0, 3))
        arrays[f"goal_offsets_seed{seed}"] = np.cumsum([0] + [len(g) for g in res.goals])
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    atomic_write_bytes(path, buf.getvalue())


def _int(cfg: DictConfig, key: str, minimum: int) -> int:
    value = cfg[key]
    if isinstance(value, bool) or not isinstance(value, int):
        raise NcaQdError(f"{key} must be an integer, got {value!r}")
    if value < minimum:
        raise NcaQdError(f"{key} must be >= {minimum}, got {value}")
    return value


def _float(cfg: DictConfig, key: str) -> float:
    value = cfg[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
        raise NcaQdError(f"{key} must be a positive number, got {value!r}")
    return float(value)


if __name__ == "__main__":
    main_guard(main)()
