"""Where each arm's result archive holds its elites along environment entropy: the paper's
appendix on the effect of α ("a larger α value is correlated with better archive coverage in the
low environment entropy area"), which it shows as archive heatmaps only.

Low entropy means regular patterns, the generators the paper expects to scale; so the count of
elites at low entropy is how much choice an arm leaves among them. For every run whose domain
has a measure named ``entropy`` (the warehouse domains), the final result archive (its
``archive_result.npz``, or the checkpoint or portable snapshot of a run in progress or shipped
without it) is read and its elites counted below fixed entropy values; over the seeds of an arm
each count is the mean ± s.e.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nca_qd.compare_evaluation import seed_mean_se
from nca_qd.errors import NcaQdError

MEASURE = "entropy"
BELOW = (0.5, 0.6, 0.7)  # entropy (0-1) bounds of the "low entropy area" counted


@dataclass
class Profile:
    """One run's result-archive elites along entropy."""

    domain: str
    algorithm: str
    seed: int
    entropy: np.ndarray  # one value per elite


def read_profiles(runs: Sequence[tuple[Path, str, str, int]]) -> list[Profile]:
    """The entropy of every elite of each run (``(run_dir, domain label, algorithm label,
    seed)``) whose domain measures entropy; runs without one are left out, as are runs whose
    archive is not kept (a shipped study with metrics only)."""
    from nca_qd.run_dir import load_archive, load_run_config

    out = []
    for path, domain, algorithm, seed in runs:
        names = list(load_run_config(path).domain.measures.names)
        if MEASURE not in names:
            continue
        try:
            archive = load_archive(path, "result")
        except NcaQdError:
            continue
        filled = np.isfinite(np.asarray(archive["objective"]))
        entropy = np.asarray(archive["measures"])[filled, names.index(MEASURE)]
        out.append(Profile(domain, algorithm, seed, entropy.astype(float)))
    return out


def _fmt(pair: tuple[float, float], share: float) -> str:
    return f"{_count(pair)} ({100 * share:.1f} %)"


def _count(pair: tuple[float, float]) -> str:
    """One seed's count as it is; a mean over seeds to a tenth (1.5 ± 0.5, not 2 ± 0)."""
    mean, se = pair
    return f"{mean:,.0f}" if np.isnan(se) else f"{mean:,.1f} ± {se:,.1f}"


def profiles_markdown(profiles: Sequence[Profile]) -> str:
    """The section: per domain and arm, the seeds, the elites, the lowest entropy held and the
    elites below each of :data:`BELOW` (share of the arm's elites in brackets). Empty when no
    run measures entropy."""
    if not profiles:
        return ""
    groups: dict[tuple[str, str], list[Profile]] = defaultdict(list)
    for p in profiles:
        groups[(p.domain, p.algorithm)].append(p)
    bounds = " | ".join(f"elites with entropy < {b}" for b in BELOW)
    lines = [
        "",
        "## Elites at low environment entropy (the paper's appendix on α)",
        "",
        "The paper: a larger α goes with better archive coverage at low environment entropy "
        "(regular patterns), shown as archive heatmaps only. Per arm, the final result "
        "archive's elites and how many lie below each entropy value (mean ± s.e. over the "
        "seeds; in brackets their share of the arm's elites).",
        "",
        f"| Domain | Algorithm | Seeds | elites | lowest entropy | {bounds} |",
        "|---|---|---|---|---|" + "---|" * len(BELOW),
    ]
    for (domain, algorithm), runs in sorted(groups.items()):
        runs = sorted(runs, key=lambda p: p.seed)
        n = [len(p.entropy) for p in runs]
        cells = []
        for b in BELOW:
            below = [int(np.sum(p.entropy < b)) for p in runs]
            cells.append(_fmt(seed_mean_se(below), sum(below) / max(sum(n), 1)))
        lowest = min((float(p.entropy.min()) for p in runs if len(p.entropy)), default=float("nan"))
        n_text = _count(seed_mean_se(n))
        lines.append(
            f"| {domain} | {algorithm} | {','.join(str(p.seed) for p in runs)} | {n_text} "
            f"| {lowest:.3f} | " + " | ".join(cells) + " |"
        )
    return "\n".join(lines) + "\n"
