"""QD search over NCA generators.

    python -m experiments.run domain=maze [algo=map_elites] [qd.n_evals=3000] [seed=1]
    python -m experiments.run resume=runs/maze/2026-11-22_03-00-00 [qd.n_evals=200000]

The run directory is ``run_dir=`` (or Hydra's ``hydra.run.dir=``), by default
``runs/<domain>/<date_time>``. See :mod:`nca_qd.experiment` for what it contains.
"""

from __future__ import annotations

import datetime
from pathlib import Path

from experiments.cli import RESUME_HINT, compose_config, main_guard, merge_overrides
from nca_qd.errors import NcaQdError

RUN_DIR_KEYS = ("hydra.run.dir=", "run_dir=")
# sysexits' EX_TEMPFAIL: the leg (leg_seconds) ended before the search; run resume= again.
EXIT_LEG_ENDED = 75


def _split_run_dir(argv: list[str]) -> tuple[str | None, list[str]]:
    run_dir, rest = None, []
    for arg in argv:
        key = next((k for k in RUN_DIR_KEYS if arg.startswith(k)), None)
        if key:
            run_dir = arg[len(key) :]
        else:
            rest.append(arg)
    return run_dir, rest


def main(argv: list[str]) -> int:
    from nca_qd.experiment import Experiment, load_run_config

    run_dir, overrides = _split_run_dir(argv)
    resume = next((a.split("=", 1)[1] for a in overrides if a.startswith("resume=")), None)
    if resume:
        cfg = load_run_config(Path(resume))
        rest = [a for a in overrides if not a.startswith("resume=")]
        for a in rest:
            if a.startswith(("domain=", "algo=")):
                key, value = a.split("=", 1)
                saved = cfg[key]["name"]
                if value != saved:
                    raise NcaQdError(f"resume directory {resume} holds a {key} {saved!r} run, not {value!r}")
        extra = [a for a in rest if not a.startswith(("domain=", "algo="))]
        cfg = merge_overrides(cfg, extra)
        run_path = Path(resume)
    else:
        cfg = compose_config("run", overrides)
        stamp = datetime.datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
        run_path = Path(run_dir or cfg.run_dir or f"runs/{cfg.domain.name}/{stamp}")
        if any((run_path / f).exists() for f in ("checkpoint.npz", "checkpoint.msgpack", "snapshot.npz")):
            raise NcaQdError(f"{run_path} already holds a run; continue it with resume={run_path}")
    cfg.run_dir = str(run_path)
    exp = Experiment(cfg, run_path)
    exp.run(resume=bool(resume))
    print(f"run directory: {run_path}")
    if exp.leg_ended:  # leg_seconds ended it: the same resume command goes on
        print(f"leg ended before the search's end; go on with: python -m experiments.run resume={run_path}")
        return EXIT_LEG_ENDED
    return 0


if __name__ == "__main__":
    main_guard(main, RESUME_HINT)()
