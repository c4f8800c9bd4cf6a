"""Where a maze run's elites sit: the agent's path length against the maze's shortest path.

    python -m benchmarks.maze_paths results/maze_qd/cma_mae_maze_entropy_s0

A maze archive's second measure is the learned agent's mean episode length, so which of its
cells can be filled depends on the agent as much as on the generators: a cell at a long path
length needs a maze whose start and goal are far apart, or an agent that wanders (a miss counts
the whole horizon). This tool grows every elite of a run's result archive at the training size,
measures the exact shortest start-goal path (the longest shortest path the domain places start
and goal on), and prints, per band of the first measure, the agent's path lengths, the shortest
paths, their ratio, and how much of the band's archive is filled at short and long path
lengths. It writes the per-elite figures to ``maze_paths.csv`` in the run directory; a run whose
archive is not shipped (the maze runs' archives are 55-150 MB) keeps that CSV, and the tool then
reads it instead of the archive, so the tables can be re-printed from the repository.

Options: ``--bands 0,0.2,0.3,0.45,0.6,1`` (edges over the first measure; default: its range in
five equal parts), ``--recompute`` (grow the elites again even where the CSV exists). Bad input
(no such run, not a maze run, no archive and no CSV): one line on stderr, exit status 2.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

from benchmarks.cli import guarded
from nca_qd.errors import NcaQdError

CSV_NAME = "maze_paths.csv"
PATH_RANGES = ((0, 100), (100, 200), (200, 400), (400, None))  # agent path-length ranges (steps)


def shortest_paths(domain, nca, genotypes: np.ndarray, chunk: int = 500) -> np.ndarray:
    """Exact shortest start-goal path (steps) of each genotype's maze at the training size."""
    import jax.numpy as jnp

    from nca_qd.domains.maze import longest_shortest_path
    from nca_qd.pipeline import generate

    out = []
    for s in range(0, len(genotypes), chunk):
        regions = generate(domain, nca, genotypes[s : s + chunk])
        length, _, _ = longest_shortest_path(jnp.asarray(regions == 0))
        out.append(np.asarray(length, np.int64))
    return np.concatenate(out) if out else np.zeros(0, np.int64)


def elite_rows(run_dir: Path, cfg) -> list[dict]:
    """One row per elite of the run's result archive: cell, both measures, shortest path."""
    from nca_qd.domains import make_domain
    from nca_qd.pipeline import make_generator
    from nca_qd.run_dir import load_archive

    archive = load_archive(run_dir, "result")
    cells = np.flatnonzero(np.isfinite(np.asarray(archive["objective"])))
    measures = np.asarray(archive["measures"])[cells]
    genotypes = np.stack([np.asarray(archive["genotypes"][i], np.float32) for i in cells])
    domain = make_domain(cfg.domain)
    shortest = shortest_paths(domain, make_generator(domain), genotypes)
    objective = np.asarray(archive["objective"])[cells]
    return [
        {
            "cell": int(c),
            "m0": round(float(m[0]), 5),
            "path_length": round(float(m[1]), 2),
            "shortest": int(s),
            "objective": float(o),
        }
        for c, m, s, o in zip(cells, measures, shortest, objective)
    ]


def read_rows(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return [
            {k: (int(v) if k in ("cell", "shortest") else float(v)) for k, v in row.items()}
            for row in csv.DictReader(f)
        ]


def write_rows(path: Path, rows: list[dict]) -> None:
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["cell", "m0", "path_length", "shortest", "objective"])
        w.writeheader()
        w.writerows(rows)


def band_table(
    rows: list[dict], cells: list[int], ranges: list[list[float]], edges: list[float]
) -> list[str]:
    """Markdown lines: per band of the first measure, path statistics and the archive's fill."""
    m0 = np.array([r["m0"] for r in rows])
    path = np.array([r["path_length"] for r in rows])
    short = np.array([r["shortest"] for r in rows])
    cell = np.array([r["cell"] for r in rows], np.int64)
    n0, n1 = cells
    occupied = np.zeros(n0 * n1, bool)
    occupied[cell] = True
    occupied = occupied.reshape(n0, n1)
    step0 = (ranges[0][1] - ranges[0][0]) / n0
    step1 = (ranges[1][1] - ranges[1][0]) / n1
    heads = [f"filled, path {a}-{b if b is not None else int(ranges[1][1])}" for a, b in PATH_RANGES]
    lines = [
        "| band | elites | path p50 | path p90 | shortest p50 | shortest max | path / shortest p50 | "
        + " | ".join(heads)
        + " |",
        "|" + "---|" * (7 + len(heads)),
    ]
    for lo, hi in zip(edges[:-1], edges[1:]):
        rows0 = slice(int(round((lo - ranges[0][0]) / step0)), int(round((hi - ranges[0][0]) / step0)))
        fills = []
        for a, b in PATH_RANGES:
            cols = slice(int(round(a / step1)), None if b is None else int(round(b / step1)))
            block = occupied[rows0, cols]
            fills.append(f"{block.mean():.2f}" if block.size else "-")
        m = (m0 >= lo) & (m0 < hi) if hi < edges[-1] else (m0 >= lo) & (m0 <= hi)
        if not m.any():
            lines.append(f"| {lo:g}-{hi:g} | 0 | - | - | - | - | - | " + " | ".join(fills) + " |")
            continue
        ratio = path[m] / np.maximum(short[m], 1)
        lines.append(
            f"| {lo:g}-{hi:g} | {int(m.sum())} | {np.median(path[m]):.0f} | "
            f"{np.percentile(path[m], 90):.0f} | "
            f"{np.median(short[m]):.0f} | {int(short[m].max())} | {np.median(ratio):.2f} | "
            + " | ".join(fills)
            + " |"
        )
    return lines


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.maze_paths", description=__doc__.split("\n")[0])
    p.add_argument("run_dir")
    p.add_argument("--bands", default=None, help="edges over the first measure, comma-separated")
    p.add_argument("--recompute", action="store_true", help="grow the elites even where the CSV exists")
    args = p.parse_args(argv)
    return guarded(lambda: _bands(args))


def _bands(args: argparse.Namespace) -> None:
    from nca_qd.run_dir import load_run_config

    run_dir = Path(args.run_dir)
    if not run_dir.is_dir():
        raise NcaQdError(f"{run_dir}: no such run directory")
    cfg = load_run_config(run_dir)
    if cfg.domain.name != "maze":
        raise NcaQdError(f"{run_dir}: a {cfg.domain.name} run, not a maze run")
    meas = cfg.domain.measures
    ranges = [list(map(float, r)) for r in meas.ranges]
    if args.bands:
        try:
            edges = [float(x) for x in args.bands.split(",")]
        except ValueError:
            raise NcaQdError(f"--bands {args.bands!r}: expected numbers separated by commas") from None
        if len(edges) < 2 or any(b <= a for a, b in zip(edges, edges[1:])):
            raise NcaQdError(f"--bands {args.bands!r}: at least two increasing edges")
    else:
        edges = list(np.linspace(ranges[0][0], ranges[0][1], 6))
    csv_path = run_dir / CSV_NAME
    if csv_path.is_file() and not args.recompute:
        rows = read_rows(csv_path)
        source = str(csv_path)
    else:
        rows = elite_rows(run_dir, cfg)
        write_rows(csv_path, rows)
        source = f"the result archive (written to {csv_path})"
    print(f"{run_dir}: {len(rows)} elites, measures {list(meas.names)}, from {source}")
    print("\n".join(band_table(rows, list(meas.cells), ranges, edges)))


if __name__ == "__main__":
    sys.exit(main())
