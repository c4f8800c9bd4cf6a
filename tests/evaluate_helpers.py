"""What the tests of experiments.evaluate share: a tiny warehouse run (random generators in a
9x10 storage area), the human-designed layout of its size, fast settings, and readers of the
evaluation's CSV and record files that read the files themselves."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

from experiments.cli import compose_config
from nca_qd.io import atomic_write_text, save_npz

# Storage 9x10 (9x14 with the workstation columns) at S, 13x14 (13x18) at S_eval.
TINY_RUN = [
    "domain=warehouse_even",
    "domain.size.train=[9,10]",
    "domain.size.eval=[13,14]",
    "domain.repair.n_shelves.train=12",
    "domain.repair.n_shelves.eval=24",
    "domain.n_agents.train=8",
    "domain.n_agents.eval=12",
]
# A valid 9x14 human-designed warehouse (7 shelves), found through $NCA_QD_MAPS.
HUMAN_9x14 = [
    "..............",
    "w...e@@e.....w",
    "..............",
    "..e@e..e@e....",
    "w............w",
    "....e@@e......",
    "..............",
    "w....e@e.....w",
    "..............",
]
FAST = [
    "T=40",
    "runs.train=3",
    "runs.eval=2",
    "exact.train=2",
    "exact.eval=1",
    "exact.time_limit_s=60",
    "sweep.train.agents=[4,8]",
    "sweep.train.runs=2",
    "sweep.eval.agents=[]",
    "sizes.shapes=[[11,15]]",
    "sizes.n_shelves={11x15: 14}",
    "sizes.agents={9x14: [8], 13x18: [12], 11x15: [8]}",
    "sizes.runs=2",
    "eval.workers=0",
    "progress=false",
    "tasks_smooth=5",
]

# Screened runs only, at the main sizes only (no curves, no more sizes, no human layouts):
# for the tests of what an evaluation keeps or picks, not of what it simulates
SCREEN_ONLY = [
    "T=20",
    "exact.train=0",
    "exact.eval=0",
    "sweep.train.agents=[]",
    "sweep.eval.agents=[]",
    "sizes.shapes=[]",
    "sizes.include_main=false",
    "baselines.human=false",
    "eval.workers=0",
    "progress=false",
]


def make_run(run_dir: Path, overrides=TINY_RUN, elites=(3, 7), empty=False) -> Path:
    """A run directory with config.yaml and a result archive of random generators."""
    from nca_qd.domains import make_domain
    from nca_qd.pipeline import make_generator

    cfg = compose_config("run", list(overrides))
    direct = cfg.algo.name == "dsage"  # the archive holds tile layouts, not NCA parameters
    domain = make_domain(cfg.domain) if cfg.domain.name != "maze" else None
    n_params = make_generator(domain, cfg.algo.name).n_params if domain is not None else 10
    cells = 12
    rng = np.random.default_rng(0)
    genotypes = np.zeros((cells, n_params), np.float32)
    objective = np.full(cells, -np.inf, np.float32)
    if not empty:
        for rank, c in enumerate(elites):
            genotypes[c] = (
                (rng.random(n_params) < 0.15).astype(np.float32)  # 0 = empty, 1 = shelf
                if direct
                else 0.3 * rng.standard_normal(n_params)
            )
            objective[c] = 5.0 - rank
    run_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_text(run_dir / "config.yaml", OmegaConf.to_yaml(cfg))
    save_npz(
        run_dir / "archive_result.npz",
        {
            "genotypes": genotypes,
            "objective": objective,
            "measures": np.zeros((cells, 2), np.float32),
            "centroids": np.zeros((cells, 2), np.float32),
        },
    )
    return run_dir


def write_human_maps(root: Path) -> Path:
    """A maps folder (for ``$NCA_QD_MAPS``) holding HUMAN_9x14 as ``warehouse/human_9x14.json``."""
    (root / "warehouse").mkdir(parents=True, exist_ok=True)
    (root / "warehouse" / "human_9x14.json").write_text(
        json.dumps({"name": "human_9x14", "layout": HUMAN_9x14, "n_row": 9, "n_col": 14})
    )
    return root


def read(path: Path) -> list[dict[str, str]]:
    import gzip

    with gzip.open(path, "rt") if path.suffix == ".gz" else path.open() as fh:
        return list(csv.DictReader(fh))


def record_lines(folder: Path, name: str) -> list[dict]:
    """The records of ``<folder>/<name>``, read from the files themselves: the packed
    ``.jsonl.gz`` (written when an evaluation stops), then the plain journal appended since."""
    import gzip

    lines: list[str] = []
    if (folder / f"{name}.jsonl.gz").is_file():
        lines += gzip.decompress((folder / f"{name}.jsonl.gz").read_bytes()).decode().splitlines()
    if (folder / f"{name}.jsonl").is_file():
        lines += (folder / f"{name}.jsonl").read_text().splitlines()
    return [json.loads(x) for x in lines if x.strip()]


def load_map_rows(rows):
    from nca_qd.io import rows_to_array
    from nca_qd.layouts import warehouse as wh

    return rows_to_array(rows, wh.TILES)
