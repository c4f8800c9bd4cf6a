"""Where the agents stand: occupancy maps of exact runs, to tell why one layout moves more tasks.

    python -m benchmarks.traffic_map results/warehouse_even_qd/league_140x500/tiling_c4472_140x500.json \
        results/warehouse_even_qd/league_140x500/nca_c4472_140x500_aisles.json \
        --agents 30000 --planner pibt_swap --out results/warehouse_even_qd/league_140x500/traffic

A throughput says how many tasks a layout moves, not where its agents lose time. This runs each
layout once (``--seed``) with the sweep's settings (``experiments/conf/sweep.yaml``, the planner
and horizon given here) and keeps the core's ``tile_visits`` (agent-timesteps on each tile) in
``<out>/<stem>_<agents>_s<seed>.npz`` (reused when present: the same inputs give the same run),
then draws ``<out>/traffic_<agents>.png``: each layout's mean occupancy (visits / T, log scale)
and the occupancy by column. It prints, per layout, the throughput and where the agent-time
goes: in the workstation columns and the ``--edge`` storage columns beside them, in the rest of
the storage rows without a shelf (the corridors), in the rest of the storage area, on the
most occupied 1 % of tiles, and on tiles occupied over nine tenths of the horizon (where agents
stand: a standing queue or a jam); and the jam's extent (``jam_rows``, ``jam_cols``: first,
last, how many storage rows / columns have a quarter of their open tiles packed).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from benchmarks.cli import guarded
from experiments.cli import compose_config
from experiments.simulate import RunSettings, exact_run
from nca_qd.io import load_map
from nca_qd.layouts import warehouse as wh
from nca_qd.sim.rhcr import planner_title
from nca_qd.sim.scenario import build_scenario, tiles_for


def run_once(path: Path, domain: str, agents: int, planner: str, T: int, seed: int, out: Path) -> dict:
    """The layout's run (from ``out`` when recorded there): throughput and tile visits."""
    rec = out / f"{path.stem}_{agents}_s{seed}.npz"
    rows = load_map(path, tiles=tiles_for(domain)).rows
    if rec.exists():
        with np.load(rec) as z:
            inputs = ([str(r) for r in z["rows"]], str(z["planner"]), int(z["T"]))
            if inputs == (list(rows), planner, T):
                return {"throughput": float(z["throughput"]), "visits": z["visits"], "rows": rows}
    overrides = ["layouts=[x]", f"agents=[{agents}]", "out=x", f"planner={planner}", f"T={T}"]
    cfg = compose_config("sweep", overrides)
    cfg.domain = domain
    settings = RunSettings(_with_agents(cfg, agents))
    res = exact_run(build_scenario(rows, domain, n_agents=agents, source=path.stem), settings, seed)
    visits = np.asarray(res.tile_visits, dtype=np.uint32)
    out.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        rec, rows=np.array(rows), planner=planner, T=T, throughput=res.throughput, visits=visits
    )
    return {"throughput": float(res.throughput), "visits": visits, "rows": rows}


def _with_agents(cfg, agents: int):
    from omegaconf import OmegaConf

    return OmegaConf.merge(cfg, {"agents": agents})


# A tile occupied over this share of the horizon holds a standing queue or a jam.
PACKED = 0.9
# A row or column with at least this share of its open tiles packed is inside the jam.
JAM_LINE = 0.25


def _tiles(rows: list[str]) -> np.ndarray:
    """Map rows -> ``[h, w]`` indices into the warehouse alphabet (``wh.TILES``)."""
    return np.array([[wh.TILES.index(c) for c in r] for r in rows], dtype=np.int32)


