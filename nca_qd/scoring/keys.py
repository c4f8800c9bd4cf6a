"""The one key scheme of everything a run or an evaluation remembers: digests of exactly the
inputs that decide an outcome, so equal keys mean equal outcomes and a change of any input (one
tile, a seed, a planner knob, a simulator's ``VERSION``) never reuses an old result.

- :func:`layout_key`: a layout (shape and tiles), 20 bytes; the search's memo
  (:class:`~nca_qd.scoring.memo.EvalMemo`) keys repairs by the generated layout and exact runs
  by the repaired one, under the fingerprint of the search's settings.
- :func:`exact_run_key`, :func:`screen_run_key`, :func:`repair_key`: one exact run, one screened
  run, one repair, 32 hex digits; the evaluation's records
  (:mod:`nca_qd.evaluation.store`) are keyed by them.

Recorded files hold these keys: each is pinned by a test against drift.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from nca_qd.scoring.jobs import ExactSettings


def layout_key(layout: np.ndarray) -> bytes:
    """The digest a layout is remembered by (shape and tiles; the integer type does not matter)."""
    arr = np.ascontiguousarray(layout, dtype=np.int16)
    h = hashlib.sha1(np.asarray(arr.shape, np.int64).tobytes())
    h.update(arr.tobytes())
    return h.digest()


def exact_run_key(
    rows: Sequence[str], scenario: str, n_agents: int, seed: int, settings: ExactSettings
) -> str:
    """Digest of one exact RHCR run's inputs (layout, scenario, agents, seed, every setting of
    :class:`~nca_qd.scoring.jobs.ExactSettings` but the wall-clock limit, and the simulator's
    version)."""
    from nca_qd.sim.rhcr import VERSION

    spec = {
        "rows": list(rows),
        "scenario": scenario,
        "n_agents": int(n_agents),
        "T": int(settings.T),
        "seed": int(seed),
        "window": int(settings.window),
        "replan": int(settings.replan),
        "planner": {k: settings.planner[k] for k in sorted(settings.planner)},
        "rhcr_version": int(VERSION),
    }
    return _digest(spec)


def screen_run_key(
    rows: Sequence[str],
    scenario: str,
    n_agents: int,
    T: int,
    seed: int,
    replan: int,
    crowd_mean: float | None = None,
) -> str:
    """Digest of a screened run's inputs (the screen's default planner, agent order and
    congestion rule with its crowding threshold, and its version): equal keys, equal runs."""
    from nca_qd.sim import screen

    spec = {
        "rows": list(rows),
        "scenario": scenario,
        "n_agents": int(n_agents),
        "T": int(T),
        "seed": int(seed),
        "replan": int(replan),
        "planner": screen.PLANNER,
        "priority": screen.PRIORITY,
        "congestion": screen.CONGESTION,
        "screen_version": int(screen.VERSION),
    }
    if crowd_mean is not None and float(crowd_mean) != screen.CROWD_MEAN:
        spec["crowd_mean"] = float(crowd_mean)  # (absent at the default: recorded keys stay valid)
    return _digest(spec)


# Repair options added after records were keyed, at their defaults (left out of the digest).
_LATER_DEFAULTS = (("connectivity", "flow"), ("keep_aisles", False))
# ... and after searches' memos were fingerprinted (connectivity was in them by then).
_MEMO_LATER_DEFAULTS = (("keep_aisles", False),)


def memo_repair_options(options: Mapping[str, Any]) -> dict[str, Any]:
    """The repair options a search memo's fingerprint names: those added later are left out at
    their defaults, so that a search resumed under a newer version keeps its memo."""
    return {k: v for k, v in options.items() if (k, v) not in _MEMO_LATER_DEFAULTS}


def repair_key(domain_name: str, layout: np.ndarray, options: Mapping[str, Any]) -> str:
    """Digest of a repair's inputs: the domain, the layout before repair (shape and tiles) and
    every option (N_s, agents, method, limits, seed)."""
    a = np.ascontiguousarray(np.asarray(layout, dtype=np.int32))
    spec = {
        "domain": domain_name,
        "shape": list(a.shape),
        "layout_sha256": hashlib.sha256(a.tobytes()).hexdigest(),
        # (options added later are absent at their defaults: recorded keys stay valid)
        "options": {k: options[k] for k in sorted(options) if (k, options[k]) not in _LATER_DEFAULTS},
    }
    return _digest(spec)


def _digest(spec: Mapping[str, Any]) -> str:
    """First 32 hex digits of the SHA-256 of ``spec`` as sorted-key JSON (values JSON cannot
    hold are written with ``str``); the recorded files' keys depend on this staying as it is."""
    return hashlib.sha256(json.dumps(spec, sort_keys=True, default=str).encode()).hexdigest()[:32]
