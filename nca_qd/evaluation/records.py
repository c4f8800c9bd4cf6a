"""The evaluation's records and map sizes, which every other module of the package passes around.

:class:`EvalLayout` (one layout under evaluation), :class:`Request` (what one table or curve
asks of one layout) and ``Results`` (the runs by layout, agent count and simulator, each a
:class:`~nca_qd.scoring.jobs.RunOutcome`, the search's outcome type too); map sizes written "HxW"
(:func:`size_str`, :func:`parse_size`, :func:`size_map`) and the full map of a generated
region and back (:func:`full_shape`, :func:`region_shape`); how a value reads in a table or a
log line (:func:`format_value`, :func:`finite`). Plain data, kept apart so that the stages
depend on it rather than on each other.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from nca_qd.errors import NcaQdError
from nca_qd.layouts import get_layout
from nca_qd.scoring.jobs import RunOutcome

SIMULATORS = ("rhcr", "screen")


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
    repair: Any = None  # nca_qd.scoring.jobs.RepairOutcome, None for human layouts


@dataclass
class Request:
    """What one table or curve needs of one layout at one agent count."""

    purpose: str  # main_train | main_eval | sweep_train | sweep_eval | sizes | select (exact check)
    layout: str  # EvalLayout.key
    n_agents: int
    screen_runs: int
    exact_runs: int
    detail: bool = False  # keep tasks per step and tile visits


Results = dict[tuple[str, int, str], list[RunOutcome]]


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


def full_shape(domain_name: str, region: Sequence[int]) -> tuple[int, int]:
    """Full-map shape of a generated region (warehouse: plus the workstation columns)."""
    return get_layout(domain_name).full_shape((int(region[0]), int(region[1])))


def region_shape(domain_name: str, full: Sequence[int]) -> tuple[int, int]:
    """The NCA's region of a full map of shape ``full``."""
    return get_layout(domain_name).region_shape((int(full[0]), int(full[1])))


def format_value(v: Any, digits: int = 4) -> str:
    """A value as a table cell or a log figure: None and NaN empty, booleans lower case."""
    if v is None:
        return ""
    if isinstance(v, (bool, np.bool_)):
        return str(bool(v)).lower()
    if isinstance(v, (float, np.floating)):
        return "" if not math.isfinite(v) else f"{float(v):.{digits}f}"
    return str(v)


def finite(v: Any) -> bool:
    """Whether ``v`` is a finite number (None, NaN and text are not)."""
    return isinstance(v, (int, float, np.integer, np.floating)) and math.isfinite(float(v))
