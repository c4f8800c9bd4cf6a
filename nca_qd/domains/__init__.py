"""Domains: tiles, sizes, seeds, measures and scoring of each environment kind.

The maze is a module here (:mod:`.maze`). The multi-agent domains are one class
(:class:`.multiagent.MultiAgentDomain`) over the layout families registered in
:data:`nca_qd.layouts.LAYOUTS`, so a new multi-agent domain is one module in
``nca_qd/layouts/``, one line there and a YAML file in ``experiments/conf/domain/``; a domain of
another kind is a new module here plus one line in :data:`DOMAINS` (see CONTRIBUTING.md).
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from typing import Any

from nca_qd.domains.base import Domain, EvalBatch, Evaluator
from nca_qd.errors import NcaQdError
from nca_qd.layouts import layout_names

# Domain config name -> "module:Class". Imported lazily so one domain's dependencies (HiGHS,
# the compiled simulator) are not loaded for another.
MULTI_AGENT = "nca_qd.domains.multiagent:MultiAgentDomain"
DOMAINS: dict[str, str] = {
    "maze": "nca_qd.domains.maze:MazeDomain",
    **{name: MULTI_AGENT for name in layout_names()},
}


def domain_class(name: str) -> type[Domain]:
    """The class registered for ``name`` (its tiles and palette need no config)."""
    from nca_qd.layouts import LAYOUTS

    if name not in DOMAINS and name in LAYOUTS:  # a layout family registered after import
        return _multi_agent().for_layout(name)
    if name not in DOMAINS:
        raise NcaQdError(f"unknown domain {name!r} (known: {', '.join(sorted(DOMAINS))})")
    module_name, cls_name = DOMAINS[name].split(":")
    cls = getattr(importlib.import_module(module_name), cls_name)
    if DOMAINS[name] == MULTI_AGENT:
        return cls.for_layout(name)
    return cls


def _multi_agent():
    module_name, cls_name = MULTI_AGENT.split(":")
    return getattr(importlib.import_module(module_name), cls_name)


def make_domain(cfg: Mapping[str, Any]) -> Domain:
    """Build the domain named by ``cfg['name']`` from its config."""
    return domain_class(cfg.get("name"))(cfg)


__all__ = ["DOMAINS", "Domain", "EvalBatch", "Evaluator", "domain_class", "make_domain"]
