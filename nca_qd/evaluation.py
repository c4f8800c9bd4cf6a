"""Evaluation of a trained archive: the paper's tables and figures (§5, appendix D).

The best generator(s) of a run's result archive generate layouts at the training size S and at
S_eval (and at more sizes); each is repaired once. Beside them stand the baselines: the
human-designed layouts of the same sizes and the tiling baseline (the repaired S layout tiled
to S_eval, then repaired). Every layout is simulated over a grid of (agent count, seed):

* exact RHCR (:mod:`nca_qd.sim.rhcr`) for as many runs as the exact budget allows, as
  parallel jobs on the evaluation backend (:mod:`nca_qd.scoring.backend`), each with an
  optional wall-clock limit (a run that hits it is recorded as ``timed_out``);
* the JAX screening simulator (:mod:`nca_qd.sim.screen`) for the rest, labelled
  ``simulator=screen`` everywhere: it is about 25 % pessimistic on throughput and agrees with
  RHCR on congestion about 80 % of the time (33x36; 28 of 32 runs at 101x102).

Statistics (:func:`run_stats`): a run that timed out or failed is counted apart and left out;
``success_rate`` is the share of the other runs that ended without congestion;
``throughput_success_*`` averages successful runs only (the paper's table);
``throughput_*`` averages every completed run (the paper's curves), with the standard error
and a Student-t 95 % interval.

The entry point is ``python -m experiments.evaluate`` (:func:`evaluate` here); the functions
below are usable on their own.
"""

from __future__ import annotations

import csv
import io
import logging
import math
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from nca_qd.errors import NcaQdError
from nca_qd.layouts import get_layout, layout_names

log = logging.getLogger("nca_qd.evaluate")

SUPPORTED = layout_names()  # the multi-agent domains (the maze has experiments.maze_transfer)
SIMULATORS = ("rhcr", "screen")


# ------------------------------------------------------------------------------ records
@dataclass
class EvalLayout:
    """One layout under evaluation (full map, indices into the domain's ``layout_tiles``)."""

    key: str  # unique id, e.g. "nca_c12@33x36"
    label: str  # legend / table name, e.g. "NCA (cell 12)"
    kind: str  # nca | human | tiling
    size: str  # "HxW" of the full map
    which: str  # train | eval | extra
    layout: np.ndarray | None  # repaired (or given) full layout; None: the repair found none
    unrepaired: np.ndarray | None = None
    cell: int | None = None
    nca_iters: int | None = None
    gen_seconds: float | None = None
    repair: Any = None  # nca_qd.scoring.tasks.RepairOutcome, None for human layouts


@dataclass
class SimOutcome:
    """One simulation run, whichever simulator ran it (small: ships between processes)."""

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

    @property
    def completed(self) -> bool:
        return self.error is None and not self.timed_out


@dataclass
class Request:
    """What one table or curve needs of one layout at one agent count."""

    purpose: str  # main_train | main_eval | sweep_train | sweep_eval | sizes
    layout: str  # EvalLayout.key
    n_agents: int
    screen_runs: int
    exact_runs: int
    detail: bool = False  # keep tasks per step and tile visits


def size_str(shape: Sequence[int]) -> str:
    return f"{int(shape[0])}x{int(shape[1])}"


def size_map(block: Mapping[str, Any], key: str) -> dict[str, Any]:
    """``block[key]``: a mapping from "HxW" to a value (null: empty)."""
    value = block.get(key)
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise NcaQdError(f"sizes.{key} must map sizes to values, e.g. {{45x47: ...}}, got {value!r}")
    return {str(k): v for k, v in value.items()}


def parse_size(text: str) -> tuple[int, int]:
    try:
        h, w = str(text).lower().split("x")
        return int(h), int(w)
    except ValueError:
        raise NcaQdError(f"a size must be written HxW (e.g. 45x47), got {text!r}") from None


# ------------------------------------------------------------------------------ the run
def load_run(run_dir: str | Path, domain: str | None = None) -> tuple[Any, dict[str, np.ndarray]]:
    """The run's config and result archive, checked: a run directory of a supported domain
    (and of ``domain`` if given) whose result archive holds at least one elite."""
    from omegaconf import OmegaConf

    from nca_qd.experiment import CONFIG_FILE, load_archive, load_run_config

    path = Path(run_dir)
    if not path.is_dir():
        raise NcaQdError(f"run_dir {path} does not exist")
    if not (path / CONFIG_FILE).is_file():
        raise NcaQdError(f"{path} is not a run directory ({CONFIG_FILE} missing)")
    cfg = load_run_config(path)
    name = OmegaConf.select(cfg, "domain.name")
    from nca_qd.domains import DOMAINS

    if name in DOMAINS and name not in SUPPORTED:
        raise NcaQdError(f"{path} is a {name} run: experiments.evaluate supports only {', '.join(SUPPORTED)}")
    if name not in SUPPORTED:
        raise NcaQdError(
            f"{path}: unknown domain {name!r} in {CONFIG_FILE} (supported: {', '.join(SUPPORTED)})"
        )
    if domain is not None and str(domain) != name:
        raise NcaQdError(f"domain={domain} given, but {path} is a {name} run")
    archive = load_archive(path, "result")
    if not np.isfinite(np.asarray(archive["objective"])).any():
        raise NcaQdError(f"{path}: the result archive is empty (no generator to evaluate)")
    return cfg, archive


def pick_cells(objective: np.ndarray, elites: Any) -> np.ndarray:
    """Archive cells to evaluate: ``elites`` best (an int) or the listed cells (which must hold
    elites), best first as :func:`nca_qd.experiment.select_elites` orders them."""
    from nca_qd.experiment import select_elites

    objective = np.asarray(objective)
    if isinstance(elites, bool):
        raise NcaQdError(f"elites must be a count or a list of cells, got {elites!r}")
    if isinstance(elites, (int, np.integer)) or (isinstance(elites, str) and elites.isdigit()):
        n = int(elites)
        if n < 1:
            raise NcaQdError(f"elites must be >= 1, got {n}")
        return select_elites(objective, n)
    try:
        cells = [int(c) for c in elites]
    except (TypeError, ValueError):
        raise NcaQdError(f"elites must be a count or a list of cells, got {elites!r}") from None
    bad = [c for c in cells if not 0 <= c < objective.size or not np.isfinite(objective[c])]
    if bad:
        raise NcaQdError(f"no elite in archive cell(s) {bad}")
    if not cells:
        raise NcaQdError("elites is an empty list")
    return np.asarray(cells, dtype=int)


# ------------------------------------------------------------------------------ shapes
def full_shape(domain_name: str, region: Sequence[int]) -> tuple[int, int]:
    """Full-map shape of a generated region (warehouse: plus the workstation columns)."""
    return get_layout(domain_name).full_shape((int(region[0]), int(region[1])))


def region_shape(domain_name: str, full: Sequence[int]) -> tuple[int, int]:
    """The NCA's region of a full map of shape ``full``."""
    return get_layout(domain_name).region_shape((int(full[0]), int(full[1])))


def interpolate_iters(
    full: Sequence[int], s_train: Sequence[int], s_eval: Sequence[int], c_train: int, c_eval: int
) -> int:
    """NCA iterations for a size between S and S_eval: linear in the map's side (square root
    of its area) between C at S and C_eval at S_eval, extrapolated beyond, at least 1."""
    side = math.sqrt(full[0] * full[1])
    a, b = math.sqrt(s_train[0] * s_train[1]), math.sqrt(s_eval[0] * s_eval[1])
    if b == a:
        return int(c_eval if side > a else c_train)
    return max(1, int(round(c_train + (side - a) / (b - a) * (c_eval - c_train))))


# ------------------------------------------------------------------------------ layouts
def generate_timed(
    domain, generator, genotypes: np.ndarray, full: Sequence[int], n_iters: int
) -> tuple[list[np.ndarray], list[float]]:
    """Full layouts generated by each genotype at map size ``full`` and the seconds each
    generation took (one at a time, after a compiling warm-up call)."""
    from nca_qd.pipeline import generate

    shape = region_shape(domain.name, full)
    generate(domain, generator, genotypes[:1], shape=shape, n_iters=n_iters)  # compile
    layouts, seconds = [], []
    for g in genotypes:
        t0 = time.perf_counter()
        region = generate(domain, generator, g[None], shape=shape, n_iters=n_iters)[0]
        seconds.append(time.perf_counter() - t0)
        layouts.append(np.asarray(domain.assemble(region), dtype=np.int32))
    return layouts, seconds


