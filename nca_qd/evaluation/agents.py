"""Agent counts: the sweeps' ranges, the counts scaled to other map sizes, and the check,
before anything runs, that every layout takes the most agents asked of it.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from nca_qd.errors import NcaQdError
from nca_qd.evaluation.records import EvalLayout, Request


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
