"""``select.by=s_eval``: the generators to evaluate chosen by a screening run at S_eval.

:func:`select_scalable` generates and repairs the pool's S_eval layouts, screens them and
ranks the pool, then (``select.exact_top``) checks the best few by exact RHCR runs, since the
screen and RHCR disagree most on the layouts near congestion (results/warehouse_even_qd/
top20_seval: the screen let 30 % of an α = 0 archive's best runs flow where RHCR let 50 %);
the :class:`Selection` keeps those layouts, which the evaluation reuses, and
:func:`write_selection` writes selection.csv and the layouts under selection/.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from nca_qd.errors import NcaQdError
from nca_qd.evaluation.layouts import Repair, generate_timed, repair_all
from nca_qd.evaluation.plan import Plan
from nca_qd.evaluation.records import EvalLayout, Request, size_str
from nca_qd.evaluation.store import ExactRunStore, ScreenRunStore
from nca_qd.evaluation.tables import write_csv
from nca_qd.interrupts import deferred_interrupts
from nca_qd.scoring.jobs import RunOutcome

log = logging.getLogger("nca_qd.evaluate")


@dataclass
class Selection:
    """What ``select.by=s_eval`` chose and why: ``cells`` (best first), one ``rows`` entry per
    candidate (selection.csv), and every candidate's generated and repaired S_eval layout by
    cell, which the evaluation reuses rather than generating and repairing it again (a
    time-budgeted repair need not give the same layout twice)."""

    cells: np.ndarray
    rows: list[dict[str, Any]]
    layouts: dict[int, EvalLayout]


def select_scalable(
    plan: Plan,
    domain,
    archive,
    pool: np.ndarray,
    backend,
    *,
    repair: Repair = repair_all,
    store: ScreenRunStore | None = None,
    exact_store: ExactRunStore | None = None,
) -> Selection:
    """``elites`` cells picked among ``pool`` (the best at S) by a screening run at S_eval.

    Each pool generator generates at S_eval (C_eval iterations) and is repaired; its layout
    is screened with N_a_eval agents (``select.runs`` seeds, ``select.T`` steps) and the pool
    is ranked by mean screened throughput (a congested run counts the tasks it finished),
    then by the S objective. The generators that scale are not always the best at S (the
    paper's protocol, ``select.by=s``, evaluates those). The pool's layouts are repaired with
    ``repair`` (:func:`~nca_qd.evaluation.layouts.repair_all` unless given); a layout whose
    screened runs ``store`` holds (the evaluation's ``screen_runs.jsonl``) is not screened
    again, and the others' runs go into it: the same command again (after an interruption
    later in the evaluation, or for other outputs) screens nothing twice. With
    ``select.exact_top`` > 0 the best by the screen are checked by exact RHCR
    (:func:`_exact_check`; their runs recorded in, and reused from, ``exact_store``).
    """
    from nca_qd.pipeline import make_generator

    sel, name, tiles = plan.select, domain.name, domain.layout_tiles
    c_eval, size = plan.nca_iters(plan.s_eval), size_str(plan.s_eval)
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
        int(plan.elites),
        len(pool),
        size,
        plan.n_eval,
        sel.runs,
        sel.T,
    )
    repair(backend, name, [(it, plan.repair_options(plan.s_eval)) for it in items])
    rows, scored, scens, keys = _candidates(plan, items, objective, name, tiles)
    runs_of = _screen(plan, scens, keys, store)
    for row, runs in zip(scored, runs_of):
        row["screen_runs"] = len(runs)
        row["screen_success_rate"] = float(np.mean([r.success for r in runs]))
        row["screen_throughput_mean"] = float(np.mean([r.throughput for r in runs]))
    ranked = sorted(scored, key=lambda r: (-r["screen_throughput_mean"], -r["objective_s"]))
    if not ranked:
        raise NcaQdError(
            f"select.by=s_eval: none of the {len(pool)} generator(s) gave a "
            f"layout to screen at {size} (see the log)"
        )
    by_cell = {it.cell: it for it in items}
    ranked = _exact_check(plan, name, tiles, by_cell, ranked, backend, exact_store)
    for r in ranked[: int(plan.elites)]:
        r["selected"] = True
    _log_ranking(ranked, size)
    return Selection(
        np.asarray([r["cell"] for r in ranked[: int(plan.elites)]], dtype=int),
        rows,
        by_cell,
    )


def _candidates(
    plan: Plan, items: list[EvalLayout], objective: np.ndarray, scenario: str, tiles: str
) -> tuple[list[dict[str, Any]], list[dict[str, Any]], list, list[list[str]]]:
    """selection.csv's row per candidate (its repair's figures; the simulations' to come), and
    for those with a layout to screen: their rows, scenarios and screened runs' record keys."""
    from nca_qd.io import array_to_rows
    from nca_qd.sim.scenario import build_scenario

    rows, scored, scens, keys = [], [], [], []
    for it in items:
        row = {
            "cell": it.cell,
            "objective_s": float(objective[it.cell]),
            "repair_status": it.repair.status if it.repair else "",
            # table 3's figures for each candidate: how much of its S_eval layout the repair drew
            "similarity": it.repair.similarity if it.repair and it.layout is not None else math.nan,
            "hamming": it.repair.hamming if it.repair and it.repair.hamming is not None else "",
            "screen_runs": 0,
            "screen_success_rate": math.nan,
            "screen_throughput_mean": math.nan,
            "exact_runs": 0,
            "exact_success_rate": math.nan,
            "exact_throughput_mean": math.nan,
            "note": "",
            "selected": False,
        }
        rows.append(row)
        if it.layout is None:
            row["note"] = "repair found no layout"
            continue
        layout_rows = array_to_rows(it.layout, tiles)
        try:
            scens.append(build_scenario(layout_rows, scenario, n_agents=plan.n_eval, source=it.label))
            scored.append(row)
            seeds = range(plan.seed, plan.seed + plan.select.runs)
            keys.append([_key(plan, layout_rows, scenario, seed) for seed in seeds])
        except NcaQdError as err:
            row["note"] = str(err)
    return rows, scored, scens, keys


def _log_ranking(ranked: list[dict[str, Any]], size: str) -> None:
    for r in ranked:
        exact = (
            f"; exact: throughput {r['exact_throughput_mean']:.3f}, success {r['exact_success_rate']:.2f}"
            if r["exact_runs"]
            else ""
        )
        log.info(
            "cell %d: S objective %.3f, screened at %s: throughput %.3f, success %.2f%s%s",
            r["cell"],
            r["objective_s"],
            size,
            r["screen_throughput_mean"],
            r["screen_success_rate"],
            exact,
            " (selected)" if r["selected"] else "",
        )


def _exact_check(
    plan: Plan,
    scenario: str,
    tiles: str,
    items: dict[int, EvalLayout],
    ranked: list[dict[str, Any]],
    backend,
    store: ExactRunStore | None,
) -> list[dict[str, Any]]:
    """The ranking after the exact check: the ``select.exact_top`` best by the screen, each run
    ``select.exact_runs`` times under exact RHCR at S_eval (N_a_eval agents, ``select.T``
    steps, the evaluation's seeds and planner), first, by their exact success rate and then
    mean throughput (completed runs); the others after them in the screen's order. Their rows
    get the exact figures. With ``select.T`` equal to ``T`` the chosen generator's check runs
    are its first S_eval runs, which the evaluation takes from ``store``."""
    from nca_qd.evaluation.runs import simulate_cells

    top = ranked[: plan.select.exact_top]
    if not top:
        return ranked
    n = plan.n_eval
    cells = {
        (items[r["cell"]].key, n): Request("select", items[r["cell"]].key, n, 0, plan.select.exact_runs)
        for r in top
    }
    log.info(
        "checking the %d best by the screen by %d exact run(s) each (T=%d)",
        len(top),
        plan.select.exact_runs,
        plan.select.T,
    )
    layouts = {items[r["cell"]].key: items[r["cell"]] for r in top}
    results = simulate_cells(
        cells,
        layouts,
        scenario,
        tiles,
        plan.select.T,
        plan.seed,
        backend,
        plan.select_exact,
        plan.screen,
        progress=False,
        store=store,
    )
    for r in top:
        done = [o for o in results[(items[r["cell"]].key, n, "rhcr")] if o.completed]
        r["exact_runs"] = len(done)
        if done:
            r["exact_success_rate"] = float(np.mean([o.success for o in done]))
            r["exact_throughput_mean"] = float(np.mean([o.throughput for o in done]))

    def by_exact(r: dict[str, Any]) -> tuple[float, float]:  # no completed run: last
        ok = r["exact_runs"] > 0
        return (-r["exact_success_rate"] if ok else 1.0, -r["exact_throughput_mean"] if ok else 0.0)

    return sorted(top, key=by_exact) + ranked[len(top) :]


def _key(plan: Plan, rows: list[str], scenario: str, seed: int) -> str:
    """The screened run's record key, as the evaluation's own screened runs are keyed."""
    from nca_qd.scoring.keys import screen_run_key

    s = plan.screen
    return screen_run_key(rows, scenario, plan.n_eval, plan.select.T, seed, s.replan, s.crowd_mean)


def _screen(
    plan: Plan, scens: list, keys: list[list[str]], store: ScreenRunStore | None
) -> list[list[RunOutcome]]:
    """Each scenario's ``select.runs`` screened runs: from ``store`` where it holds them all,
    the rest simulated in one batch (and recorded)."""
    from nca_qd.sim.screen import simulate_scenarios

    known: dict[int, list[RunOutcome]] = {}
    if store is not None:
        for i, ks in enumerate(keys):
            outs = [store.get(k, False, False) for k in ks]
            if all(o is not None for o in outs):
                known[i] = [o for o in outs if o is not None]
        if known:
            used = [k for i in known for k in keys[i]]
            log.info("%d screened run(s) reused from %s", len(used), store.sources(used))
    todo = [i for i in range(len(scens)) if i not in known]
    if not todo:
        return [known[i] for i in range(len(scens))]
    # one batch (minutes at 101x102): an interruption waits until its runs are recorded
    with deferred_interrupts():
        res = simulate_scenarios(
            [scens[i] for i in todo],
            plan.n_eval,
            plan.select.T,
            range(plan.seed, plan.seed + plan.select.runs),
            replan=plan.screen.replan,
            threads=plan.screen.threads,
            crowd_mean=plan.screen.crowd_mean,
        )
        for i, runs in zip(todo, res):
            known[i] = [
                RunOutcome("screen", r.seed, float(r.throughput), bool(r.success), int(r.stop_time))
                for r in runs
            ]
            if store is not None:
                for k, o in zip(keys[i], known[i]):
                    store.add(k, o)
    return [known[i] for i in range(len(scens))]


def write_selection(out: Path, selection: Selection, tiles: str) -> None:
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