def tile_layout(domain_name: str, layout: np.ndarray, full: Sequence[int]) -> np.ndarray:
    """The tiling baseline before repair: the generated region tiled (and cropped) to the
    region of ``full``, the fixed frame added (warehouse: the storage area between the
    workstation columns; manufacturing: the whole map)."""
    kind = get_layout(domain_name)

    def tile(a: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        reps = (-(-shape[0] // a.shape[0]), -(-shape[1] // a.shape[1]))
        return np.tile(a, reps)[: shape[0], : shape[1]]

    region = tile(kind.region(np.asarray(layout)), region_shape(domain_name, full))
    return np.asarray(kind.assemble(region), dtype=np.int32)


def human_layout(domain_name: str, full: Sequence[int], tiles: str) -> np.ndarray | None:
    """The human-designed layout of that size from the reference maps, None if there is none."""
    from nca_qd.io import load_map, reference_maps_dir

    path = reference_maps_dir() / get_layout(domain_name).family / f"human_{size_str(full)}.json"
    if not path.is_file():
        return None
    return load_map(path, tiles).to_array(tiles)


def repair_all(backend, domain_name: str, items: list[tuple[EvalLayout, dict]]) -> None:
    """Repair each ``(layout, options)`` on the backend; sets ``layout`` and ``repair``."""
    from nca_qd.scoring.backend import JobFailed, map_jobs
    from nca_qd.scoring.tasks import RepairOutcome, repair_task

    if not items:
        return
    log.info("repairing %d layout(s) on %s", len(items), backend.describe())
    out = map_jobs(backend, repair_task, [(domain_name, it.unrepaired, opts) for it, opts in items])
    for (it, _), res in zip(items, out):
        if isinstance(res, JobFailed):
            res = RepairOutcome(None, "error", 0.0, None, 0.0, res.error)
        it.repair, it.layout = res, res.layout
        if res.layout is None:
            log.warning(
                "%s at %s: repair found no layout (%s%s)",
                it.label,
                it.size,
                res.status,
                f": {res.error}" if res.error else "",
            )
        else:
            log.info(
                "%s at %s: repaired (%s, Hamming %s, similarity %.3f, %.1f s)",
                it.label,
                it.size,
                res.status,
                res.hamming,
                res.similarity,
                res.seconds,
            )


# ------------------------------------------------------------------------------ agents
def agent_range(spec: Mapping[str, Any], n_ref: int, default_step: int, where: str) -> list[int]:
    """Agent counts of a sweep: ``spec['agents']`` if a list, else ``range(start, stop, step)``
    inclusive; null start: half of ``n_ref``, null stop: 1.25 x ``n_ref`` (rounded to the step),
    null step: ``default_step``."""
    if spec.get("agents") is not None:
        return positive_ints(spec["agents"], f"{where}.agents")
    step = spec.get("step") or default_step
    start = spec.get("start") or max(step, (n_ref // 2) // step * step)
    stop = spec.get("stop") or -(-int(1.25 * n_ref) // step) * step
    for name, v in (("step", step), ("start", start), ("stop", stop)):
        positive_ints([v], f"{where}.{name}")
    if stop < start:
        raise NcaQdError(f"{where}: stop ({stop}) is below start ({start})")
    return list(range(int(start), int(stop) + 1, int(step)))


def scaled_agents(
    full: Sequence[int], n_ref: int, ref_full: Sequence[int], fractions: Sequence[float], round_to: int
) -> list[int]:
    """Agent counts at map size ``full``: ``n_ref`` (the count at ``ref_full``) scaled by the
    map's area, times each fraction, rounded to ``round_to`` (at least ``round_to``)."""
    base = n_ref * (full[0] * full[1]) / (ref_full[0] * ref_full[1])
    out = sorted({max(round_to, int(round(base * f / round_to)) * round_to) for f in fractions})
    return out


def positive_ints(values: Any, where: str) -> list[int]:
    try:
        vals = [values] if isinstance(values, (int, np.integer)) else list(values)
    except TypeError:
        raise NcaQdError(f"{where} must be a list of positive integers, got {values!r}") from None
    for v in vals:
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise NcaQdError(f"{where} must be positive integers, got {v!r}")
    return [int(v) for v in vals]


def check_agents(
    layouts: Mapping[str, EvalLayout], requests: Iterable[Request], scenario: str, tiles: str
) -> None:
    """Before anything runs: every layout must take the most agents asked of it (the
    simulators' own check, with the layout and size named)."""
    from nca_qd.io import array_to_rows
    from nca_qd.sim.scenario import build_scenario

    most: dict[str, int] = {}
    for r in requests:
        most[r.layout] = max(most.get(r.layout, 0), r.n_agents)
    for key, n in most.items():
        lay = layouts[key]
        try:
            build_scenario(
                array_to_rows(lay.layout, tiles), scenario, n_agents=n, source=f"{lay.label} ({lay.size})"
            )
        except NcaQdError as exc:
            raise NcaQdError(f"{exc} (lower the agent counts for this size)") from None


# ------------------------------------------------------------------------------ simulation
def exact_run(
    rows: list[str],
    scenario: str,
    n_agents: int,
    T: int,
    seed: int,
    time_limit_s: float | None,
    window: int,
    replan: int,
    detail: bool,
    planner: Mapping[str, Any] | None = None,
) -> SimOutcome:
    """One exact RHCR run as a backend job (errors of the layout come back in ``error``);
    ``planner``: validated planner knobs (:func:`nca_qd.sim.rhcr.planner_options`)."""
    from nca_qd.sim.rhcr import simulate

    t0 = time.perf_counter()
    try:
        r = simulate(
            rows,
            scenario,
            n_agents,
            T,
            seed,
            window=window,
            replan=replan,
            time_limit_s=time_limit_s,
            **dict(planner or {}),
        )
    except NcaQdError as exc:
        return SimOutcome("rhcr", seed, error=str(exc), seconds=time.perf_counter() - t0)
    return SimOutcome(
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
    )


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


Results = dict[tuple[str, int, str], list[SimOutcome]]


def simulate_cells(
    cells: Mapping[tuple[str, int], Request],
    layouts: Mapping[str, EvalLayout],
    scenario: str,
    tiles: str,
    T: int,
    seed0: int,
    backend,
    exact_cfg: Mapping[str, Any],
    screen_cfg: Mapping[str, Any],
    progress: bool = True,
) -> Results:
    """Run every cell: exact runs as backend jobs (in a background thread, so they overlap
    the screening), screening runs batched by (shape, agent count) in this process.
    Returns ``results[(layout, n_agents, simulator)]``: outcomes in seed order."""
    from concurrent.futures import ThreadPoolExecutor

    from tqdm import tqdm

    from nca_qd.io import array_to_rows
    from nca_qd.scoring.backend import JobFailed, map_jobs
    from nca_qd.sim.rhcr import planner_options

    rows = {k: array_to_rows(v.layout, tiles) for k, v in layouts.items() if v.layout is not None}
    planner = planner_options(exact_cfg, "exact.")
    jobs, slots = [], []
    for (key, n), c in cells.items():
        for i in range(c.exact_runs):
            jobs.append(
                (
                    rows[key],
                    scenario,
                    n,
                    T,
                    seed0 + i,
                    exact_cfg.get("time_limit_s"),
                    int(exact_cfg.get("window", 10)),
                    int(exact_cfg.get("replan", 5)),
                    c.detail,
                    planner,
                )
            )
            slots.append((key, n))
    results: Results = {}
    with ThreadPoolExecutor(max_workers=1) as pool:
        future = None
        if jobs:
            log.info("%d exact RHCR run(s) (T=%d) submitted to %s", len(jobs), T, backend.describe())
            future = pool.submit(map_jobs, backend, exact_run, jobs)
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
        for (shape, n), group in sorted(groups.items(), key=lambda kv: (kv[0][0], kv[0][1])):
            bar.set_postfix(size=size_str(shape), agents=n)
            for c, outs in zip(group, screen_group(group, rows, scenario, n, T, seed0, screen_cfg)):
                results[(c.layout, n, "screen")] = outs
            bar.update(len(group))
        bar.close()
        if future is not None:
            if not future.done():
                log.info("screening done; waiting for the exact runs")
            for (key, n), job, out in zip(slots, jobs, future.result()):
                if isinstance(out, JobFailed):
                    out = SimOutcome("rhcr", job[4], error=out.error)
                results.setdefault((key, n, "rhcr"), []).append(out)
    for k in results:
        results[k].sort(key=lambda o: o.seed)
        _log_cell(layouts[k[0]], k[1], k[2], results[k])
    return results


def screen_group(
    group: list[Request],
    rows: Mapping[str, list[str]],
    scenario: str,
    n: int,
    T: int,
    seed0: int,
    screen_cfg: Mapping[str, Any],
) -> list[list[SimOutcome]]:
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
        replan=int(screen_cfg.get("replan", 5)),
        threads=screen_cfg.get("threads"),
    )
    per_run = (time.perf_counter() - t0) / max(1, runs * len(group))
    out = []
    for c, row in zip(group, res):
        out.append(
            [
                SimOutcome(
                    "screen",
                    r.seed,
                    float(r.throughput),
                    bool(r.success),
                    int(r.stop_time),
                    False,
                    per_run,
                    None,
                    np.asarray(r.tasks_per_step) if c.detail else None,
                    np.asarray(r.tile_visits) if c.detail else None,
                )
                for r in row[: c.screen_runs]
            ]
        )
    return out


def _log_cell(lay: EvalLayout, n: int, sim: str, outs: list[SimOutcome]) -> None:
    s = run_stats(outs)
    log.info(
        "%s %s N_a=%d %s: %d run(s), success %s, throughput %s",
        lay.label,
        lay.size,
        n,
        sim,
        s["runs"],
        _fmt(s["success_rate"], 2),
        _fmt(s["throughput_mean"], 3),
    )
    for o in outs:
        if o.timed_out:
            log.warning(
                "%s %s N_a=%d rhcr seed %d hit the time limit (timed_out)", lay.label, lay.size, n, o.seed
            )
        elif o.error:
            log.warning("%s %s N_a=%d %s seed %d failed: %s", lay.label, lay.size, n, sim, o.seed, o.error)


# ------------------------------------------------------------------------------ statistics
def mean_se_ci(values: Sequence[float]) -> tuple[float, float, float, float]:
    """Mean, standard error and Student-t 95 % interval (NaN where undefined: s.e. and
    interval need two values)."""
    from scipy import stats

    x = np.asarray(values, dtype=float)
    if x.size == 0:
        return (math.nan,) * 4
    m = float(x.mean())
    if x.size < 2:
        return m, math.nan, math.nan, math.nan
    se = float(x.std(ddof=1) / math.sqrt(x.size))
    h = float(stats.t.ppf(0.975, x.size - 1)) * se
    return m, se, m - h, m + h


def run_stats(outs: Sequence[SimOutcome]) -> dict[str, Any]:
    """Figures of a set of runs (see the module docstring for what each averages)."""
    done = [o for o in outs if o.completed]
    succ = [o.throughput for o in done if o.success]
    m, se, lo, hi = mean_se_ci([o.throughput for o in done])
    ms, ses, _, _ = mean_se_ci(succ)
    return {
        "runs": len(outs),
        "completed": len(done),
        "timed_out": sum(o.timed_out for o in outs),
        "errors": sum(o.error is not None for o in outs),
        "success_rate": len(succ) / len(done) if done else math.nan,
        "throughput_success_mean": ms,
        "throughput_success_se": ses,
        "throughput_mean": m,
        "throughput_se": se,
        "ci95_low": lo,
        "ci95_high": hi,
        "sim_seconds_mean": float(np.mean([o.seconds for o in outs])) if outs else math.nan,
    }


def request_runs(results: Results, r: Request) -> dict[str, list[SimOutcome]]:
    """The runs of request ``r`` per simulator: the first ones of its cell (seed order)."""
    out = {}
    for sim, want in (("rhcr", r.exact_runs), ("screen", r.screen_runs)):
        got = results.get((r.layout, r.n_agents, sim), [])[:want]
        if want > 0 and got:
            out[sim] = got
    return out


# ------------------------------------------------------------------------------ writing
def _fmt(v: Any, digits: int = 4) -> str:
    if v is None:
        return ""
    if isinstance(v, (bool, np.bool_)):
        return str(bool(v)).lower()
    if isinstance(v, (float, np.floating)):
        return "" if not math.isfinite(v) else f"{float(v):.{digits}f}"
    return str(v)


def write_csv(
    path: str | Path, rows: Sequence[Mapping[str, Any]], columns: Sequence[str], digits: int = 6
) -> None:
    """Rows as CSV (atomic); NaN and None are empty cells."""
    from nca_qd.io import atomic_write_text

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for row in rows:
        w.writerow([_fmt(row.get(c), digits) for c in columns])
    atomic_write_text(path, buf.getvalue())


def markdown_table(rows: Sequence[Mapping[str, Any]], columns: Sequence[tuple[str, str]]) -> str:
    """A Markdown table of ``rows``; ``columns`` are (key, header) pairs, values pre-formatted."""
    head = "| " + " | ".join(h for _, h in columns) + " |"
    sep = "|" + "|".join("---" for _ in columns) + "|"
    body = ["| " + " | ".join(str(r.get(k, "")) for k, _ in columns) + " |" for r in rows]
    return "\n".join([head, sep, *body]) + "\n"


STAT_COLUMNS = [
    "runs",
    "completed",
    "timed_out",
    "errors",
    "success_rate",
    "throughput_mean",
    "throughput_se",
    "ci95_low",
    "ci95_high",
    "throughput_success_mean",
    "throughput_success_se",
    "sim_seconds_mean",
]
LAYOUT_COLUMNS = ["layout", "kind", "cell", "size", "which"]


def _layout_cols(lay: EvalLayout) -> dict[str, Any]:
    return {"layout": lay.label, "kind": lay.kind, "cell": lay.cell, "size": lay.size, "which": lay.which}


def layout_record(lay: EvalLayout, scenario: str, tiles: str) -> dict[str, Any]:
    """One row of layouts.csv: generation and repair figures of one layout."""
    from nca_qd.io import array_to_rows
    from nca_qd.sim.scenario import build_scenario

    rep = lay.repair
    trav = None
    if lay.layout is not None:
        try:
            trav = build_scenario(array_to_rows(lay.layout, tiles), scenario).n_traversable
        except NcaQdError:
            trav = None
    return {
        **_layout_cols(lay),
        "nca_iters": lay.nca_iters,
        "gen_seconds": lay.gen_seconds,
        "repair_status": rep.status if rep is not None else "given",
        "repair_seconds": rep.seconds if rep is not None else None,
        "similarity": rep.similarity if rep is not None else None,
        "hamming": rep.hamming if rep is not None else None,
        "repair_error": rep.error if rep is not None else None,
        "n_traversable": trav,
        "file": f"layouts/{lay.key.replace('@', '_')}.json",
    }


# ------------------------------------------------------------------------------ plots
def _style(labels: Sequence[str]) -> dict[str, Any]:
    """A fixed colour per layout label: NCA greens/blues, human grey, tiling orange."""
    nca = ["#2a9d3a", "#1f5fbf", "#7b3fb5", "#17a2a2", "#8c564b", "#bcbd22"]
    colours, i = {}, 0
    for lab in labels:
        if lab.startswith("human"):
            colours[lab] = "#555555"
        elif lab.startswith("tiling"):
            colours[lab] = "#e67e22"
        else:
            colours[lab] = nca[i % len(nca)]
            i += 1
    return colours


def _legend_note(ax) -> None:
    ax.legend(fontsize=7, loc="best")
    ax.grid(alpha=0.3)


def plot_curves(
    path: str | Path,
    rows: Sequence[Mapping[str, Any]],
    x: str,
    title: str,
    xlabel: str,
    y: str = "throughput_mean",
    ylabel: str = "throughput",
    band: tuple[str, str] | None = ("ci95_low", "ci95_high"),
) -> None:
    """Lines per (layout, simulator): screen dashed with a shaded band, RHCR solid with
    markers and error bars; the legend names the simulator."""
    import matplotlib.pyplot as plt

    from nca_qd.viz import save_figure

    labels = list(dict.fromkeys(r["layout"] for r in rows))
    colours = _style(labels)
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for lab in labels:
        for sim in SIMULATORS:
            pts = sorted(
                (r for r in rows if r["layout"] == lab and r["simulator"] == sim), key=lambda r: r[x]
            )
            pts = [r for r in pts if _finite(r.get(y))]
            if not pts:
                continue
            xs = np.array([r[x] for r in pts], dtype=float)
            ys = np.array([r[y] for r in pts], dtype=float)
            c = colours[lab]
            if sim == "screen":
                ax.plot(xs, ys, "--", color=c, marker="o", mfc="none", ms=4, label=f"{lab} (screen)")
            else:
                ax.plot(xs, ys, "-", color=c, marker="s", ms=5, label=f"{lab} (RHCR)")
            if band is not None:
                lo = np.array(
                    [r.get(band[0]) if _finite(r.get(band[0])) else np.nan for r in pts], dtype=float
                )
                hi = np.array(
                    [r.get(band[1]) if _finite(r.get(band[1])) else np.nan for r in pts], dtype=float
                )
                if sim == "screen" and len(xs) > 1:
                    ax.fill_between(xs, lo, hi, color=c, alpha=0.15, linewidth=0)
                else:
                    ok = np.isfinite(lo) & np.isfinite(hi)
                    if ok.any():
                        ax.errorbar(
                            xs[ok],
                            ys[ok],
                            yerr=[ys[ok] - lo[ok], hi[ok] - ys[ok]],
                            fmt="none",
                            ecolor=c,
                            capsize=3,
                        )
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(
        title + "\nscreen = JAX screening approximation (~25 % below RHCR); band/bars: 95 % CI", fontsize=8
    )
    _legend_note(ax)
    save_figure(fig, path)


def _finite(v: Any) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and math.isfinite(float(v))


def plot_tile_usage(path: str | Path, panels: Sequence[tuple[str, np.ndarray, np.ndarray]]) -> None:
    """Tile-usage heatmaps side by side: (title, mean visits [H, W], traversable [H, W])."""
    import matplotlib.pyplot as plt

    from nca_qd.viz import save_figure

    n = len(panels)
    h, w = panels[0][1].shape
    scale = min(0.08, 4.0 / max(h, w)) if max(h, w) > 40 else 0.12
    fig, axes = plt.subplots(1, n, figsize=(max(3.5, n * (w * scale + 1.2)), h * scale + 1.0), squeeze=False)
    for ax, (title, visits, trav) in zip(axes[0], panels):
        img = np.where(trav, visits, np.nan).astype(float)
        cmap = plt.get_cmap("viridis").with_extremes(bad="#d0d0d0")
        im = ax.imshow(img, cmap=cmap, interpolation="nearest")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(title, fontsize=8)
        fig.colorbar(im, ax=ax, fraction=0.046, pad=0.02, label="visits per run")
    save_figure(fig, path)


def plot_sizes(path: str | Path, rows: Sequence[Mapping[str, Any]]) -> None:
    """The "more sizes" figure: best mean throughput over the agent counts tried at each
    size, and the agent count where it peaks (the paper's "maximum scalability")."""
    import matplotlib.pyplot as plt

    from nca_qd.viz import save_figure

    sizes = sorted({r["size"] for r in rows}, key=lambda s: math.prod(parse_size(s)))
    pos = {s: i for i, s in enumerate(sizes)}
    labels = list(dict.fromkeys(r["layout"] for r in rows))
    colours = _style(labels)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for lab in labels:
        for sim in SIMULATORS:
            pts = sorted(
                (
                    r
                    for r in rows
                    if r["layout"] == lab and r["simulator"] == sim and _finite(r.get("max_throughput_mean"))
                ),
                key=lambda r: pos[r["size"]],
            )
            if not pts:
                continue
            xs = [pos[r["size"]] for r in pts]
            style = dict(ls="--", marker="o", mfc="none") if sim == "screen" else dict(ls="-", marker="s")
            name = f"{lab} ({'screen' if sim == 'screen' else 'RHCR'})"
            axes[0].plot(xs, [r["max_throughput_mean"] for r in pts], color=colours[lab], label=name, **style)
            err = [
                (x, r["max_throughput_mean"], r["max_throughput_se"])
                for x, r in zip(xs, pts)
                if _finite(r.get("max_throughput_se"))
            ]
            if err:
                axes[0].errorbar(
                    [a for a, _, _ in err],
                    [b for _, b, _ in err],
                    yerr=[c for _, _, c in err],
                    fmt="none",
                    ecolor=colours[lab],
                    capsize=3,
                )
            axes[1].plot(xs, [r["agents_at_max"] for r in pts], color=colours[lab], label=name, **style)
    for ax, yl in zip(axes, ("max mean throughput (bars: s.e.)", "agents at the max (max scalability)")):
        ax.set_xticks(range(len(sizes)))
        ax.set_xticklabels(sizes, rotation=30, fontsize=8)
        ax.set_xlabel("map size")
        ax.set_ylabel(yl)
        _legend_note(ax)
    fig.suptitle("Scaling to more sizes (screen = JAX screening approximation)", fontsize=9)
    save_figure(fig, path)


def plot_tasks(
    path: str | Path,
    series: Sequence[tuple[str, str, np.ndarray, np.ndarray, np.ndarray]],
    smooth: int,
    title: str,
) -> None:
    """Tasks finished per timestep: (layout, simulator, mean, low, high), moving average over
    ``smooth`` steps for the picture (the CSV keeps every step)."""
    import matplotlib.pyplot as plt

    from nca_qd.viz import save_figure

    def ma(a: np.ndarray) -> np.ndarray:
        if smooth <= 1 or a.size < smooth:
            return a
        return np.convolve(np.nan_to_num(a), np.ones(smooth) / smooth, mode="valid")

    colours = _style(list(dict.fromkeys(s[0] for s in series)))
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for lab, sim, m, lo, hi in series:
        t = np.arange(1, m.size + 1)[(smooth - 1 if smooth > 1 and m.size >= smooth else 0) :]
        ls = "--" if sim == "screen" else "-"
        ax.plot(
            t, ma(m), ls, color=colours[lab], lw=1, label=f"{lab} ({'screen' if sim == 'screen' else 'RHCR'})"
        )
        if np.isfinite(lo).any():
            ax.fill_between(t, ma(lo), ma(hi), color=colours[lab], alpha=0.15, linewidth=0)
    ax.set_xlabel("timestep")
    ax.set_ylabel(
        f"tasks finished per step ({smooth}-step moving average)" if smooth > 1 else "tasks finished per step"
    )
    ax.set_title(title + "\nband: 95 % CI over runs; a congested run adds zeros after it stops", fontsize=8)
    _legend_note(ax)
    save_figure(fig, path)


# ------------------------------------------------------------------------------ the command
@dataclass
class Evaluation:
    """Everything :func:`evaluate` built: layouts, requests, raw results, summary rows."""

    domain: str
    out: Path
    layouts: dict[str, EvalLayout]
    requests: list[Request]
    results: Results
    summary: list[dict[str, Any]]
    summary_markdown: str


def evaluate(ecfg: Mapping[str, Any], domain_override: str | None = None) -> Evaluation:
    """The whole evaluation described by ``ecfg`` (experiments/conf/evaluate.yaml, as plain
    containers); writes every output under ``ecfg['out']`` (default <run_dir>/evaluation)."""
    from omegaconf import OmegaConf

    from nca_qd.domains import make_domain
    from nca_qd.io import atomic_write_text
    from nca_qd.scoring.backend import make_backend

    ecfg = _validated(ecfg)
    run_dir = Path(ecfg["run_dir"])
    cfg, archive = load_run(run_dir, domain_override)
    dcfg = OmegaConf.to_container(cfg.domain, resolve=True)
    name = dcfg["name"]
    out = Path(ecfg["out"]) if ecfg.get("out") else run_dir / "evaluation"
    by_s_eval = ecfg["select"]["by"] == "s_eval"
    cells_idx = pick_cells(archive["objective"], ecfg["select"]["pool"] if by_s_eval else ecfg["elites"])
    domain = make_domain(dcfg)
    tiles = domain.layout_tiles
    plan = _Plan(ecfg, dcfg, name)
    backend = make_backend(ecfg.get("eval"))  # an unreachable scheduler fails here, early
    selection: Selection | None = None
    try:
        if by_s_eval:
            selection = select_scalable(ecfg, dcfg, domain, archive, cells_idx, plan, backend)
            cells_idx = selection.cells
        log.info(
            "evaluating %s (%s): cell(s) %s; sizes %s",
            run_dir,
            name,
            [int(c) for c in cells_idx],
            ", ".join(plan.all_sizes),
        )
        ready = (
            {selection.layouts[int(c)].key: selection.layouts[int(c)] for c in cells_idx} if selection else {}
        )
        layouts = _build_layouts(ecfg, dcfg, domain, archive, cells_idx, plan, backend, ready)
        requests = plan.requests(layouts)
        check_agents(layouts, requests, name, tiles)
        cells = merge_requests(requests)
        if ecfg["screen"]["where"] == "rest":
            for c in cells.values():
                if c.exact_runs > 0:
                    c.screen_runs = 0
        results = simulate_cells(
            cells,
            layouts,
            name,
            tiles,
            int(ecfg["T"]),
            int(ecfg["seed"]),
            backend,
            ecfg["exact"],
            ecfg["screen"],
            bool(ecfg["progress"]),
        )
    finally:
        backend.close()
    out.mkdir(parents=True, exist_ok=True)
    t_write = time.time()
    atomic_write_text(out / "evaluate_config.yaml", OmegaConf.to_yaml(OmegaConf.create(ecfg)))
    summary, md = _write_outputs(out, ecfg, name, domain, layouts, requests, results, plan)
    if selection:
        _write_selection(out, selection, tiles)
    remove_stale_outputs(out, t_write - 2.0)
    return Evaluation(name, out, layouts, requests, results, summary, md)


# Files this command writes (patterns under ``out``); one of them older than this evaluation's
# writing is left from an earlier evaluation into the same folder (e.g. a curve turned off).
OUTPUT_PATTERNS = (
    "summary.csv",
    "summary.md",
    "runs.csv",
    "layouts.csv",
    "layouts_*.png",
    "selection.csv",
    "selection/*.json",
    "layouts/*.json",
    "throughput_vs_agents_*.csv",
    "throughput_vs_agents_*.png",
    "tasks_over_time_*.csv",
    "tasks_over_time_*.png",
    "tile_usage_*.csv",
    "tile_usage_*.png",
    "scaling_sizes.csv",
    "scaling_sizes.png",
    "scaling_sizes_grid.csv",
)


def remove_stale_outputs(out: Path, before: float) -> list[Path]:
    """Delete this command's output files in ``out`` last written before ``before`` (epoch
    seconds): leftovers of an earlier evaluation that this one did not rewrite."""
    stale = [
        p for pat in OUTPUT_PATTERNS for p in out.glob(pat) if p.is_file() and p.stat().st_mtime < before
    ]
    for p in stale:
        log.info("removing %s (left from an earlier evaluation)", p)
        p.unlink()
    return stale


def _validated(ecfg: Mapping[str, Any]) -> dict[str, Any]:
    """Plain copy of the config with its numbers checked (one clear error each)."""
    e = dict(ecfg)

    def pos(path: str, allow_zero: bool = False) -> None:
        node: Any = e
        for k in path.split("."):
            node = node[k]
        low = 0 if allow_zero else 1
        if isinstance(node, bool) or not isinstance(node, int) or node < low:
            raise NcaQdError(f"{path} must be an integer >= {low}, got {node!r}")

    if not e.get("run_dir"):
        raise NcaQdError("give run_dir=<run directory>")
    for p in (
        "T",
        "runs.train",
        "runs.eval",
        "sweep.train.runs",
        "sweep.eval.runs",
        "sizes.runs",
        "sizes.round_to",
        "exact.window",
        "exact.replan",
        "screen.replan",
    ):
        pos(p)
    for p in ("exact.train", "exact.eval", "exact.sweep_train", "exact.sweep_eval", "exact.sizes", "seed"):
        pos(p, allow_zero=True)
    tl = e["exact"].get("time_limit_s")
    if tl is not None and (isinstance(tl, bool) or not isinstance(tl, (int, float)) or tl <= 0):
        raise NcaQdError(f"exact.time_limit_s must be a positive number or null, got {tl!r}")
    from nca_qd.sim.rhcr import planner_options

    planner_options(e["exact"], "exact.")
    sel = e.setdefault("select", {"by": "s", "pool": 10, "runs": 2, "T": 1000})
    if sel.get("by") not in ("s", "s_eval"):
        raise NcaQdError(f"select.by must be s or s_eval, got {sel.get('by')!r}")
    if sel["by"] == "s_eval":
        for p in ("select.pool", "select.runs", "select.T"):
            pos(p)
        if isinstance(e["elites"], bool) or not isinstance(e["elites"], int):
            raise NcaQdError(
                f"select.by=s_eval picks a number of elites; elites must be a count, got {e['elites']!r}"
            )
        if e["elites"] > sel["pool"]:
            raise NcaQdError(f"elites ({e['elites']}) exceeds select.pool ({sel['pool']})")
    if e["screen"]["where"] not in ("all", "rest"):
        raise NcaQdError(f"screen.where must be all or rest, got {e['screen']['where']!r}")
    for k in ("train", "eval"):
        if e["exact"][k] > e["runs"][k]:
            raise NcaQdError(f"exact.{k} ({e['exact'][k]}) exceeds runs.{k} ({e['runs'][k]})")
    return e


class _Plan:
    """Sizes, agent counts and run counts of every table and curve."""

    def __init__(self, e: Mapping[str, Any], d: Mapping[str, Any], name: str):
        self.e, self.d, self.name = e, d, name
        self.s_train = full_shape(name, d["size"]["train"])
        self.s_eval = full_shape(name, d["size"]["eval"])
        self.n_train = int(e["agents"]["train"] or d["n_agents"]["train"])
        self.n_eval = int(e["agents"]["eval"] or d["n_agents"]["eval"])
        self.sweep_train = agent_range(e["sweep"]["train"], self.n_train, 10, "sweep.train")
        self.sweep_eval = agent_range(
            e["sweep"]["eval"], self.n_eval, get_layout(name).eval_agent_step, "sweep.eval"
        )
        sz = e["sizes"]
        extra = [tuple(positive_ints(s, "sizes.shapes")) for s in sz["shapes"]]
        for s in extra:
            if len(s) != 2:
                raise NcaQdError(f"sizes.shapes entries must be [rows, cols], got {list(s)}")
        curve = list(extra)
        if sz["include_main"]:
            curve = [self.s_train, *curve, self.s_eval]
        self.curve = list(dict.fromkeys(curve))  # map sizes on the "more sizes" curve
        self.extra = [s for s in dict.fromkeys(extra) if s not in (self.s_train, self.s_eval)]
        ref_n = int(sz.get("reference_agents") or self.n_eval)
        fr = sz["fractions"]
        if not fr or any(isinstance(f, bool) or not isinstance(f, (int, float)) or f <= 0 for f in fr):
            raise NcaQdError(f"sizes.fractions must be positive numbers, got {fr!r}")
        explicit = {
            parse_size(k): positive_ints(v, f"sizes.agents.{k}") for k, v in size_map(sz, "agents").items()
        }
        for key in ("agents", "nca_iters", "n_shelves"):
            stray = [k for k in size_map(sz, key) if parse_size(k) not in self.curve]
            if stray:
                raise NcaQdError(
                    f"sizes.{key} names {', '.join(map(str, stray))}, not a size "
                    f"of the curve ({', '.join(size_str(s) for s in self.curve)})"
                )
        self.curve_agents = {
            s: explicit.get(s) or scaled_agents(s, ref_n, self.s_eval, sz["fractions"], int(sz["round_to"]))
            for s in self.curve
        }
        self.all_sizes = [size_str(s) for s in dict.fromkeys([self.s_train, self.s_eval, *self.extra])]

    def which(self, shape: tuple[int, int]) -> str:
        return "train" if shape == self.s_train else "eval" if shape == self.s_eval else "extra"

    def most_agents(self, shape: tuple[int, int]) -> int:
        """The most agents any table or curve puts on a map of this size."""
        ns = list(self.curve_agents.get(shape, []))
        if shape == self.s_train:
            ns += [self.n_train, *self.sweep_train]
        if shape == self.s_eval:
            ns += [self.n_eval, *self.sweep_eval]
        return max(ns) if ns else 1

    def requests(self, layouts: Mapping[str, EvalLayout]) -> list[Request]:
        e, ex = self.e, self.e["exact"]
        out: list[Request] = []
        for key, lay in layouts.items():
            if lay.layout is None:
                continue
            shape = lay.layout.shape
            if shape == self.s_train:
                out.append(Request("main_train", key, self.n_train, e["runs"]["train"], ex["train"], True))
                out += [
                    Request("sweep_train", key, n, e["sweep"]["train"]["runs"], ex["sweep_train"])
                    for n in self.sweep_train
                ]
            if shape == self.s_eval:
                out.append(Request("main_eval", key, self.n_eval, e["runs"]["eval"], ex["eval"], True))
                out += [
                    Request("sweep_eval", key, n, e["sweep"]["eval"]["runs"], ex["sweep_eval"])
                    for n in self.sweep_eval
                ]
            if shape in self.curve_agents and lay.kind != "tiling":
                out += [
                    Request("sizes", key, n, e["sizes"]["runs"], ex["sizes"])
                    for n in self.curve_agents[shape]
                ]
        return out


def _repair_opts(
    e: Mapping[str, Any], d: Mapping[str, Any], plan: _Plan, shape: tuple[int, int]
) -> dict[str, Any]:
    """Repair options at a full-map size: the run's (train or eval block), N_s of the human
    layout at other sizes (or ``sizes.n_shelves``), traversable >= the most agents simulated
    (manufacturing), then this command's ``repair`` overrides."""
    from nca_qd.scoring.tasks import repair_options

    which = plan.which(shape)
    opts = repair_options(d, "train" if which == "train" else "eval")
    if which == "extra":
        opts.pop("n_shelves", None)
        n_s = size_map(e["sizes"], "n_shelves").get(size_str(shape))
        if n_s is not None:
            opts["n_shelves"] = int(n_s)
    opts["n_agents"] = max(int(opts.get("n_agents", 0)), plan.most_agents(shape))
    opts.update({k: v for k, v in (e.get("repair") or {}).items() if v is not None})
    return opts


@dataclass
class Selection:
    """What ``select.by=s_eval`` chose and why: ``cells`` (best first), one ``rows`` entry per
    candidate (selection.csv), and every candidate's generated and repaired S_eval layout by
    cell, which the evaluation reuses rather than generating and repairing it again (a
    time-budgeted repair need not give the same layout twice)."""

    cells: np.ndarray
    rows: list[dict[str, Any]]
    layouts: dict[int, EvalLayout]


def select_scalable(e, d, domain, archive, pool: np.ndarray, plan: _Plan, backend) -> Selection:
    """``elites`` cells picked among ``pool`` (the best at S) by a screening run at S_eval.

    Each pool generator generates at S_eval (C_eval iterations) and is repaired; its layout
    is screened with N_a_eval agents (``select.runs`` seeds, ``select.T`` steps) and the pool
    is ranked by mean screened throughput (a congested run counts the tasks it finished),
    then by the S objective. The generators that scale are not always the best at S (the
    paper's protocol, ``select.by=s``, evaluates those).
    """
    from nca_qd.io import array_to_rows
    from nca_qd.pipeline import make_generator
    from nca_qd.sim.scenario import build_scenario
    from nca_qd.sim.screen import simulate_scenarios

    sel, name, tiles = e["select"], domain.name, domain.layout_tiles
    c_eval, size = int(d["nca_iters"]["eval"]), size_str(plan.s_eval)
    objective = np.asarray(archive["objective"])
    lays, secs = generate_timed(
        domain, make_generator(domain), archive["genotypes"][pool], plan.s_eval, c_eval
    )
    items = [
        EvalLayout(
            f"nca_c{int(c)}@{size}",
            f"NCA (cell {int(c)})",
            "nca",
            size,
            "eval",
            None,
            lay,
            int(c),
            c_eval,
            sec,
        )
        for c, lay, sec in zip(pool, lays, secs)
    ]
    log.info(
        "selecting %d of %d generator(s) by a screening run at %s (%d agents, %d run(s), T=%d)",
        int(e["elites"]),
        len(pool),
        size,
        plan.n_eval,
        sel["runs"],
        sel["T"],
    )
    repair_all(backend, name, [(it, _repair_opts(e, d, plan, plan.s_eval)) for it in items])
    rows, scens, scored = [], [], []
    for it in items:
        row = {
            "cell": it.cell,
            "objective_s": float(objective[it.cell]),
            "repair_status": it.repair.status if it.repair else "",
            "screen_runs": 0,
            "screen_success_rate": math.nan,
            "screen_throughput_mean": math.nan,
            "note": "",
            "selected": False,
        }
        rows.append(row)
        if it.layout is None:
            row["note"] = "repair found no layout"
            continue
        try:
            scens.append(
                build_scenario(array_to_rows(it.layout, tiles), name, n_agents=plan.n_eval, source=it.label)
            )
            scored.append(row)
        except NcaQdError as err:
            row["note"] = str(err)
    if scens:
        seeds = range(int(e["seed"]), int(e["seed"]) + int(sel["runs"]))
        res = simulate_scenarios(
            scens,
            plan.n_eval,
            int(sel["T"]),
            seeds,
            replan=int(e["screen"]["replan"]),
            threads=e["screen"].get("threads"),
        )
        for row, runs in zip(scored, res):
            row["screen_runs"] = len(runs)
            row["screen_success_rate"] = float(np.mean([r.success for r in runs]))
            row["screen_throughput_mean"] = float(np.mean([r.throughput for r in runs]))
    ranked = sorted(scored, key=lambda r: (-r["screen_throughput_mean"], -r["objective_s"]))
    if not ranked:
        raise NcaQdError(
            f"select.by=s_eval: none of the {len(pool)} generator(s) gave a "
            f"layout to screen at {size} (see the log)"
        )
    for r in ranked[: int(e["elites"])]:
        r["selected"] = True
    for r in ranked:
        log.info(
            "cell %d: S objective %.3f, screened at %s: throughput %.3f, success %.2f%s",
            r["cell"],
            r["objective_s"],
            size,
            r["screen_throughput_mean"],
            r["screen_success_rate"],
            " (selected)" if r["selected"] else "",
        )
    return Selection(
        np.asarray([r["cell"] for r in ranked[: int(e["elites"])]], dtype=int),
        rows,
        {it.cell: it for it in items},
    )


def _write_selection(out: Path, selection: Selection, tiles: str) -> None:
    """selection.csv, and each candidate's repaired S_eval layout under selection/ (so the
    survivors of the screen can go to exact RHCR without being generated again)."""
    from nca_qd.io import MapFile, array_to_rows, save_map

    rows = []
    for r in selection.rows:
        item = selection.layouts[r["cell"]]
        r = {**r, "file": ""}
        if item.layout is not None:
            stem = f"nca_c{item.cell}_{item.size}"
            save_map(
                out / "selection" / f"{stem}.json",
                MapFile(stem, array_to_rows(item.layout, tiles), {"kind": "nca", "cell": item.cell}),
            )
            r["file"] = f"selection/{stem}.json"
        rows.append(r)
    write_csv(out / "selection.csv", rows, list(rows[0]))


def _build_layouts(
    e, d, domain, archive, cells_idx, plan: _Plan, backend, ready: Mapping[str, EvalLayout] | None = None
) -> dict[str, EvalLayout]:
    """Generate (NCA), load (human) and tile, then repair everything that needs it. NCA
    layouts already generated and repaired (``ready``, by key: the S_eval layouts of a
    selection) are taken as they are."""
    from nca_qd.pipeline import make_generator

    name, tiles = domain.name, domain.layout_tiles
    generator = make_generator(domain)
    genotypes = np.asarray(archive["genotypes"][cells_idx])
    layouts: dict[str, EvalLayout] = {}
    sizes = list(dict.fromkeys([plan.s_train, plan.s_eval, *plan.extra]))
    c_train, c_eval = int(d["nca_iters"]["train"]), int(d["nca_iters"]["eval"])
    iters_cfg = {
        parse_size(k): positive_ints(v, f"sizes.nca_iters.{k}")[0]
        for k, v in size_map(e["sizes"], "nca_iters").items()
    }
    for shape in sizes:
        which = plan.which(shape)
        n_iters = (
            c_train
            if which == "train"
            else c_eval
            if which == "eval"
            else iters_cfg.get(shape) or interpolate_iters(shape, plan.s_train, plan.s_eval, c_train, c_eval)
        )
        keys = [f"nca_c{int(c)}@{size_str(shape)}" for c in cells_idx]
        todo = [i for i, k in enumerate(keys) if k not in (ready or {})]
        made: dict[int, tuple[np.ndarray, float]] = {}
        if todo:
            t0 = time.perf_counter()
            lays, secs = generate_timed(domain, generator, genotypes[todo], shape, n_iters)
            made = dict(zip(todo, zip(lays, secs)))
            log.info(
                "generated %d layout(s) at %s (C=%d) in %.1f s",
                len(todo),
                size_str(shape),
                n_iters,
                time.perf_counter() - t0,
            )
        for i, (c, key) in enumerate(zip(cells_idx, keys)):
            if i in made:
                lay, sec = made[i]
                item = EvalLayout(
                    key,
                    f"NCA (cell {int(c)})",
                    "nca",
                    size_str(shape),
                    which,
                    None,
                    lay,
                    int(c),
                    n_iters,
                    sec,
                )
            else:
                item = ready[key]
                log.info(
                    "%s at %s: the selection's layout (generated and repaired there)", item.label, item.size
                )
            layouts[key] = item
    first = [
        (layouts[k], _repair_opts(e, d, plan, plan.s_train))
        for k in layouts
        if layouts[k].size == size_str(plan.s_train)
    ]
    repair_all(backend, name, first)  # S first: the tiling baseline starts from it
    rest = [
        (lay, _repair_opts(e, d, plan, parse_size(lay.size)))
        for lay in layouts.values()
        if lay.repair is None
    ]
    if e["baselines"]["tiling"] and plan.s_eval != plan.s_train:
        best = layouts[f"nca_c{int(cells_idx[0])}@{size_str(plan.s_train)}"]
        if best.layout is None:
            log.warning("no tiling baseline: the best generator's S layout was not repaired")
        else:
            tiled = EvalLayout(
                f"tiling_c{best.cell}@{size_str(plan.s_eval)}",
                f"tiling (cell {best.cell})",
                "tiling",
                size_str(plan.s_eval),
                "eval",
                None,
                tile_layout(name, best.layout, plan.s_eval),
                best.cell,
            )
            layouts[tiled.key] = tiled
            rest.append((tiled, _repair_opts(e, d, plan, plan.s_eval)))
    repair_all(backend, name, rest)
    if e["baselines"]["human"]:
        for shape in dict.fromkeys([*sizes, *plan.curve]):
            lay = human_layout(name, shape, tiles)
            if lay is None:
                log.warning(
                    "no human-designed %s layout of size %s in the reference maps; that baseline is left out",
                    name,
                    size_str(shape),
                )
                continue
            item = EvalLayout(
                f"human@{size_str(shape)}", "human", "human", size_str(shape), plan.which(shape), lay
            )
            layouts[item.key] = item
    return layouts


def _write_outputs(
    out: Path,
    e,
    name: str,
    domain,
    layouts: dict[str, EvalLayout],
    requests: list[Request],
    results: Results,
    plan: _Plan,
):
    """Every CSV and PNG, the summary table (CSV and Markdown); returns (rows, markdown)."""
    from nca_qd.io import MapFile, array_to_rows, save_map
    from nca_qd.viz import render_layouts

    tiles = domain.layout_tiles
    # layouts: files, pictures, generation and repair figures
    lay_rows = [layout_record(l, name, tiles) for l in layouts.values()]
    for lay in layouts.values():
        stem = lay.key.replace("@", "_")
        if lay.layout is not None:
            save_map(
                out / "layouts" / f"{stem}.json",
                MapFile(f"{stem}", array_to_rows(lay.layout, tiles), {"kind": lay.kind, "cell": lay.cell}),
            )
        if lay.unrepaired is not None:
            save_map(
                out / "layouts" / f"{stem}_unrepaired.json",
                MapFile(f"{stem}_unrepaired", array_to_rows(lay.unrepaired, tiles)),
            )
    write_csv(out / "layouts.csv", lay_rows, list(lay_rows[0]))
    for size in dict.fromkeys(l.size for l in layouts.values()):
        shown = [l for l in layouts.values() if l.size == size and l.layout is not None]
        if shown:
            render_layouts(
                out / f"layouts_{size}.png",
                [l.layout for l in shown],
                tiles,
                domain.palette,
                [f"{l.label} {l.size}" for l in shown],
            )
    # every run
    run_rows = []
    for (key, n, sim), outs in results.items():
        for o in outs:
            run_rows.append(
                {
                    **_layout_cols(layouts[key]),
                    "n_agents": n,
                    "simulator": sim,
                    "seed": o.seed,
                    "throughput": o.throughput,
                    "success": o.success,
                    "stop_time": o.stop_time,
                    "timed_out": o.timed_out,
                    "seconds": o.seconds,
                    "error": o.error,
                }
            )
    write_csv(
        out / "runs.csv",
        run_rows,
        LAYOUT_COLUMNS
        + [
            "n_agents",
            "simulator",
            "seed",
            "throughput",
            "success",
            "stop_time",
            "timed_out",
            "seconds",
            "error",
        ],
    )
    stat_rows: dict[str, list[dict[str, Any]]] = {}
    for r in requests:
        for sim, outs in request_runs(results, r).items():
            stat_rows.setdefault(r.purpose, []).append(
                {
                    **_layout_cols(layouts[r.layout]),
                    "n_agents": r.n_agents,
                    "simulator": sim,
                    **run_stats(outs),
                }
            )
    curve_cols = LAYOUT_COLUMNS + ["n_agents", "simulator"] + STAT_COLUMNS
    T = int(e["T"])
    for which in ("train", "eval"):
        rows = stat_rows.get(f"sweep_{which}", [])
        if rows:
            stem = f"throughput_vs_agents_{which}"
            write_csv(out / f"{stem}.csv", rows, curve_cols)
            plot_curves(
                out / f"{stem}.png",
                rows,
                "n_agents",
                f"{name}: throughput vs agents at {rows[0]['size']} (T={T})",
                "agents",
            )
        _write_detail(out, which, name, layouts, requests, results, T, int(e["tasks_smooth"]), tiles)
    size_rows = stat_rows.get("sizes", [])
    if size_rows:
        write_csv(out / "scaling_sizes_grid.csv", size_rows, curve_cols)
        peak = _peaks(size_rows)
        write_csv(
            out / "scaling_sizes.csv",
            peak,
            [
                "layout",
                "kind",
                "cell",
                "size",
                "simulator",
                "agents_tried",
                "max_throughput_mean",
                "max_throughput_se",
                "agents_at_max",
                "success_rate_at_max",
            ],
        )
        plot_sizes(out / "scaling_sizes.png", peak)
    summary = _summary_rows(name, layouts, requests, results, plan)
    write_csv(out / "summary.csv", summary, list(summary[0]) if summary else ["layout"])
    md = _summary_markdown(name, summary, T)
    from nca_qd.io import atomic_write_text

    atomic_write_text(out / "summary.md", md)
    return summary, md


def _peaks(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per (layout, size, simulator): the best mean throughput and the agent count there."""
    groups: dict[tuple, list] = {}
    for r in rows:
        groups.setdefault((r["layout"], r["size"], r["simulator"]), []).append(r)
    out = []
    for (lab, size, sim), rs in groups.items():
        ok = [r for r in rs if _finite(r["throughput_mean"])]
        best = max(ok, key=lambda r: r["throughput_mean"]) if ok else None
        out.append(
            {
                "layout": lab,
                "kind": rs[0]["kind"],
                "cell": rs[0]["cell"],
                "size": size,
                "simulator": sim,
                "agents_tried": " ".join(str(r["n_agents"]) for r in sorted(rs, key=lambda r: r["n_agents"])),
                "max_throughput_mean": best["throughput_mean"] if best else math.nan,
                "max_throughput_se": best["throughput_se"] if best else math.nan,
                "agents_at_max": best["n_agents"] if best else None,
                "success_rate_at_max": best["success_rate"] if best else math.nan,
            }
        )
    return out


def _write_detail(
    out: Path, which: str, scenario: str, layouts, requests, results, T: int, smooth: int, tiles: str
) -> None:
    """Tasks over time and tile-usage heatmaps of the main comparison's runs at one size."""
    from nca_qd.io import array_to_rows
    from nca_qd.sim.scenario import build_scenario

    reqs = [r for r in requests if r.purpose == f"main_{which}"]
    series, task_rows, panels, heat_rows = [], [], [], []
    for r in reqs:
        lay = layouts[r.layout]
        runs = request_runs(results, r)
        for sim, outs in runs.items():
            tps = [o.tasks_per_step for o in outs if o.completed and o.tasks_per_step is not None]
            if tps:
                mat = np.zeros((len(tps), T))
                for i, tp in enumerate(tps):
                    mat[i, : min(T, tp.size)] = tp[:T]
                m = mat.mean(0)
                if len(tps) > 1:
                    from scipy import stats

                    h = stats.t.ppf(0.975, len(tps) - 1) * mat.std(0, ddof=1) / math.sqrt(len(tps))
                    lo, hi = m - h, m + h
                else:
                    lo = hi = np.full(T, np.nan)
                series.append((lay.label, sim, m, lo, hi))
                task_rows += [
                    {
                        "layout": lay.label,
                        "kind": lay.kind,
                        "size": lay.size,
                        "n_agents": r.n_agents,
                        "simulator": sim,
                        "runs": len(tps),
                        "t": t + 1,
                        "tasks_mean": m[t],
                        "ci95_low": lo[t],
                        "ci95_high": hi[t],
                    }
                    for t in range(T)
                ]
        # heatmap: RHCR runs where there are any, else the screen's
        for sim in ("rhcr", "screen"):
            vis = [o.tile_visits for o in runs.get(sim, []) if o.completed and o.tile_visits is not None]
            if vis:
                mean = np.mean(np.stack(vis), axis=0)
                trav = build_scenario(array_to_rows(lay.layout, tiles), scenario).traversable
                panels.append(
                    (
                        f"{lay.label} ({'RHCR' if sim == 'rhcr' else 'screen'}, "
                        f"{len(vis)} run(s), N_a={r.n_agents})",
                        mean,
                        trav,
                    )
                )
                heat_rows += [
                    {
                        "layout": lay.label,
                        "kind": lay.kind,
                        "size": lay.size,
                        "n_agents": r.n_agents,
                        "simulator": sim,
                        "runs": len(vis),
                        "row": i,
                        "col": j,
                        "tile": tiles[lay.layout[i, j]],
                        "visits_mean": float(mean[i, j]),
                    }
                    for i in range(mean.shape[0])
                    for j in range(mean.shape[1])
                ]
                break
    if series:
        write_csv(
            out / f"tasks_over_time_{which}.csv",
            task_rows,
            [
                "layout",
                "kind",
                "size",
                "n_agents",
                "simulator",
                "runs",
                "t",
                "tasks_mean",
                "ci95_low",
                "ci95_high",
            ],
        )
        plot_tasks(
            out / f"tasks_over_time_{which}.png",
            series,
            smooth,
            f"{scenario}: tasks finished over time at {layouts[reqs[0].layout].size}",
        )
    if panels:
        write_csv(
            out / f"tile_usage_{which}.csv",
            heat_rows,
            ["layout", "kind", "size", "n_agents", "simulator", "runs", "row", "col", "tile", "visits_mean"],
        )
        plot_tile_usage(out / f"tile_usage_{which}.png", panels)


def _summary_rows(name: str, layouts, requests, results, plan: _Plan) -> list[dict[str, Any]]:
    """The main comparison: every layout at S (N_a) and S_eval (N_a_eval), per simulator,
    with generation and repair figures; a layout without a repaired map gets one row."""
    rows = []
    for which, n in (("train", plan.n_train), ("eval", plan.n_eval)):
        reqs = {r.layout: r for r in requests if r.purpose == f"main_{which}"}
        for key, lay in layouts.items():
            if lay.which != which:
                continue
            rep = lay.repair
            base = {
                "domain": name,
                "size": lay.size,
                "which": which,
                "n_agents": n,
                "layout": lay.label,
                "kind": lay.kind,
                "cell": lay.cell,
                "gen_seconds": lay.gen_seconds,
                "repair_status": rep.status if rep is not None else "given",
                "repair_seconds": rep.seconds if rep is not None else None,
                "similarity": rep.similarity if rep is not None else None,
                "hamming": rep.hamming if rep is not None else None,
            }
            runs = request_runs(results, reqs[key]) if key in reqs else {}
            if not runs:
                rows.append({**base, "simulator": "", **{c: None for c in STAT_COLUMNS}})
            for sim, outs in runs.items():
                rows.append({**base, "simulator": sim, **run_stats(outs)})
    return rows


def _summary_markdown(name: str, rows: Sequence[Mapping[str, Any]], T: int) -> str:
    """The summary as a Markdown table (throughput of successful runs, as in the paper)."""

    def pm(m, se):
        if not _finite(m):
            return "N/A"
        return f"{m:.2f} ± {se:.2f}" if _finite(se) else f"{m:.2f}"

    shown = []
    for r in rows:
        shown.append(
            {
                "size": f"{r['size']} ({'S' if r['which'] == 'train' else 'S_eval'})",
                "n": r["n_agents"],
                "layout": r["layout"],
                "sim": r["simulator"] or "-",
                "runs": "-"
                if r.get("runs") is None
                else f"{r['runs']}"
                + (f" ({r['timed_out']} timed out)" if r.get("timed_out") else "")
                + (f" ({r['errors']} failed)" if r.get("errors") else ""),
                "succ": ("-" if not _finite(r.get("success_rate")) else f"{100 * r['success_rate']:.0f} %"),
                "thr": pm(r.get("throughput_success_mean"), r.get("throughput_success_se")),
                "thr_all": pm(r.get("throughput_mean"), r.get("throughput_se")),
                "gen": "-" if not _finite(r.get("gen_seconds")) else f"{r['gen_seconds']:.3f}",
                "rep": "-" if not _finite(r.get("repair_seconds")) else f"{r['repair_seconds']:.1f}",
                "delta": "-" if not _finite(r.get("similarity")) else f"{r['similarity']:.3f}",
                "status": r["repair_status"],
            }
        )
    cols = [
        ("size", "size"),
        ("n", "N_a"),
        ("layout", "layout"),
        ("sim", "simulator"),
        ("runs", "runs"),
        ("succ", "success"),
        ("thr", "throughput (successful runs)"),
        ("thr_all", "throughput (all runs)"),
        ("gen", "NCA gen s"),
        ("rep", "repair s"),
        ("delta", "Δ"),
        ("status", "repair"),
    ]
    return (
        f"## {name}: main comparison (T={T}; mean ± standard error; screen = JAX "
        f"screening approximation, rhcr = exact)\n\n" + markdown_table(shown, cols)
    )
