"""Re-derive :data:`nca_qd.sim.free_flow.CONGESTED_MODEL`, the free-flow estimate's share of free
flow for a layout with a congested screened run (``eval.screen_congested``).

The fit: on the layouts of the calibration set drawn with seed 0
(:func:`nca_qd.calibration.layout_set.make_layouts`) that have at least one congested screened
run (PIBT screen, crowding rule, 5 seeds), least squares of RHCR's mean throughput over free flow
against ``[1, mean screened throughput / free flow, mean stop time / T]``. The check: the
Spearman correlation of RHCR's mean throughput with the estimate on the held-out seed-1 set,
refitted against shipped. RHCR on both sets costs about 1.5 CPU-hours each; its figures are
cached in JSON files between calls. ``python -m experiments.calibrate fit=congested``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from nca_qd.calibration.layout_set import (
    AGENTS,
    SCENARIO,
    make_layouts,
    rhcr_figures,
    screen_figures,
    spearman,
)
from nca_qd.sim.free_flow import CONGESTED_MODEL, free_flow_throughput, rhcr_estimate
from nca_qd.sim.scenario import build_scenario


def set_figures(maps: Path | None, seed: int, cache: Path | None) -> tuple[np.ndarray, ...]:
    """The set drawn with ``seed``: screened throughput, verdict and stop time / T per layout
    and run ``[n, 5]``, free flow ``[n]`` and RHCR's mean throughput ``[n]``."""
    layouts = make_layouts(maps, seed=seed)
    names = [n for n, _ in layouts]
    exact = rhcr_figures(layouts, cache)
    screen, _ = screen_figures(layouts, "crowding")
    flow = np.array([free_flow_throughput(build_scenario(r, SCENARIO), AGENTS) for _, r in layouts])
    per_run = np.array([screen[n] for n in names])  # [n, seeds, 4]
    y = np.array([np.mean([r[0] for r in exact[n]]) for n in names])
    return per_run[..., 0], per_run[..., 1] > 0.5, per_run[..., 3], flow, y


def fit(
    thr: np.ndarray, ok: np.ndarray, stop: np.ndarray, flow: np.ndarray, y: np.ndarray
) -> tuple[float, float, float]:
    """Least squares of ``y / flow`` on the layouts with a congested run (see the module)."""
    some = ~ok.all(1)
    if some.sum() < 3:
        raise ValueError(f"need at least 3 layouts with a congested screened run, got {int(some.sum())}")
    design = np.column_stack([np.ones(some.sum()), thr[some].mean(1) / flow[some], stop[some].mean(1)])
    coef, *_ = np.linalg.lstsq(design, y[some] / flow[some], rcond=None)
    return float(coef[0]), float(coef[1]), float(coef[2])


def refit(
    maps: Path | None, cache_fit: Path | None, cache_check: Path | None, efficiency: float
) -> dict[str, Any]:
    """Fit on the seed-0 set, check on the seed-1 set against the shipped coefficients."""
    thr, ok, stop, flow, y = set_figures(maps, 0, cache_fit)
    coef = fit(thr, ok, stop, flow, y)
    thr1, ok1, stop1, flow1, y1 = set_figures(maps, 1, cache_check)
    return {
        "fit_layouts": int((~ok.all(1)).sum()),
        "coefficients": [round(c, 3) for c in coef],
        "shipped": list(CONGESTED_MODEL),
        "held_out_spearman_refit": round(
            spearman(y1, rhcr_estimate(thr1, ok1, stop1, flow1, efficiency, coef)), 3
        ),
        "held_out_spearman_shipped": round(
            spearman(y1, rhcr_estimate(thr1, ok1, stop1, flow1, efficiency)), 3
        ),
    }
