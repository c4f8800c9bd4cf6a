"""Evaluate a trained run: the paper's tables and figures at S, S_eval and more sizes.

    python -m experiments.evaluate run_dir=runs/warehouse_even/2024-01-01_12-00-00
    python -m experiments.evaluate run_dir=<run> elites=3 exact.train=10 exact.eval=2 \\
        exact.time_limit_s=3600 out=eval_even
    python -m experiments.evaluate run_dir=<run> elites=[1234,5678] sweep.eval.start=25
    python -m experiments.evaluate run_dir=<run> T=1000 runs.train=10 runs.eval=5 \\
        sweep.train.agents=[100,200,300] sweep.eval.agents=[] sizes.shapes=[] \\
        eval.scheduler=tcp://head:8786

The best generator(s) of the run's result archive generate at S (C=50) and S_eval (C_eval=200)
and at the ``sizes.shapes``; each layout is repaired once; the human-designed layouts and the
tiling baseline stand beside them (a DSAGE run's archive holds tile layouts of size S: those
are evaluated at S only, beside the human layout). Exact RHCR runs (``exact.*``, in parallel on the ``eval``
backend) and the JAX screening simulator (the rest, labelled ``screen``) give success rate and
throughput (mean ± standard error, 95 % intervals). Writes under ``out`` (default
``<run_dir>/evaluation/``):

- ``summary.csv`` / ``summary.md``: the main comparison (printed at the end);
- ``throughput_vs_agents_{train,eval}.{csv,png}``, ``tasks_over_time_{train,eval}.{csv,png}``,
  ``tile_usage_{train,eval}.{csv,png}``, ``scaling_sizes.{csv,png}`` (+ ``scaling_sizes_grid.csv``);
- ``runs.csv`` (every simulation), ``layouts.csv`` (generation and repair figures),
  ``layouts/*.json`` and ``layouts_<size>.png``, ``evaluate_config.yaml``.

Settings: experiments/conf/evaluate.yaml. Library: :mod:`nca_qd.evaluation`.
"""

from __future__ import annotations

from omegaconf import OmegaConf

from experiments.cli import compose_config, main_guard, take_domain
from nca_qd.errors import NcaQdError
from nca_qd.preload import preload

INTERRUPTED = (
    "finished exact runs, screened batches and repairs are kept (packed) in "
    "<out>/exact_runs.jsonl.gz, <out>/screen_runs.jsonl.gz and <out>/repairs.jsonl.gz; "
    "the same command goes on from them"
)


def main(argv: list[str]) -> int:
    from nca_qd.evaluation import evaluate

    argv, domain = take_domain(argv)
    cfg = compose_config("evaluate", argv)
    if OmegaConf.is_missing(cfg, "run_dir") or not cfg.run_dir:
        raise NcaQdError("give run_dir=<run directory>")
    preload()  # an evaluation takes hours: later edits to the tree cannot reach it
    result = evaluate(OmegaConf.to_container(cfg, resolve=True), domain_override=domain)
    print(result.summary_markdown, end="", flush=True)
    print(f"\nwritten to {result.out}", flush=True)
    return 0


if __name__ == "__main__":
    main_guard(main, INTERRUPTED)()
