"""Re-derive a domain's crowding threshold (``domain.simulation.screen_crowd_mean``) and the
free-flow estimate's efficiency (``eval.screen_efficiency``) from a search's memo, and check
whether a threshold still holds on the layouts a search finds later.

The screen calls a run congested once the most crowded 5x5 block has held ``threshold`` agents
on average since the start (:mod:`nca_qd.sim.screen`). Every layout a search ran exactly is a
labelled example: RHCR's majority verdict over its 5 runs. The layouts are screened once under
RHCR's own rule (``moved``: no agent moved for a whole replanning period), recording the
crowding of every check, and the crowding rule is then replayed for any threshold on those
records (:func:`crowd_replay`), so a grid of thresholds costs one screening.

- :func:`calibrate_threshold`: the exactly-run layouts of iterations up to ``until`` in two
  random halves; the threshold whose majority verdicts agree best with RHCR's on one half, the
  scaled estimate's factor at that threshold (``eval.screen_scale``) and the free-flow
  estimate's efficiency (RHCR's mean share of free flow over that half's flowing runs), then
  each candidate threshold screened for real on the other half.
- :func:`threshold_drift`: the agreement of each threshold on the layouts of iterations
  ``lo``..``hi``: a threshold fitted on a search's first, mostly random layouts may misjudge
  the denser ones it finds later.

``python -m experiments.calibrate fit=crowd_threshold memo=<run>/eval_memo.npz until=28``.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from nca_qd.calibration.layout_set import spearman
from nca_qd.sim.free_flow import free_flow_throughput, rhcr_estimate
from nca_qd.sim.scenario import Scenario, build_scenario

REPLAN = 5  # the screen's check period h
GRID = np.arange(14.0, 30.01, 0.25)  # candidate thresholds
DRIFT_GRID = np.arange(16.0, 30.01, 2.0)
SCALE = 1.3  # the scaled screen's factor (eval.screen_scale), for its error beside the estimate's


def crowd_replay(crowd, tasks, stop0, ok0, threshold: float, replan: int = REPLAN):
    """The crowding rule replayed on runs made under RHCR's rule alone (``crowd`` [n, S, checks],
    ``tasks`` [n, S, T], their stop times and verdicts): (success, throughput) per run had the
    screen used ``threshold``."""
    from nca_qd.sim.screen import CROWD_MIN_CHECKS

    n_checks = np.arange(1, crowd.shape[-1] + 1)
    made = n_checks * replan <= stop0[..., None]  # the checks each run reached
    hit = made & (n_checks >= CROWD_MIN_CHECKS) & (np.cumsum(crowd, -1) >= threshold * n_checks)
    first = np.where(hit.any(-1), hit.argmax(-1), -1)
    stop = np.where(first >= 0, replan * (first + 1), stop0)
    done = np.cumsum(tasks, -1)
    thr = np.take_along_axis(done, (stop - 1)[..., None], -1)[..., 0] / tasks.shape[-1]
    return ok0 & (first < 0), thr


def replay_records(runs, T: int):
    """Screened runs made under RHCR's rule alone ([layout][seed]) of horizon ``T`` as the
    arrays :func:`crowd_replay` reads: crowding per check, tasks per step, stop times, verdicts."""
    n_seeds = len(runs[0]) if runs else 0
    crowd = np.zeros((len(runs), n_seeds, T // REPLAN))
    tasks = np.zeros((len(runs), n_seeds, T))
    for i, row in enumerate(runs):
        for s, r in enumerate(row):
            crowd[i, s, : len(r.crowding)] = r.crowding
            tasks[i, s] = r.tasks_per_step
    stop0 = np.array([[r.stop_time for r in row] for row in runs])
    ok0 = np.array([[r.success for r in row] for row in runs])
    return crowd, tasks, stop0, ok0


class MemoRuns(NamedTuple):
    """How a search ran its layouts exactly, read from its memo's fingerprint."""

    domain: str
    n_agents: int
    T: int
    seeds: list[int]