def shares(rows: list[str], visits: np.ndarray, T: int, edge: int) -> dict:
    """Where the agent-time goes (shares of all agent-timesteps; the first three sum to 1): the
    workstation columns and ``edge`` storage columns beside them, the corridor rows' cells
    beyond them, the rest of the storage area; then the most occupied 1 % of tiles and the
    tiles occupied over :data:`PACKED` of the horizon (a standing queue or a jam: a tile an
    agent leaves is soon taken again)."""
    lay = _tiles(rows)
    v = visits.astype(np.float64)
    total = v.sum()
    w, frame = lay.shape[1], wh.FRAME
    near = np.zeros(lay.shape, bool)
    near[:, : frame + edge] = True
    near[:, w - frame - edge :] = True
    corridor = wh.aisle_rows(lay)  # the rows the repair's keep_aisles holds
    storage = np.zeros(lay.shape, bool)
    storage[:, frame : w - frame] = True
    top = np.sort(v.ravel())[::-1][: max(1, v.size // 100)].sum()
    return {
        "near_workstations": v[near].sum() / total,
        "corridor_rows": v[corridor & ~near].sum() / total,
        "other_storage": v[storage & ~corridor & ~near].sum() / total,
        "top_1pct_tiles": top / total,
        "on_packed_tiles": v[v > PACKED * T].sum() / total,
    }


def jam_extent(rows: list[str], visits: np.ndarray, T: int) -> dict:
    """Where the jam stands: the first and last storage row and column in which at least
    :data:`JAM_LINE` of the open (non-shelf) tiles are packed (occupied over :data:`PACKED` of
    the horizon), and how many rows and columns are; ``None`` where none is. Two layouts can
    hold the same agent-time on packed tiles in jams of different shape (a band across the
    rows or a block bounded by them)."""
    open_ = wh.storage(_tiles(rows)) != wh.SHELF
    packed = (wh.storage(visits) > PACKED * T) & open_
    out: dict = {}
    for axis, name, offset in ((1, "rows", 0), (0, "cols", wh.FRAME)):
        share = packed.sum(axis=axis) / np.maximum(open_.sum(axis=axis), 1)
        idx = np.flatnonzero(share >= JAM_LINE)
        extent = [int(idx[0]) + offset, int(idx[-1]) + offset, int(idx.size)] if idx.size else None
        out[f"jam_{name}"] = extent
    return out


def draw(path: Path, runs: dict[str, dict], agents: int, planner: str, T: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    n = len(runs)
    h, w = next(iter(runs.values()))["visits"].shape
    map_h = min(4.0, 14 * h / w)
    fig, axes = plt.subplots(
        n + 1,
        1,
        figsize=(14, n * map_h + 2.5),
        squeeze=False,
        height_ratios=[map_h] * n + [2.5],
        layout="constrained",
    )
    vmax = max(float(r["visits"].max()) for r in runs.values()) / T
    for ax, (stem, r) in zip(axes[:n, 0], runs.items()):
        occ = r["visits"] / T
        im = ax.imshow(
            np.where(occ > 0, occ, np.nan),
            norm=LogNorm(1e-3, max(vmax, 1e-2)),
            aspect="auto",
            cmap="magma",
            interpolation="nearest",
        )
        ax.set_title(f"{stem}: {r['throughput']:.2f} tasks/step", fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(im, ax=axes[:n, 0].tolist(), label="mean agents on the tile")
    ax = axes[n, 0]
    for stem, r in runs.items():
        ax.plot(r["visits"].sum(axis=0) / T, label=stem, lw=0.8)
    ax.set_xlabel("column")
    ax.set_ylabel("agents in the column")
    ax.legend(fontsize=8)
    fig.suptitle(f"occupancy over T = {T:,} at {agents:,} agents ({planner_title(planner)})", fontsize=10)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("layouts", nargs="+", type=Path, help="layout JSON files (their stems label them)")
    p.add_argument("--domain", default="warehouse_even")
    p.add_argument("--agents", type=int, required=True)
    p.add_argument("--planner", default="pibt_swap", help="rhcr | pibt | pibt_swap")
    p.add_argument("--T", type=int, default=5000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--edge", type=int, default=5, help="storage columns counted as near the workstations")
    p.add_argument("--out", type=Path, required=True, help="folder for the runs' visits and the picture")
    args = p.parse_args(argv)
    return guarded(lambda: _map_all(args))


def _map_all(args: argparse.Namespace) -> None:
    runs = {}
    for path in args.layouts:
        r = run_once(path, args.domain, args.agents, args.planner, args.T, args.seed, args.out)
        runs[path.stem] = r
        row = {"layout": path.stem, "agents": args.agents, "throughput": round(r["throughput"], 3)}
        row.update({k: round(v, 4) for k, v in shares(r["rows"], r["visits"], args.T, args.edge).items()})
        row.update(jam_extent(r["rows"], r["visits"], args.T))
        print(json.dumps(row), flush=True)
    draw(args.out / f"traffic_{args.agents}.png", runs, args.agents, args.planner, args.T)


if __name__ == "__main__":
    raise SystemExit(main())
