"""Train the learned maze agent (PPO + LSTM over vmapped environments, ACCEL levels).

    python -m experiments.train_agent [run_dir=/tmp/agent] [total_env_steps=20000000] [seed=1]
    python -m experiments.train_agent resume=/tmp/agent [total_env_steps=...] [ship=true]
    python -m experiments.train_agent resume=/tmp/agent ship_only=true

``ship=true`` writes the best held-out checkpoint to ``nca_qd/agent/weights/`` (the ``learned``
maze agent kind) when training ends; ``resume=<dir> ship=true`` with no steps left only ships.
Settings: experiments/conf/train_agent.yaml; library: :mod:`nca_qd.agent`.
"""

from __future__ import annotations

import datetime
from pathlib import Path

from omegaconf import OmegaConf

from experiments.cli import RESUME_HINT, compose_config, main_guard, merge_overrides
from nca_qd.errors import NcaQdError, require_bool
from nca_qd.preload import preload


def main(argv: list[str]) -> int:
    from nca_qd.agent.train import CHECKPOINT_FILE, AgentRun

    resume = next((a.split("=", 1)[1] for a in argv if a.startswith("resume=")), None)
    if resume:
        path = Path(resume) / "config.yaml"
        if not path.is_file():
            raise NcaQdError(f"{resume} is not an agent run directory (config.yaml missing)")
        cfg = OmegaConf.load(path)
        rest = [a for a in argv if not a.startswith("resume=")]
        cfg = merge_overrides(cfg, rest)
        run_path = Path(resume)
    else:
        cfg = compose_config("train_agent", argv)
        stamp = datetime.datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
        run_path = Path(cfg.run_dir or f"runs/agent/{stamp}")
        if (run_path / CHECKPOINT_FILE).exists():
            raise NcaQdError(f"{run_path} already holds a run; continue it with resume={run_path}")
    cfg.run_dir, cfg.resume = str(run_path), None
    ship_only = require_bool("ship_only", cfg.get("ship_only", False))
    require_bool("ship", cfg.ship)
    require_bool("progress", cfg.progress)
    if ship_only and not resume:
        raise NcaQdError("ship_only=true needs resume=<run dir>")
    cfg.ship_only = False
    if not ship_only:
        preload()  # a training takes hours: later edits to the tree cannot reach it
    run = AgentRun(cfg, run_path)
    tree = run.load()[0] if ship_only else run.run(resume=bool(resume))
    print(
        f"run directory: {run_path}  best held-out success {float(tree['best_success']):.3f} "
        f"at update {int(tree['best_update'])}"
    )
    if cfg.ship or ship_only:
        out = run.ship(tree, cfg.ship_dir)
        print(f"shipped to {out}")
    return 0


if __name__ == "__main__":
    main_guard(main, RESUME_HINT)()
