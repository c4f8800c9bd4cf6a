"""Statistics of a set of runs (the package docstring says what each figure averages):
mean, standard error and Student-t 95 % interval (:func:`mean_se_ci`), a table row's figures
(:func:`run_stats`), and the runs that answer one request (:func:`request_runs`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from nca_qd.evaluation.records import Request, Results
from nca_qd.scoring.jobs import RunOutcome


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


def run_stats(outs: Sequence[RunOutcome]) -> dict[str, Any]:
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


def request_runs(results: Results, r: Request) -> dict[str, list[RunOutcome]]:
    """The runs of request ``r`` per simulator: the first ones of its cell (seed order)."""
    out = {}
    for sim, want in (("rhcr", r.exact_runs), ("screen", r.screen_runs)):
        got = results.get((r.layout, r.n_agents, sim), [])[:want]
        if want > 0 and got:
            out[sim] = got
    return out
