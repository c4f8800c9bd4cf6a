"""Compare QD algorithms over seeds: the QD-score / coverage table and curves of the paper's
appendix.

    python -m experiments.compare runs=[runs/maze_cma_mae_s0,runs/maze_dsage_s0,...] out=cmp/
    python -m experiments.compare runs=results/compare_maze        # every run below a folder
    python -m experiments.compare runs=results/warehouse_even_qd out=results name=warehouse_even_comparison

Runs are grouped by domain (with its measures) and algorithm; each group's final QD-score and
coverage are reported as mean ± standard error over its runs (``comparison.md``, ``comparison.csv``)
and drawn over evaluations with 95 % intervals (``comparison.png``). Arms differ by algorithm
and α. Runs that hold an evaluation (``<run>/evaluation/summary.csv``, ``experiments.evaluate``)
add the paper's tables 2, 3 and 5 beside its rows (``comparison_evaluation.csv``); check folders
of the runs below the paths (``experiments.evaluate`` with ``select.by=s_eval`` or ``elites=N``)
add the archives' best generators at S_eval. See :mod:`nca_qd.compare`,
:mod:`nca_qd.compare_evaluation` and :mod:`nca_qd.compare_top`.
"""

from __future__ import annotations

from omegaconf import ListConfig

from experiments.cli import compose_config, main_guard
from nca_qd.compare import compare
from nca_qd.errors import NcaQdError


def main(argv: list[str]) -> int:
    cfg = compose_config("compare", argv)
    runs = cfg.runs
    if runs is None:
        raise NcaQdError("give runs=<run dir or folder> or runs=[dir,dir,...]")
    paths = list(runs) if isinstance(runs, (list, ListConfig)) else [runs]
    out = cfg.out or (paths[0] if len(paths) == 1 else "compare")
    table, files = compare(paths, out, str(cfg.name))
    print(table, end="")
    for f in files:
        print(f)
    return 0


if __name__ == "__main__":
    main_guard(main)()
