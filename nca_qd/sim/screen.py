"""Screening lifelong-MAPF simulator in JAX: jitted, vmapped over layouts and seeds.

A fast approximation of the exact RHCR simulator (:mod:`nca_qd.sim.rhcr`) for ranking many
layouts. Same task model (:func:`nca_qd.sim.scenario.build_scenario`): goal classes, class
cycle with a uniformly drawn first kind, weighted goal cells, dwell times, distinct uniform
initial cells, RHCR's congestion rule (every ``replan`` = h steps: more than half of the
agents neither moved nor dwelt during those h steps -> stop, failure) and throughput =
finished tasks / T with T the full horizon. By default (``congestion="crowding"``) a run also
stops, as congested, when from the 10th check on the most crowded 5x5 block has held >= 17
agents on average since the start (on a map larger than 33x36, the mean of its r most
crowded blocks, r = its blocks / a 33x36 map's: see :func:`crowd_rank`): a calibrated proxy for
the dense jams in which RHCR's windowed PBS collapses but PIBT does not
(``congestion="moved"`` applies RHCR's rule alone).

Planning differs: instead of windowed PBS over space-time A* replanned every h steps, every
timestep each agent takes one step by PIBT (Okumura et al. 2022; the kernels are in
:mod:`nca_qd.sim.screen_pibt`, this module compiles, batches and reports them).

How it differs from RHCR in outcome: PIBT keeps traffic moving by pushing agents back, so with
RHCR's congestion rule alone it almost never congests where windowed PBS collapses (e.g. the
human-designed warehouse); the crowding proxy is what makes its verdicts track RHCR's. It has
no lookahead, so its throughput is below RHCR's where RHCR runs freely, and with the crowding
proxy it is too pessimistic on some layouts (random aisles at 33x36; manufacturing with 1,800
agents at 101x102). Rank layouts with it; do not take its success/failure verdict as RHCR's.
Its agreement with RHCR (rank correlation, congestion verdicts per run and per layout, at both
sizes) is measured by ``benchmarks/bench_screen.py`` and recorded, with dates, in
docs/benchmarks.md ("Screening simulator").

``planner="windowed"`` replaces PIBT by RHCR's scheme with windowed PBS replaced by prioritized
planning in one random order per call (:mod:`nca_qd.sim.screen_windowed`: every h steps each
agent plans a w=10-step path by a space-time wavefront over its (2w+1)^2 patch, against the
paths of the agents before it; one that finds none stays; RHCR's congestion rule alone).
It is experimental and not the default: it ranks layouts better than PIBT but agrees on
congestion less (it congests too early: no priority swaps for stuck agents, agents stop at
goals inside the window), and it is an order of magnitude slower (docs/benchmarks.md).

Distances (true shortest paths from every goal cell to every cell) are computed in JAX per
layout by repeated relaxation of all goal cells at once, stored as int16 ``[G, H*W]``.

Random streams are counter-based (a 32-bit integer hash of seed, agent, goal index, time), so
goal ``k`` of agent ``a`` is a pure function of (seed, a, k): the goal log is rebuilt after the
run instead of being carried through it. Streams do not match RHCR's.

>>> r = simulate(rows, "warehouse_even", n_agents=200, T=1000, seed=0)
>>> grid = simulate_batch([rows_a, rows_b], "warehouse_even", 200, 1000, seeds=range(5))
"""

from __future__ import annotations

import inspect
import os
import time
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from nca_qd.errors import NcaQdError
from nca_qd.sim import screen_base, screen_pibt
from nca_qd.sim.result import RunResult
from nca_qd.sim.scenario import Scenario, build_scenario
from nca_qd.sim.screen_base import (
    WINDOW,
    LayoutArrays,
    _draw_goal,
    _goal_cells,
    _hash,
    _jax,
    _on_cpu,
    _round_up,
    distance_table,
    prepare,
)
from nca_qd.sim.screen_pibt import CROWD_MEAN, CROWD_MIN_CHECKS, crowd_rank

__all__ = [
    "CROWD_MEAN",
    "CROWD_MIN_CHECKS",
    "crowd_rank",
    "crowd_mean_for",
    "ScreenResult",
    "LayoutArrays",
    "simulate",
    "simulate_batch",
    "simulate_scenarios",
    "prepare",
    "goal_log",
]

