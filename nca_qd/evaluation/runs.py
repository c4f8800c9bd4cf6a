"""The simulations of an evaluation: exact RHCR runs and screened runs.

The requests are merged into one cell per (layout, agent count) (:func:`merge_requests`);
:func:`simulate_cells` runs each cell's exact RHCR runs as backend jobs
(:func:`~nca_qd.scoring.jobs.exact_job`, the search's job too, in a background thread; runs
recorded in the folder's :class:`~nca_qd.evaluation.store.ExactRunStore` are reused, and each
new one is recorded as it ends) while it screens the cells in this process, in vmapped batches
of one shape and agent count (:func:`screen_group`; cells whose runs the folder's
:class:`~nca_qd.evaluation.store.ScreenRunStore` holds are reused, and each batch's runs are
recorded as it ends). Every run comes back as a :class:`~nca_qd.scoring.jobs.RunOutcome`, the
search's outcome type too.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from nca_qd.evaluation.plan import ScreenSettings
from nca_qd.evaluation.records import EvalLayout, Request, Results, format_value, size_str
from nca_qd.evaluation.stats import run_stats
from nca_qd.evaluation.store import ExactRunStore, ScreenRunStore
from nca_qd.interrupts import deferred_interrupts
from nca_qd.scoring.jobs import ExactSettings, RunOutcome, exact_job
from nca_qd.scoring.keys import exact_run_key, screen_run_key

log = logging.getLogger("nca_qd.evaluate")


def merge_requests(requests: Iterable[Request]) -> dict[tuple[str, int], Request]:
    """One simulation cell per (layout, agent count): the most runs any request asks for."""
    cells: dict[tuple[str, int], Request] = {}
    for r in requests:
        c = cells.get((r.layout, r.n_agents))
        if c is None:
            cells[(r.layout, r.n_agents)] = Request(
                "cell", r.layout, r.n_agents, r.screen_runs, r.exact_runs, r.detail
            )
        else:
            c.screen_runs = max(c.screen_runs, r.screen_runs)
            c.exact_runs = max(c.exact_runs, r.exact_runs)
            c.detail = c.detail or r.detail
    return cells


def simulate_cells(
    cells: Mapping[tuple[str, int], Request],
    layouts: Mapping[str, EvalLayout],
    scenario: str,
    tiles: str,
    T: int,
    seed0: int,
    backend,
    exact: ExactSettings,
    screen: ScreenSettings,
    progress: bool = True,
    store: ExactRunStore | None = None,
    screen_store: ScreenRunStore | None = None,
) -> Results:
    """Run every cell: exact runs as backend jobs under ``exact`` (in a background thread, so
    they overlap the screening), screening runs batched by (shape, agent count) in this process.
    With a ``store``, exact runs it holds are reused and every new one is recorded in it as it
    finishes; likewise screened runs with a ``screen_store`` (recorded per batch).
    Returns ``results[(layout, n_agents, simulator)]``: outcomes in seed order."""
    from concurrent.futures import ThreadPoolExecutor

    from nca_qd.io import array_to_rows
    from nca_qd.scoring.backend import map_jobs

    rows = {k: array_to_rows(v.layout, tiles) for k, v in layouts.items() if v.layout is not None}
    results: Results = {}
    done: dict[tuple[str, int], list[RunOutcome]] = {}  # added to results after the screen's
    jobs, slots, run_keys, reused_keys = [], [], [], []
    for (key, n), c in cells.items():
        for i in range(c.exact_runs):
            rk = exact_run_key(rows[key], scenario, n, seed0 + i, exact)
            known = store.get(rk, c.detail) if store is not None else None
            done.setdefault((key, n), [])
            if known is not None:
                done[(key, n)].append(known)
                reused_keys.append(rk)
                continue
            jobs.append((rows[key], scenario, n, seed0 + i, exact, c.detail))
            slots.append((key, n))
            run_keys.append(rk)
    if store is not None and reused_keys:
        log.info("%d exact RHCR run(s) reused from %s", len(reused_keys), store.sources(reused_keys))

    def record(i: int, out: Any) -> None:
        if store is not None:
            store.add(run_keys[i], _outcome(out, jobs[i][3]))

    with ThreadPoolExecutor(max_workers=1) as pool:
        future = None
        if jobs:
            log.info("%d exact RHCR run(s) (T=%d) submitted to %s", len(jobs), T, backend.describe())
            future = pool.submit(map_jobs, backend, exact_job, jobs, record)
        try:
            _screen_cells(cells, layouts, rows, scenario, T, seed0, screen, progress, results, screen_store)
            if future is not None:
                if not future.done():
                    log.info("screening done; waiting for the exact runs")
                for (key, n), job, out in zip(slots, jobs, future.result()):
                    done[(key, n)].append(_outcome(out, job[3]))
        except KeyboardInterrupt:  # Ctrl-C / SIGTERM: stop the exact runs now, not when they end
            abort = getattr(backend, "abort", None)
            if abort is not None:
                abort()
            raise
    for (key, n), outs in done.items():
        results[(key, n, "rhcr")] = outs
    for k in results:
        results[k].sort(key=lambda o: o.seed)
        _log_cell(layouts[k[0]], k[1], k[2], results[k])
    return results


def _screen_cells(
    cells: Mapping[tuple[str, int], Request],
    layouts: Mapping[str, EvalLayout],
    rows: Mapping[str, list[str]],
    scenario: str,
    T: int,
    seed0: int,
    screen: ScreenSettings,
    progress: bool,
    results: Results,
    store: ScreenRunStore | None = None,
) -> None:
    """Every cell's screening runs, batched by (shape, agent count), into ``results``; a cell
    whose runs ``store`` holds is not screened again, and each batch's runs go into it."""
    from tqdm import tqdm

    replan, crowd_mean = screen.replan, screen.crowd_mean

    def key_of(c: Request, seed: int) -> str:
        return screen_run_key(rows[c.layout], scenario, c.n_agents, T, seed, replan, crowd_mean)

    groups: dict[tuple[tuple[int, int], int], list[Request]] = {}
    for (key, n), c in cells.items():
        if c.screen_runs > 0:
            groups.setdefault((layouts[key].layout.shape, n), []).append(c)
    bar = tqdm(
        total=sum(len(g) for g in groups.values()),
        disable=not progress,
        desc="screen",
        unit="cell",
        dynamic_ncols=True,
    )
    reused: list[str] = []
    for (shape, n), group in sorted(groups.items(), key=lambda kv: (kv[0][0], kv[0][1])):
        bar.set_postfix(size=size_str(shape), agents=n)
        known: dict[str, list[RunOutcome]] = {}
        if store is not None:
            for c in group:
                ks = [key_of(c, seed0 + i) for i in range(c.screen_runs)]
                outs = [store.get(k, c.detail, _screen_visits(c)) for k in ks]
                if all(o is not None for o in outs):
                    known[c.layout] = [o for o in outs if o is not None]
                    reused += ks
        todo = [c for c in group if c.layout not in known]
        # a batch is minutes of one JAX call at 101x102: an interruption waits until its runs
        # are recorded, instead of dropping them
        with deferred_interrupts():
            fresh = screen_group(todo, rows, scenario, n, T, seed0, screen) if todo else []
            for c, outs in zip(todo, fresh):
                if store is not None:
                    for o in outs:
                        store.add(key_of(c, o.seed), o)
                known[c.layout] = outs
        for c in group:  # in the group's order, reused or not
            results[(c.layout, n, "screen")] = known[c.layout]
        bar.update(len(group))
    if reused and store is not None:
        log.info("%d screened run(s) reused from %s", len(reused), store.sources(reused))
    bar.close()


