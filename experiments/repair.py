"""Repair one layout file with HiGHS and print one JSON line.

    python -m experiments.repair domain=warehouse_even layout=in.json out=out.json [render=cmp.png]
    python -m experiments.repair layout=paper_33x36.json tile=[101,102] n_shelves=2500 out=tiled.json

Prints ``{"status", "hamming", "similarity", "seconds", "valid", ...}``; ``valid`` comes from the
independent validator (graph search). Exit status 0 with a repaired layout, 1 when the repair
found none (status ``infeasible`` / ``no_solution``), 2 for bad input (one line on stderr).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

from experiments.cli import check_writable, compose_config, main_guard, size_pair
from nca_qd.errors import NcaQdError
from nca_qd.io import MapFile, array_to_rows, load_map, save_map
from nca_qd.layouts import LAYOUTS, get_layout
from nca_qd.repair import make_rules, repair, tiles_of
from nca_qd.repair.validator import check
from nca_qd.scoring.jobs import REPAIR_OPTIONS

log = logging.getLogger("nca_qd.repair")


def domain_default(cfg, key: str, n_rows: int):
    """The domain's repair setting; a per-size one (``{train: .., eval: ..}``) is taken for the
    size whose row count the layout has (training size when neither matches)."""
    value = cfg.domain.repair.get(key)
    if hasattr(value, "keys"):
        which = "eval" if n_rows == int(cfg.domain.size.eval[0]) else "train"
        value = value.get(which)
    return value


def tiled(domain: str, layout, size, path: Path):
    """``layout`` tiled to the full-map ``size`` [rows, cols] as the evaluation's tiling baseline
    is (:func:`nca_qd.evaluation.layouts.tile_layout`), after checking both."""
    from nca_qd.evaluation.layouts import tile_layout
    from nca_qd.evaluation.records import region_shape

    size = size_pair(size, "tile")
    get_layout(domain).check_frame(layout, str(path))
    if min(region_shape(domain, size)) < 1:
        raise NcaQdError(f"tile={list(size)} leaves no storage region for {domain}")
    return tile_layout(domain, layout, list(size))


def main(argv: list[str]) -> int:
    cfg = compose_config("repair", argv)
    domain = cfg.domain.name
    if domain not in LAYOUTS:
        raise NcaQdError(f"domain {domain!r} has no repair (repairable: {', '.join(LAYOUTS)})")
    if not cfg.layout or not cfg.out:
        raise NcaQdError("give layout=<in.json> and out=<out.json>")
    check_writable(cfg.out, "out")
    if cfg.render:
        check_writable(cfg.render, "render")
    tiles = tiles_of(domain)
    path = Path(cfg.layout)
    mapfile = load_map(path, tiles)
    layout = mapfile.to_array(tiles)
    name, extra = mapfile.name, dict(mapfile.extra)
    if cfg.tile is not None:
        source = f"{mapfile.name} ({layout.shape[0]}x{layout.shape[1]})"
        layout = tiled(domain, layout, cfg.tile, path)
        # the tiling baseline is named as one: its title and file tell it from a grown layout
        name, extra["tiled_from"] = f"{mapfile.name}_tiled_{layout.shape[0]}x{layout.shape[1]}", source
    opts = {
        key: (cfg[key] if cfg[key] is not None else domain_default(cfg, key, layout.shape[0]))
        for key in REPAIR_OPTIONS  # the command line's value, else the domain's repair block
    }
    opts = {key: value for key, value in opts.items() if value is not None}
    try:
        get_layout(domain).check_frame(layout, str(path))
        rules = make_rules(domain, layout.shape, n_shelves=cfg.n_shelves, n_agents=cfg.n_agents)
    except NcaQdError as exc:
        msg = str(exc)
        raise NcaQdError(msg if msg.startswith(str(path)) else f"{path}: {msg}") from None
    res = repair(domain, layout, n_shelves=cfg.n_shelves, n_agents=cfg.n_agents, **opts)
    valid = res.layout is not None and check(res.layout, rules) is None
    line = {
        "status": res.status,
        "hamming": res.hamming,
        "similarity": round(res.similarity, 6),
        "seconds": round(res.seconds, 3),
        "valid": valid,
        "objective": res.objective,
        "method": res.method,
        # proven: the whole-map MILP's dual bound where it ran, else the tile-count bound
        "bound": res.details.get("bound"),
        "gap": None if res.details.get("gap") is None else round(res.details["gap"], 6),
    }
    if res.layout is not None:
        extra["repair"] = {k: line[k] for k in ("status", "hamming", "similarity", "seconds")}
        suffix = "_repaired"
        if opts.get("keep_aisles"):  # not the paper's repair: the file and its name say so
            extra["repair"]["keep_aisles"] = True
            suffix += "_aisles_kept"
        save_map(cfg.out, MapFile(name=name + suffix, rows=array_to_rows(res.layout, tiles), extra=extra))
        if cfg.render:
            from nca_qd.viz import render_layouts

            render_layouts(
                cfg.render,
                [layout, res.layout],
                tiles,
                dict(get_layout(domain).palette),
                ["unrepaired", f"repaired (Hamming {res.hamming})"],
            )
    print(json.dumps(line), flush=True)
    return 0 if res.layout is not None else 1


if __name__ == "__main__":
    main_guard(main)()