# The screen's decisions: bump whenever a change alters any run's outcome (the evaluation's
# screen_runs.jsonl reuses recorded runs of the same version; tests/test_screen.py holds the
# digest of reference runs per version).
VERSION = 2  # 2: crowding on maps larger than 33x36 is the mean of the r most crowded blocks
PRIORITY = "random"  # "random": fresh random agent order each step; "age": PIBT's (steps
# since the last finished goal, fixed random tie-break)
PLANNER = "pibt"  # or "windowed": prioritized planning over a window (screen_windowed.py)
# PIBT's congestion rule; the windowed planner applies "moved" (RHCR's) only
CONGESTION = "crowding"  # or "moved" (RHCR's rule alone), or "progress" (more than half
# neither finished a goal, dwelt, nor ended the h steps closer to it)
MAX_AGENTS = 46340  # (N - 1) * N + N < 2**31 for the random order's affine map
MAX_TABLE = 2**28  # int16 distance-table entries per batch (512 MiB); more -> several batches


def crowd_mean_for(domain_cfg: Mapping[str, Any], override: Any = None) -> float:
    """The crowding threshold a domain config asks for (``simulation.screen_crowd_mean``, else
    :data:`CROWD_MEAN`), or ``override`` where it is not None; a bad value is one clear line."""
    value = override
    if value is None:
        value = (domain_cfg.get("simulation") or {}).get("screen_crowd_mean", CROWD_MEAN)
    return _crowd_mean(value)


def _crowd_mean(value: Any) -> float:
    """A crowding threshold as a float: a positive finite number, or one clear line."""
    number = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    if not number or not 0 < value < float("inf"):
        raise NcaQdError(
            f"the crowding threshold (screen_crowd_mean) must be a positive number, got {value!r}"
        )
    return float(value)


@dataclass
class ScreenResult(RunResult):
    """Outcome of one screening run: :class:`~nca_qd.sim.result.RunResult` plus two diagnostics.

    ``cpu_seconds`` / ``wall_seconds`` are the batch's process CPU / wall time divided by the
    number of runs in the batch (compilation excluded when it was already compiled).
    ``goals[a]`` holds the goals agent ``a`` finished, then its current one.
    """

    # share of agent-steps (not dwelling) that did not bring the agent closer to its goal
    delay_rate: float = 0.0
    # the most agents in one DENSITY_K x DENSITY_K block (on a map larger than 33x36: the mean
    # of its crowd_rank most crowded blocks), at each congestion check
    crowding: np.ndarray | None = field(default=None, repr=False)

    def summary(self) -> dict:
        return {**super().summary(), "congested": self.congested}


_COMPILED: dict = {}
_EXECUTABLES: dict = {}


def _batched(
    n_agents, T, replan, cycle, record_paths, priority, congestion, planner=PLANNER, crowd_mean=CROWD_MEAN
):
    """Jitted: (stacked layouts [L, ...], distances [L, G, HW], layout index [R], seeds [R])
    -> results with leading axis R (one per run)."""
    jax, _ = _jax()
    key = (n_agents, T, replan, cycle, record_paths, priority, congestion, planner, crowd_mean)
    if key not in _COMPILED:

        def run(lay, dist, lidx, seeds):
            if planner == "windowed":
                from nca_qd.sim import screen_windowed

                return screen_windowed.run_batch(
                    lay,
                    dist,
                    lidx,
                    seeds,
                    n_agents=n_agents,
                    T=T,
                    replan=replan,
                    cycle=cycle,
                    record_paths=record_paths,
                )
            return screen_pibt.run_batch(
                lay,
                dist,
                lidx,
                seeds,
                n_agents=n_agents,
                T=T,
                replan=replan,
                cycle=cycle,
                record_paths=record_paths,
                priority=priority,
                congestion=congestion,
                crowd_mean=crowd_mean,
            )

        _COMPILED[key] = jax.jit(run)
    return _COMPILED[key]


def _compiled(fn, *args):
    """Ahead-of-time compiled ``fn`` for these argument shapes (cached)."""
    key = (fn, tuple((a.shape, str(a.dtype)) for a in _leaves(args)))
    if key not in _EXECUTABLES:
        _EXECUTABLES[key] = fn.lower(*args).compile()
    return _EXECUTABLES[key]


def _leaves(tree):
    jax, _ = _jax()
    return jax.tree_util.tree_leaves(tree)


def _distance_fn():
    """Jitted ``[L, H, W], [L, G] -> [L, G, H*W]``: on CPU one layout after another (each
    layout's chunks stay cache-sized, see :func:`distance_table`), elsewhere vmapped."""
    jax, _ = _jax()
    if "dist" not in _COMPILED:
        if _on_cpu():
            _COMPILED["dist"] = jax.jit(lambda t, g: jax.lax.map(lambda x: distance_table(*x), (t, g)))
        else:
            _COMPILED["dist"] = jax.jit(jax.vmap(distance_table))
    return _COMPILED["dist"]


