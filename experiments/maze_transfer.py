"""The paper's maze transfer experiment: success rates of the maze agent on NCA mazes at 18x18 and
66x66 and on random 66x66 baseline mazes.

    python -m experiments.maze_transfer [run_dir=<maze QD run>] [agent=learned] [episodes=100]
    python -m experiments.maze_transfer baseline.n_mazes=20 baseline.episodes=5 out=/tmp/transfer

Prints one JSON line per case (``case``, ``episodes``, ``success_rate``, ``stderr`` and details):
``paper_nca_18x18``, ``paper_nca_66x66``, ``own_nca_18x18`` and ``own_nca_66x66`` (only with
``run_dir``), ``baseline_66x66``. Writes a PNG per maze with episode 0's path and
``results.jsonl`` to ``out``. Settings: experiments/conf/maze_transfer.yaml; library:
:mod:`nca_qd.agent.transfer`.
"""

from __future__ import annotations

import datetime
import json
from pathlib import Path

from omegaconf import OmegaConf

from experiments.cli import compose_config, main_guard
from nca_qd.errors import NcaQdError, require_bool


def main(argv: list[str]) -> int:
    from nca_qd.agent.transfer import run_transfer
    from nca_qd.io import atomic_write_text

    cfg = compose_config("maze_transfer", argv)
    for key in ("episodes", "horizon_factor"):
        v = cfg[key]
        if not isinstance(v, int) or isinstance(v, bool) or v <= 0:
            raise NcaQdError(f"{key} must be a positive integer, got {v!r}")
    for key in ("pictures", "progress"):
        require_bool(key, cfg[key])
    stamp = datetime.datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    out = Path(cfg.out or f"runs/maze_transfer/{stamp}")
    out.mkdir(parents=True, exist_ok=True)
    lines: list[str] = []

    def emit(res):
        line = json.dumps(res)
        lines.append(line)
        print(line, flush=True)

    run_transfer(OmegaConf.to_container(cfg, resolve=True), out, emit)
    atomic_write_text(out / "results.jsonl", "\n".join(lines) + "\n")
    atomic_write_text(out / "config.yaml", OmegaConf.to_yaml(cfg))
    return 0


if __name__ == "__main__":
    main_guard(main)()