def memo_runs(memo) -> MemoRuns:
    spec = json.loads(str(memo["fingerprint"]))
    return MemoRuns(spec["domain"], int(spec["n_agents"]), int(spec["T"]), list(range(int(spec["n_runs"]))))


def memo_exact_layouts(memo, lo: int, hi: int) -> tuple[list[int], Callable[[list[int]], list[Scenario]]]:
    """A search memo's exactly-run layouts of iterations ``lo``..``hi``: their indices among
    the memo's exact entries, and a function giving any entries' scenarios."""
    from nca_qd.io import array_to_rows
    from nca_qd.layouts import get_layout
    from nca_qd.scoring.keys import layout_key

    scenario = memo_runs(memo).domain
    tiles = get_layout(scenario, "domain").tiles
    by_key = {layout_key(lay): i for i, lay in enumerate(memo["repair_layouts"])}
    entries = [
        j
        for j, k in enumerate(memo["exact_keys"])
        if bytes(k) in by_key and lo <= memo["exact_iteration"][j] <= hi
    ]

    def scenarios(entries_: list[int]) -> list[Scenario]:
        return [
            build_scenario(
                array_to_rows(memo["repair_layouts"][by_key[bytes(memo["exact_keys"][j])]], tiles), scenario
            )
            for j in entries_
        ]

    return entries, scenarios


def screen_in_chunks(scens: list[Scenario], runs: MemoRuns, congestion: str, threshold: float | None = None):
    """Screen scenarios 64 at a time as the search ran them (agents, T, as many seeds):
    [scenario][seed] runs."""
    from nca_qd.sim.screen import CROWD_MEAN, simulate_scenarios

    crowd_mean = CROWD_MEAN if threshold is None else threshold
    return [
        row
        for a in range(0, len(scens), 64)
        for row in simulate_scenarios(
            scens[a : a + 64], runs.n_agents, runs.T, runs.seeds, congestion=congestion, crowd_mean=crowd_mean
        )
    ]


def threshold_drift(memo_path: Path, lo: int, hi: int) -> Iterator[dict[str, Any]]:
    """Each threshold's majority verdicts against RHCR's on the memo's exactly-run layouts of
    iterations ``lo``..``hi`` (first line: what was looked at)."""
    memo = np.load(memo_path)
    runs = memo_runs(memo)
    entries, scenarios = memo_exact_layouts(memo, lo, hi)
    crowd, tasks, stop0, ok0 = replay_records(screen_in_chunks(scenarios(entries), runs, "moved"), runs.T)
    rhcr = memo["exact_success"][entries].astype(bool).mean(1) > 0.5
    yield {
        "memo": str(memo_path),
        "iterations": [lo, min(hi, int(memo["exact_iteration"].max()))],
        "layouts": len(entries),
        "rhcr_flows": int(rhcr.sum()),
    }
    for x in DRIFT_GRID:
        flows = crowd_replay(crowd, tasks, stop0, ok0, float(x))[0].mean(1) > 0.5
        yield {
            "threshold": float(x),
            "majority_agreement": round(float(np.mean(flows == rhcr)), 3),
            "rhcr_flows_screen_congests": int(np.sum(rhcr & ~flows)),
            "rhcr_congests_screen_flows": int(np.sum(~rhcr & flows)),
        }


def best_threshold(crowd, tasks, stop0, ok0, rhcr_ok: np.ndarray) -> tuple[float, float]:
    """The grid's threshold whose replayed majority verdicts agree best with RHCR's (the
    lowest of equals), and that agreement."""
    agree = [
        float(np.mean((crowd_replay(crowd, tasks, stop0, ok0, x)[0].mean(1) > 0.5) == rhcr_ok)) for x in GRID
    ]
    i = int(np.argmax(agree))
    return float(GRID[i]), agree[i]