def _distance_tables(traversable, goal_cells, threads: int):
    """A compiled callable () -> ``[L, G, H*W]`` distance tables, the goals split over
    ``threads`` CPU threads (XLA releases the GIL; a table does not depend on the split).
    Compiled here, so that a caller's clock can start after it."""
    _, jnp = _jax()
    L, G = goal_cells.shape
    parts = max(1, min(threads, G // screen_base.DIST_CHUNK)) if _on_cpu() else 1
    size = _round_up(-(-G // parts), screen_base.DIST_CHUNK) if parts > 1 else G
    padded = jnp.pad(goal_cells, ((0, 0), (0, size * parts - G)), constant_values=-1)
    exe = _compiled(_distance_fn(), traversable, padded[:, :size])
    if parts == 1:
        return lambda: exe(traversable, padded)

    def run():
        with ThreadPoolExecutor(max_workers=parts) as pool:
            outs = list(
                pool.map(lambda i: exe(traversable, padded[:, i * size : (i + 1) * size]), range(parts))
            )
        return jnp.concatenate(outs, axis=1)[:, :G]

    return run


def _default_threads() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover
        return os.cpu_count() or 1


def goal_log(lay: LayoutArrays, cycle, base, k_done: np.ndarray) -> list[np.ndarray]:
    """Rebuild each agent's goals (finished ones, then the current one) as (row, col, dwell)."""
    jax, jnp = _jax()
    N = k_done.shape[0]
    W = lay.traversable.shape[1]
    kmax = int(k_done.max()) + 1
    a = jnp.repeat(jnp.arange(N, dtype=jnp.int32), kmax)
    k = jnp.tile(jnp.arange(kmax, dtype=jnp.int32), N)
    phase0 = _hash(base, jnp.arange(N, dtype=jnp.int32), 3) % jnp.uint32(len(cycle))
    phase0 = phase0.astype(jnp.int32)
    lay_j = LayoutArrays(*(jnp.asarray(x) for x in lay))
    gi, dw = _draw_goal(lay_j, cycle, base, a, k, phase0[a])
    cells = np.asarray(lay.goal_cells)[np.asarray(gi)].reshape(N, kmax)
    dw = np.asarray(dw).reshape(N, kmax)
    return [
        np.stack(
            [cells[i, : k_done[i] + 1] // W, cells[i, : k_done[i] + 1] % W, dw[i, : k_done[i] + 1]], axis=1
        ).astype(np.int64)
        for i in range(N)
    ]


# ----------------------------------------------------------------------------- public API
def _congestion(congestion: str | None, planner: str) -> str:
    """The congestion rule asked for, or the planner's default ("moved" for the windowed one)."""
    if congestion is None:
        return "moved" if planner == "windowed" else CONGESTION
    return congestion


def _check(
    n_agents: int,
    T: int,
    replan: int,
    congestion: str | None = None,
    priority: str = PRIORITY,
    planner: str = PLANNER,
    crowd_mean: float = CROWD_MEAN,
) -> None:
    if planner not in ("pibt", "windowed"):
        raise NcaQdError(f"planner must be 'pibt' or 'windowed', got {planner!r}")
    congestion = _congestion(congestion, planner)
    if planner == "windowed" and congestion != "moved":
        raise NcaQdError(
            f"the windowed planner applies RHCR's congestion rule ('moved') only, got {congestion!r}"
        )
    if planner == "windowed" and isinstance(replan, (int, np.integer)) and replan > WINDOW:
        raise NcaQdError(f"the windowed planner replans within its {WINDOW}-step window, got replan={replan}")
    if planner == "windowed" and priority != "random":
        raise NcaQdError(f"the windowed planner draws a random order per call, got priority {priority!r}")
    if priority not in ("random", "age"):
        raise NcaQdError(f"priority must be 'random' or 'age', got {priority!r}")
    _crowd_mean(crowd_mean)
    if congestion not in ("moved", "progress", "crowding"):
        raise NcaQdError(f"congestion rule must be 'moved', 'progress' or 'crowding', got {congestion!r}")
    if isinstance(T, bool) or not isinstance(T, (int, np.integer)) or T <= 0:
        raise NcaQdError(f"horizon T must be a positive integer, got {T!r}")
    if isinstance(n_agents, bool) or not isinstance(n_agents, (int, np.integer)) or n_agents <= 0:
        raise NcaQdError(f"need at least one agent, got {n_agents!r}")
    if n_agents > MAX_AGENTS:  # the random order's a*i + b stays within int32
        raise NcaQdError(f"the screen simulates at most {MAX_AGENTS} agents, got {n_agents}")
    if not isinstance(replan, (int, np.integer)) or replan < 1:
        raise NcaQdError(f"replan (congestion check period h) must be >= 1, got {replan!r}")


def layout_groups(scens: Sequence[Scenario], max_entries: int | None = None) -> list[list[int]]:
    """Consecutive groups of scenario indices whose distance tables (``[L, G, H*W]`` int16,
    G padded to the group's largest goal count) hold at most ``max_entries`` (default
    ``MAX_TABLE``) entries; a layout too large for int32 indexing alone is an error."""
    limit = MAX_TABLE if max_entries is None else max_entries
    groups: list[list[int]] = []
    g_max = 0
    for i, s in enumerate(scens):
        hw = int(np.prod(s.shape))
        g = _round_up(_goal_cells(s).size)
        if g * hw >= 2**31:
            raise NcaQdError(
                f"layout {i} ({s.shape[0]}x{s.shape[1]}, {g} goal cells) is too "
                f"large for the screen's distance table ({g * hw:,} entries)"
            )
        if groups and (len(groups[-1]) + 1) * max(g_max, g) * hw <= limit:
            groups[-1].append(i)
            g_max = max(g_max, g)
        else:
            groups.append([i])
            g_max = g
    return groups


def simulate_scenarios(
    scens: Sequence[Scenario],
    n_agents: int,
    T: int,
    seeds: Sequence[int],
    replan: int = 5,
    record_paths: bool = False,
    priority: str = PRIORITY,
    congestion: str | None = None,
    threads: int | None = None,
    planner: str = PLANNER,
    crowd_mean: float = CROWD_MEAN,
) -> list[list[ScreenResult]]:
    """Simulate every validated scenario (one kind, one shape) with every seed, as vmapped
    batches (split over ``threads`` CPU threads, default: all available CPUs): one batch,
    or consecutive groups of layouts when the distance tables would exceed ``MAX_TABLE``
    entries (30 warehouses of 101x102 need 2.3 G). A run's result does not depend on the
    batch it is in. ``crowd_mean``: the crowding rule's threshold (agents in the most crowded
    ``DENSITY_K`` x ``DENSITY_K`` block, mean over the checks so far). Returns
    ``results[layout][seed]``."""
    _check(n_agents, T, replan, congestion, priority, planner, crowd_mean)
    congestion = _congestion(congestion, planner)
    seeds = [int(s) for s in seeds]
    if not seeds:
        return [[] for _ in scens]
    for s in scens:
        if n_agents > s.n_traversable:
            raise NcaQdError(f"{n_agents} agents but only {s.n_traversable} traversable tiles")
        if any(not np.isfinite(c.weights).all() for c in s.classes):
            raise NcaQdError("goal weights must be finite")
    out: list[list[ScreenResult]] = []
    for group in layout_groups(scens):
        out += _simulate_group(
            [scens[i] for i in group],
            n_agents,
            T,
            seeds,
            replan,
            record_paths,
            priority,
            congestion,
            threads,
            planner,
            float(crowd_mean),
        )
    return out


def _simulate_group(
    scens: Sequence[Scenario],
    n_agents: int,
    T: int,
    seeds: list[int],
    replan: int,
    record_paths: bool,
    priority: str,
    congestion: str,
    threads: int | None,
    planner: str = PLANNER,
    crowd_mean: float = CROWD_MEAN,
) -> list[list[ScreenResult]]:
    """One vmapped batch of validated scenarios (see :func:`simulate_scenarios`)."""
    lay = prepare(scens)
    cycle = tuple(int(c) for c in scens[0].cycle)
    flags = (bool(record_paths), priority, congestion, planner, float(crowd_mean))
    fn = _batched(int(n_agents), int(T), int(replan), cycle, *flags)
    jax, jnp = _jax()
    lay_j = LayoutArrays(*(jnp.asarray(x) for x in lay))
    S = len(seeds)
    runs = len(scens) * S
    lidx = np.repeat(np.arange(len(scens), dtype=np.int32), S)
    seed_r = np.tile(np.array(seeds, dtype=np.int64) % 2**32, len(scens)).astype(np.uint32)
    # Runs are split into equal chunks (the last one padded with repeats), one per thread;
    # XLA releases the GIL, so chunks run in parallel on CPU. Results do not depend on it.
    n_threads = max(1, int(threads or _default_threads()))
    threads = min(n_threads, runs)
    size = -(-runs // threads)
    pad = size * threads - runs
    lidx = np.concatenate([lidx, np.repeat(lidx[-1:], pad)])
    seed_r = np.concatenate([seed_r, np.repeat(seed_r[-1:], pad)])
    tables = _distance_tables(lay_j.traversable, lay_j.goal_cells, n_threads)
    chunks = [
        (jnp.asarray(lidx[i * size : (i + 1) * size]), jnp.asarray(seed_r[i * size : (i + 1) * size]))
        for i in range(threads)
    ]
    L, H, W = lay.traversable.shape
    dist_spec = jax.ShapeDtypeStruct((L, lay.goal_cells.shape[1], H * W), jnp.int16)
    exe = _compiled(fn, lay_j, dist_spec, *chunks[0])  # compiled before the clock starts
    cpu0, wall0 = time.process_time(), time.perf_counter()
    dist = tables()
    if threads == 1:
        parts = [jax.device_get(exe(lay_j, dist, *chunks[0]))]
    else:
        with ThreadPoolExecutor(max_workers=threads) as pool:
            parts = list(pool.map(lambda c: jax.device_get(exe(lay_j, dist, *c)), chunks))
    out = {k: np.concatenate([p[k] for p in parts])[:runs] for k in parts[0]}
    cpu = (time.process_time() - cpu0) / runs
    wall = (time.perf_counter() - wall0) / runs
    results = []
    S = len(seeds)
    for li, scen in enumerate(scens):
        row = []
        one_lay = LayoutArrays(*(x[li] for x in lay))
        for si, seed in enumerate(seeds):
            stop = int(out["stop_time"][li * S + si])
            tasks = np.asarray(out["tasks"][li * S + si]).astype(np.int64)
            finished = int(tasks.sum())
            congested = bool(out["congested"][li * S + si])
            paths = goals = None
            if record_paths:
                W = scen.shape[1]
                flat = np.asarray(out["paths"][li * S + si][: stop + 1])
                paths = np.stack([flat // W, flat % W], axis=-1).astype(np.int32)
                goals = goal_log(one_lay, cycle, out["base"][li * S + si], np.asarray(out["k"][li * S + si]))
            row.append(
                ScreenResult(
                    scenario=scen.name,
                    seed=seed,
                    n_agents=int(n_agents),
                    T=int(T),
                    throughput=finished / T,
                    success=(not congested) and stop == T,
                    congested=congested,
                    stop_time=stop,
                    finished_tasks=finished,
                    tasks_per_step=tasks,
                    tile_visits=np.asarray(out["visits"][li * S + si]).astype(np.int64),
                    cpu_seconds=cpu,
                    wall_seconds=wall,
                    goals=goals,
                    paths=paths,
                    delay_rate=float(out["delays"][li * S + si]) / max(1, stop * n_agents),
                    crowding=np.asarray(out["crowd"][li * S + si]) / crowd_rank(*scen.shape),
                )
            )
        results.append(row)
    return results


def simulate_batch(
    layouts: Sequence[Sequence[str]],
    scenario: str,
    n_agents: int,
    T: int,
    seeds: Sequence[int],
    **options: Any,
) -> list[list[ScreenResult]]:
    """Validate layouts (rows) and simulate all of them with all seeds in one vmapped batch:
    :func:`simulate_scenarios` with ``options`` (the one place that names the screen's
    settings). All layouts must have one shape. Bad input (unknown scenario or tiles,
    unreachable goals, too many agents, bad T or option) raises :class:`NcaQdError` before
    anything is compiled."""
    try:  # the settings checked before the layouts are built (the cheaper error first)
        bound = inspect.signature(simulate_scenarios).bind([], n_agents, T, seeds, **options)
    except TypeError as exc:
        raise NcaQdError(f"screen: {exc}") from None
    bound.apply_defaults()
    a = bound.arguments
    _check(n_agents, T, a["replan"], a["congestion"], a["priority"], a["planner"], a["crowd_mean"])
    scens = [
        build_scenario(list(r), scenario, n_agents=n_agents, source=f"layout {i}")
        for i, r in enumerate(layouts)
    ]
    return simulate_scenarios(scens, n_agents, T, seeds, **options)


def simulate(
    rows: Sequence[str], scenario: str, n_agents: int, T: int, seed: int, **options: Any
) -> ScreenResult:
    """One screening run (a batch of one; ``options`` as :func:`simulate_scenarios`)."""
    return simulate_batch([rows], scenario, n_agents, T, [seed], **options)[0][0]
