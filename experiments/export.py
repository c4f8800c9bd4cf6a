"""Export a layout for other multi-agent path finding tools (MovingAI, League of Robot Runners).

    python -m experiments.export layout=map.json format=movingai out=exports/
    python -m experiments.export run=results/manufacturing_a5 rows=101 cols=102 format=lorr out=exports/
    python -m experiments.export human=true domain=warehouse_even rows=140 cols=500 format=json out=maps/

Writes the format's files into ``out`` (:mod:`nca_qd.export` describes them) and prints one JSON
line naming them (and, for a warehouse, its shelf count). From a run, the generator of ``cell``
grows a layout at ``rows`` x ``cols`` (the whole map) and, with ``repair=true``, the domain's
repair makes it valid. Bad input: one line on stderr and exit 2.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from experiments.cli import compose_config, main_guard, take_domain
from nca_qd.errors import NcaQdError, require_bool
from nca_qd.io import atomic_write_text, load_map


def _domain_of(tiles_used: set[str], given: str | None) -> str:
    from nca_qd.layouts import LAYOUTS

    if given:
        if given not in LAYOUTS:
            raise NcaQdError(f"domain {given!r} cannot be exported (known: {', '.join(LAYOUTS)})")
        return given
    fits = [n for n, kind in LAYOUTS.items() if tiles_used <= set(kind.tiles)]
    if not fits:
        raise NcaQdError(f"no domain has the tiles {''.join(sorted(tiles_used))!r}; give domain=<name>")
    return fits[0]


def _from_file(cfg) -> tuple[list[str], str, str]:
    path = Path(cfg.layout)
    mapfile = load_map(path)
    domain = _domain_of(set("".join(mapfile.rows)), cfg.domain)
    from nca_qd.layouts import get_layout

    load_map(path, get_layout(domain).tiles)  # names the file and a character that does not fit
    return list(mapfile.rows), domain, cfg.name or path.stem


def _from_run(cfg) -> tuple[list[str], str, str]:
    from nca_qd.api import load_generator

    g = load_generator(cfg.run, cfg.cell)
    if g.domain.name not in ("warehouse_even", "warehouse_uneven", "manufacturing"):
        raise NcaQdError(f"{cfg.run} is a {g.domain.name} run: only multi-agent layouts are exported")
    rows, cols = (
        (cfg.rows, cfg.cols) if cfg.rows is not None or cfg.cols is not None else g.full_shape("train")
    )
    layout = g.layout(rows, cols, repair=cfg.repair, n_shelves=cfg.n_shelves)
    name = cfg.name or f"{Path(str(cfg.run)).name}_c{g.cell}_{layout.shape[0]}x{layout.shape[1]}"
    return g.rows(layout), g.domain.name, name


def _human(cfg) -> tuple[list[str], str, str]:
    from nca_qd.layouts import get_layout
    from nca_qd.layouts.warehouse import human_layout

    domain = str(cfg.domain or "warehouse_even")
    if not domain.startswith("warehouse"):
        raise NcaQdError(f"human=true draws warehouses (domain=warehouse_even or _uneven), not {domain}")
    if cfg.rows is None or cfg.cols is None:
        raise NcaQdError("human=true needs rows=<R> cols=<C>")
    rows, cols = _size(cfg.rows, "rows"), _size(cfg.cols, "cols")
    kind = get_layout(domain)
    lay = human_layout((rows, cols))
    return ["".join(kind.tiles[t] for t in row) for row in lay], domain, cfg.name or f"human_{rows}x{cols}"


def _size(value, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise NcaQdError(f"{what} must be a positive integer, got {value!r}")
    return value


def _default_agents(domain: str, shape: tuple[int, int]) -> int:
    """The domain's agent count at the nearer (by area) of its training and evaluation sizes."""
    from experiments.cli import compose_config as compose

    d = compose("run", [f"domain={domain}"]).domain
    from nca_qd.layouts import get_layout

    kind = get_layout(domain)
    area = shape[0] * shape[1]
    sizes = {w: kind.full_shape(tuple(d.size[w])) for w in ("train", "eval")}
    which = min(sizes, key=lambda w: abs(sizes[w][0] * sizes[w][1] - area))
    return int(d.n_agents[which])


def main(argv: list[str]) -> int:
    from nca_qd.export import FORMATS, export_files
    from nca_qd.sim.scenario import build_scenario

    argv, domain_override = take_domain(argv)  # a plain string here, not run.yaml's config group
    cfg = compose_config("export", argv)
    if domain_override is not None:
        cfg.domain = domain_override
    for switch in ("human", "repair"):
        require_bool(switch, cfg[switch])
    if bool(cfg.layout) + bool(cfg.run) + cfg.human != 1:
        raise NcaQdError("give one of layout=<file.json>, run=<run dir> or human=true")
    if cfg.format not in FORMATS:
        raise NcaQdError(f"unknown format {cfg.format!r} (known: {', '.join(FORMATS)})")
    if not cfg.out:
        raise NcaQdError("give out=<folder>")
    out = Path(str(cfg.out))
    if out.exists() and not out.is_dir():
        raise NcaQdError(f"out={out}: is a file, not a folder")
    parent = out if out.is_dir() else out.parent
    if parent.exists() and not os.access(parent, os.W_OK):
        raise NcaQdError(f"out={out}: folder {parent} is not writable")
    rows, domain, name = _from_file(cfg) if cfg.layout else _from_run(cfg) if cfg.run else _human(cfg)
    agents = int(cfg.agents) if cfg.agents is not None else _default_agents(domain, (len(rows), len(rows[0])))
    scen = build_scenario(rows, domain, n_agents=agents, source=name)
    files = export_files(
        scen, str(cfg.format), name, agents, int(cfg.tasks), int(cfg.seed), float(cfg.reveal)
    )
    out.mkdir(parents=True, exist_ok=True)
    for fname, text in files.items():
        atomic_write_text(out / fname, text)
    print(
        json.dumps(
            {
                "format": cfg.format,
                "domain": domain,
                "size": f"{len(rows)}x{len(rows[0])}",
                **({"shelves": "".join(rows).count("@")} if domain.startswith("warehouse") else {}),
                "agents": agents,
                "files": [str(out / f) for f in files],
            }
        )
    )
    return 0


if __name__ == "__main__":
    main_guard(main)()
