"""Multi-agent layout families: one module per family holds all its facts, one registry here.

:data:`LAYOUTS` maps a layout (and multi-agent domain) name to its
:class:`~nca_qd.layouts.base.LayoutKind`: tiles, frame, seed, palette, task model, repair
constraints, measures. Repair, the simulators' scenarios, the path checker, the evaluation and
the commands read these facts through :func:`get_layout`. A new multi-agent domain is a new
module here (a ``LayoutKind``), one line in :data:`LAYOUTS` and a YAML file in
``experiments/conf/domain/``; see CONTRIBUTING.md.
"""

from __future__ import annotations

from nca_qd.errors import NcaQdError
from nca_qd.layouts import manufacturing, warehouse
from nca_qd.layouts.base import Construction, GoalKind, LayoutKind, TaskModel

LAYOUTS: dict[str, LayoutKind] = {
    "warehouse_even": warehouse.EVEN,
    "warehouse_uneven": warehouse.UNEVEN,
    "manufacturing": manufacturing.MANUFACTURING,
}


def layout_names() -> tuple[str, ...]:
    return tuple(LAYOUTS)


def get_layout(name: str, what: str = "layout") -> LayoutKind:
    """The facts of layout ``name``; an unknown name is a one-line :class:`NcaQdError`."""
    if name not in LAYOUTS:
        raise NcaQdError(f"unknown {what} {name!r} (known: {', '.join(LAYOUTS)})")
    return LAYOUTS[name]


__all__ = ["LAYOUTS", "Construction", "GoalKind", "LayoutKind", "TaskModel", "get_layout", "layout_names"]