def _screen_visits(c: Request) -> bool:
    """Whether a cell's screened runs keep their tile visits: only for the heatmap of a cell
    without exact runs (with them, the heatmap is the exact runs')."""
    return c.detail and c.exact_runs == 0


def _outcome(out: Any, seed: int) -> RunOutcome:
    """A backend job's result as a RunOutcome (a job that failed every attempt: its error)."""
    from nca_qd.scoring.backend import JobFailed

    return RunOutcome("rhcr", seed, error=out.error) if isinstance(out, JobFailed) else out


def screen_group(
    group: list[Request],
    rows: Mapping[str, list[str]],
    scenario: str,
    n: int,
    T: int,
    seed0: int,
    screen: ScreenSettings,
) -> list[list[RunOutcome]]:
    """Screening runs of layouts of one shape at one agent count, in one vmapped batch."""
    from nca_qd.sim.screen import simulate_batch

    runs = max(c.screen_runs for c in group)
    t0 = time.perf_counter()
    res = simulate_batch(
        [rows[c.layout] for c in group],
        scenario,
        n,
        T,
        range(seed0, seed0 + runs),
        replan=screen.replan,
        threads=screen.threads,
        crowd_mean=screen.crowd_mean,
    )
    per_run = (time.perf_counter() - t0) / max(1, runs * len(group))
    out = []
    for c, row in zip(group, res):
        out.append(
            [
                RunOutcome(
                    "screen",
                    r.seed,
                    float(r.throughput),
                    bool(r.success),
                    int(r.stop_time),
                    False,
                    per_run,
                    None,
                    np.asarray(r.tasks_per_step) if c.detail else None,
                    np.asarray(r.tile_visits) if _screen_visits(c) else None,
                )
                for r in row[: c.screen_runs]
            ]
        )
    return out


def _log_cell(lay: EvalLayout, n: int, sim: str, outs: list[RunOutcome]) -> None:
    s = run_stats(outs)
    log.info(
        "%s %s N_a=%d %s: %d run(s), success %s, throughput %s",
        lay.label,
        lay.size,
        n,
        sim,
        s["runs"],
        format_value(s["success_rate"], 2),
        format_value(s["throughput_mean"], 3),
    )
    for o in outs:
        if o.timed_out:
            log.warning(
                "%s %s N_a=%d rhcr seed %d hit the time limit (timed_out)", lay.label, lay.size, n, o.seed
            )
        elif o.error:
            log.warning("%s %s N_a=%d %s seed %d failed: %s", lay.label, lay.size, n, sim, o.seed, o.error)