def fit_scale(screened: np.ndarray, rhcr: np.ndarray) -> float:
    """The factor ``s`` of the scaled estimate (``eval.screen_scale``: RHCR's mean throughput
    ≈ ``s`` x the screen's), least squares through the origin over layouts."""
    screened, rhcr = np.asarray(screened, float), np.asarray(rhcr, float)
    return float(screened @ rhcr / (screened @ screened))


def calibrate_threshold(
    memo_path: Path, until: int, configured: float, seed: int = 2, limit: int | None = None
) -> Iterator[dict[str, Any]]:
    """Calibrate on half the memo's exactly-run layouts up to iteration ``until``, check the
    best, the ``configured`` and the screen's default threshold on the other half (JSON-ready
    lines; the first says what was looked at). ``limit``: at most this many layouts (a quick
    look; the figures then are not the calibration's)."""
    from nca_qd.sim.screen import CROWD_MEAN

    memo = np.load(memo_path)
    runs = memo_runs(memo)
    entries, scenarios = memo_exact_layouts(memo, int(memo["exact_iteration"].min()), until)
    order = np.random.default_rng(seed).permutation(entries)[:limit]
    cal, chk = np.sort(order[: len(order) // 2]), np.sort(order[len(order) // 2 :])
    yield {
        "memo": str(memo_path),
        "domain": runs.domain,
        "until": until,
        "calibrate_on": len(cal),
        "check_on": len(chk),
    }
    crowd, tasks, stop0, ok0 = replay_records(screen_in_chunks(scenarios(list(cal)), runs, "moved"), runs.T)
    best, agreement = best_threshold(
        crowd, tasks, stop0, ok0, memo["exact_success"][cal].astype(bool).mean(1) > 0.5
    )
    replayed = crowd_replay(crowd, tasks, stop0, ok0, best)[1].mean(1)
    yield {
        "calibration_best_threshold": best,
        "calibration_agreement": round(agreement, 3),
        "screen_scale": round(fit_scale(replayed, memo["exact_throughput"][cal].mean(1)), 3),
    }

    def free_flows(entries_) -> np.ndarray:
        return np.array([free_flow_throughput(scen, runs.n_agents) for scen in scenarios(list(entries_))])

    flowed = memo["exact_success"][cal].astype(bool)
    shares = (memo["exact_throughput"][cal] / free_flows(cal)[:, None])[flowed]
    efficiency = float(shares.mean())
    yield {"free_flow_efficiency": round(efficiency, 4), "fitted_on_runs": int(flowed.sum())}
    rhcr_ok = memo["exact_success"][chk].astype(bool).mean(1) > 0.5
    rhcr_thr = memo["exact_throughput"][chk].mean(1)
    flow_chk = free_flows(chk)
    for x in sorted({best, float(configured), CROWD_MEAN}):
        t0 = time.perf_counter()
        res = screen_in_chunks(scenarios(list(chk)), runs, "crowding", x)
        ok = np.array([[r.success for r in row] for row in res])
        run_thr = np.array([[r.throughput for r in row] for row in res])
        stop = np.array([[r.stop_time / runs.T for r in row] for row in res])
        err = SCALE * run_thr.mean(1) - rhcr_thr
        est = rhcr_estimate(run_thr, ok, stop, flow_chk, efficiency)
        yield {
            "threshold": x,
            "layouts": len(chk),
            "screen_run_success": round(float(ok.mean()), 3),
            "rhcr_run_success": round(float(memo["exact_success"][chk].mean()), 3),
            "majority_agreement": round(float(np.mean((ok.mean(1) > 0.5) == rhcr_ok)), 3),
            "spearman": round(spearman(rhcr_thr, run_thr.mean(1)), 3),
            "scaled_mae": round(float(np.abs(err).mean()), 3),
            "scaled_bias": round(float(err.mean()), 3),
            "free_flow_spearman": round(spearman(rhcr_thr, est), 3),
            "free_flow_mae": round(float(np.abs(est - rhcr_thr).mean()), 3),
            "free_flow_bias": round(float((est - rhcr_thr).mean()), 3),
            "wall_s": round(time.perf_counter() - t0),
        }
