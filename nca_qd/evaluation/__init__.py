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

The entry point is ``python -m experiments.evaluate`` (:func:`evaluate` here, which reads top to
bottom as the evaluation's steps); one module per step, each usable on its own:

* :mod:`.records`: the records passed between the steps (a layout under evaluation, a request
  of a table or curve, a simulation's outcome) and map sizes;
* :mod:`.plan`: the settings checked, and every size, agent count and run count (the plan);
* :mod:`.agents`: agent counts of the sweeps and of the other sizes, and their check;
* :mod:`.selection`: ``select.by=s_eval``, the generators chosen by a screening run at S_eval;
* :mod:`.layouts`: the run's archive, the layouts generated, tiled, loaded and repaired;
* :mod:`.runs`: the exact RHCR runs and the screened runs of every (layout, agent count);
* :mod:`.store`: every exact run recorded as it ends (``exact_runs.jsonl``, packed into
  ``exact_runs.jsonl.gz`` when the evaluation stops), every screened batch's runs likewise
  (``screen_runs.jsonl``), every repaired layout (``repairs.jsonl``: the
  repair is time-limited, so repairing again may give another layout), reused by the next
  evaluation into the same folder, so an interrupted one resumes;
* :mod:`.stats`: the statistics of a set of runs;
* :mod:`.tables`: the tables' rows (CSV, Markdown); :mod:`.plots`: the figures;
* :mod:`.outputs`: every file written, and those an earlier evaluation left behind removed.

Every name of the former single module ``nca_qd/evaluation.py`` is importable from here.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from nca_qd.errors import NcaQdError
from nca_qd.evaluation.agents import agent_range, check_agents, positive_ints, scaled_agents
from nca_qd.evaluation.layouts import (
    SUPPORTED,
    build_layouts,
    generate_timed,
    human_layout,
    load_run,
    pick_cells,
    repair_all,
    tile_layout,
)
from nca_qd.evaluation.outputs import OUTPUT_PATTERNS, remove_stale_outputs, write_outputs
from nca_qd.evaluation.plan import (
    Plan,
    ScreenSettings,
    SelectSettings,
    exact_settings,
    interpolate_iters,
    validated,
)
from nca_qd.evaluation.plots import plot_curves, plot_sizes, plot_tasks, plot_tile_usage
from nca_qd.evaluation.records import (
    SIMULATORS,
    EvalLayout,
    Request,
    Results,
    full_shape,
    parse_size,
    region_shape,
    size_map,
    size_str,
)
from nca_qd.evaluation.runs import merge_requests, screen_group, simulate_cells
from nca_qd.evaluation.selection import Selection, select_scalable, write_selection
from nca_qd.evaluation.stats import mean_se_ci, request_runs, run_stats
from nca_qd.evaluation.store import ExactRunStore, RepairStore, ScreenRunStore
from nca_qd.evaluation.tables import LAYOUT_COLUMNS, STAT_COLUMNS, layout_record, markdown_table, write_csv

log = logging.getLogger("nca_qd.evaluate")


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
    containers); writes every output under ``ecfg['out']`` (default <run_dir>/evaluation).

    Every repair goes through this module's ``repair_all`` (looked up when called and handed
    to the selection and to the layouts, with the folder's :class:`RepairStore` unless
    ``repair.reuse=false``), so replacing it here replaces them all."""
    from omegaconf import OmegaConf

    from nca_qd.domains import make_domain
    from nca_qd.io import atomic_write_text
    from nca_qd.pipeline import make_generator
    from nca_qd.scoring.backend import make_backend

    ecfg = validated(ecfg)
    run_dir = Path(ecfg["run_dir"])
    cfg, archive = load_run(run_dir, domain_override)
    dcfg = OmegaConf.to_container(cfg.domain, resolve=True)
    name = dcfg["name"]
    algo = OmegaConf.select(cfg, "algo.name")
    out = Path(ecfg["out"]) if ecfg.get("out") else run_dir / "evaluation"
    domain = make_domain(dcfg)
    # A direct search's layouts (DSAGE) exist at S only: no S_eval, as in the paper's table 1.
    scales = getattr(make_generator(domain, algo), "scalable", True)
    plan = Plan(ecfg, dcfg, name, scales=scales)
    by_s_eval = plan.select.by == "s_eval"
    if by_s_eval and not scales:
        raise NcaQdError(
            f"{run_dir} is a {str(algo).upper()} run: its layouts exist at the training size only, "
            "so select.by=s_eval does not apply (use select.by=s)"
        )
    if not scales:
        log.info(
            "%s is a %s run: its layouts are evaluated at S only (no S_eval, tiling or other sizes)",
            run_dir,
            str(algo).upper(),
        )
    cells_idx = pick_cells(archive["objective"], plan.select.pool if by_s_eval else plan.elites)
    tiles = domain.layout_tiles
    backend = make_backend(ecfg.get("eval"))  # an unreachable scheduler fails here, early
    selection: Selection | None = None
    also = ecfg["records_from"]  # other folders' records serve identical runs and repairs
    repair_store = RepairStore(out, also) if plan.repair_reuse else None

    def repair(backend: Any, domain_name: str, items: list) -> None:
        repair_all(backend, domain_name, items, store=repair_store)

    screen_store = ScreenRunStore(out, also) if plan.screen.reuse else None
    store = ExactRunStore(out, also) if plan.exact_reuse else None
    try:
        if by_s_eval:
            selection = select_scalable(
                plan,
                domain,
                archive,
                cells_idx,
                backend,
                repair=repair,
                store=screen_store,
                exact_store=store,
            )
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
        layouts = build_layouts(plan, domain, archive, cells_idx, backend, ready, repair=repair, algo=algo)
        requests = plan.requests(layouts)
        check_agents(layouts, requests, name, tiles)
        cells = merge_requests(requests)
        if plan.screen.where == "rest":
            for c in cells.values():
                if c.exact_runs > 0:
                    c.screen_runs = 0
        results = simulate_cells(
            cells,
            layouts,
            name,
            tiles,
            plan.T,
            plan.seed,
            backend,
            plan.exact,
            plan.screen,
            plan.progress,
            store,
            screen_store,
        )
    except BaseException:  # Ctrl-C, SIGTERM, a campaign's leg: the records packed to ship
        # (before the backend closes, which may wait for a running job)
        for st in (repair_store, store, screen_store):
            if st is not None:
                st.pack()
        raise
    finally:
        backend.close()
    out.mkdir(parents=True, exist_ok=True)
    t_write = time.time()
    # the configuration as run, the screen's threshold resolved (the run's domain's if not given)
    ecfg["screen"]["crowd_mean"] = plan.screen.crowd_mean
    atomic_write_text(out / "evaluate_config.yaml", OmegaConf.to_yaml(OmegaConf.create(ecfg)))
    summary, md = write_outputs(out, plan, domain, layouts, requests, results)
    if selection:
        write_selection(out, selection, tiles)
    remove_stale_outputs(out, t_write - 2.0)
    for st in (repair_store, store, screen_store):
        if st is None:
            continue
        if ecfg["prune_records"]:  # every run asked for is in: the record files keep what it used
            st.prune()
        else:
            st.pack()
    return Evaluation(name, out, layouts, requests, results, summary, md)


__all__ = [
    "LAYOUT_COLUMNS",
    "OUTPUT_PATTERNS",
    "SIMULATORS",
    "STAT_COLUMNS",
    "ScreenSettings",
    "SelectSettings",
    "SUPPORTED",
    "EvalLayout",
    "Evaluation",
    "ExactRunStore",
    "RepairStore",
    "ScreenRunStore",
    "Request",
    "Results",
    "Selection",
    "agent_range",
    "check_agents",
    "evaluate",
    "exact_settings",
    "full_shape",
    "generate_timed",
    "human_layout",
    "interpolate_iters",
    "layout_record",
    "load_run",
    "markdown_table",
    "mean_se_ci",
    "merge_requests",
    "parse_size",
    "pick_cells",
    "plot_curves",
    "plot_sizes",
    "plot_tasks",
    "plot_tile_usage",
    "positive_ints",
    "region_shape",
    "remove_stale_outputs",
    "repair_all",
    "request_runs",
    "run_stats",
    "scaled_agents",
    "screen_group",
    "select_scalable",
    "simulate_cells",
    "size_map",
    "size_str",
    "tile_layout",
    "write_csv",
]
