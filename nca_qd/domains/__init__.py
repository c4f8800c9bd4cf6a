"""Domains: tiles, sizes, seeds, measures and scoring of each environment kind.

A new domain is a new module here plus one line in :data:`DOMAINS` and a YAML file in
``experiments/conf/domain/``.
"""

from __future__ import annotations

import importlib
from typing import Any, Mapping

from nca_qd.domains.base import Domain, EvalBatch, Evaluator
from nca_qd.errors import NcaQdError

# Domain config name -> "module:Class". Imported lazily so one domain's dependencies (HiGHS,
# the compiled simulator) are not loaded for another.
DOMAINS: dict[str, str] = {
    "maze": "nca_qd.domains.maze:MazeDomain",
    "warehouse_even": "nca_qd.domains.warehouse:WarehouseDomain",
    "warehouse_uneven": "nca_qd.domains.warehouse:WarehouseUnevenDomain",
    "manufacturing": "nca_qd.domains.manufacturing:ManufacturingDomain",
}


def domain_class(name: str) -> type[Domain]:
    """The class registered for ``name`` (its tiles and palette need no config)."""
    if name not in DOMAINS:
        raise NcaQdError(f"unknown domain {name!r} (known: {', '.join(sorted(DOMAINS))})")
    module_name, cls_name = DOMAINS[name].split(":")
    return getattr(importlib.import_module(module_name), cls_name)


def make_domain(cfg: Mapping[str, Any]) -> Domain:
    """Build the domain named by ``cfg['name']`` from its config."""
    return domain_class(cfg.get("name"))(cfg)


__all__ = ["DOMAINS", "Domain", "EvalBatch", "Evaluator", "domain_class", "make_domain"]
