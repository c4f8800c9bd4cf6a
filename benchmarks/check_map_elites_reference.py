"""MAP-Elites here against pyribs' on the linear-projection sphere: the paper's settings, side by side.

    .venv/bin/python -m benchmarks.check_map_elites_reference [--iterations 400] [--seeds 12]

The paper's code runs MAP-Elites on pyribs 0.5.0: five ``IsoLineEmitter`` (batch 10, ``x0 = 0``,
σ_iso = 0.01, σ_line = 0.2, no initial solutions) on a ``GridArchive`` which in the warehouse and
manufacturing domains is CMA-MAE's threshold archive (learning rate 0.01, threshold_min 0), with
an elitist result archive beside it; for the maze an elitist archive. This runs both archives with
pyribs (the installed version; the threshold archive's rule is the same since 0.5.0) and with
:class:`nca_qd.qd.emitters.IsoLineEmitter` on :class:`nca_qd.qd.loop.QDLoop` (``n_initial = 0``,
``initial_sigma = 0.01``), seeds 0..n-1 each, and prints the result archives' QD-score and
coverage (mean ± s.e. over seeds). The random streams differ, so the two agree in distribution
only: the difference of the means against its standard error is the check.
"""

from __future__ import annotations

import argparse
import math

import jax
import numpy as np

from nca_qd.evaluation.stats import mean_se_ci
from nca_qd.qd.benchmarks import sphere_batch_objective, sphere_objective, sphere_spec
from nca_qd.qd.emitters import IsoLineEmitter
from nca_qd.qd.loop import QDLoop

DIM, EMITTERS, BATCH = 100, 5, 10
ISO, LINE = 0.01, 0.2
SETTINGS = {"elitist": (1.0, -np.inf), "threshold": (0.01, 0.0)}


def ours(archive: str, seed: int, iterations: int) -> tuple[float, float]:
    """QD-score and coverage of the result archive after ``iterations`` batches, this repository."""
    lr, tmin = SETTINGS[archive]
    loop = QDLoop(
        IsoLineEmitter(EMITTERS * BATCH, DIM, ISO, ISO, LINE, 0),
        sphere_batch_objective(),
        DIM,
        sphere_spec(DIM, learning_rate=lr, threshold_min=tmin),
    )
    state = loop.init(jax.random.PRNGKey(seed))
    for _ in range(iterations):
        state, metrics, _ = loop.step(state)
    return float(metrics["qd_score"]), float(metrics["coverage"])


def pyribs(archive: str, seed: int, iterations: int) -> tuple[float, float]:
    """The same with pyribs' GridArchive, IsoLineEmitter and Scheduler (result archive beside)."""
    from ribs.archives import GridArchive
    from ribs.emitters import IsoLineEmitter as RibsIsoLine
    from ribs.schedulers import Scheduler

    lr, tmin = SETTINGS[archive]
    spec = sphere_spec(DIM)
    ranges = [tuple(r) for r in spec.ranges]
    main = GridArchive(
        solution_dim=DIM, dims=spec.cells, ranges=ranges, learning_rate=lr, threshold_min=tmin, seed=seed
    )
    result = GridArchive(solution_dim=DIM, dims=spec.cells, ranges=ranges, seed=seed)
    rng = np.random.default_rng(seed)
    emitters = [
        RibsIsoLine(
            main,
            x0=np.zeros(DIM),
            iso_sigma=ISO,
            line_sigma=LINE,
            batch_size=BATCH,
            seed=int(rng.integers(2**31)),
        )
        for _ in range(EMITTERS)
    ]
    scheduler = Scheduler(main, emitters, result_archive=result)
    for _ in range(iterations):
        sols = scheduler.ask()
        ev = sphere_objective(jax.numpy.asarray(sols, jax.numpy.float32))
        scheduler.tell(np.asarray(ev.objective, np.float64), np.asarray(ev.measures, np.float64))
    return float(result.stats.qd_score), float(result.stats.coverage)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iterations", type=int, default=400)
    parser.add_argument("--seeds", type=int, default=12)
    args = parser.parse_args(argv)
    print(
        f"sphere n={DIM}, {EMITTERS} Iso+LineDD emitters x {BATCH}, x0 = 0, iso {ISO}, line {LINE}, "
        f"{args.iterations} iterations ({args.iterations * EMITTERS * BATCH:,} evaluations), "
        f"seeds 0-{args.seeds - 1}"
    )
    for archive in SETTINGS:
        row = {}
        for name, run in (("here", ours), ("pyribs", pyribs)):
            runs = [run(archive, s, args.iterations) for s in range(args.seeds)]
            row[name] = (mean_se_ci([q for q, _ in runs])[:2], mean_se_ci([c for _, c in runs])[:2])
        (qa, sa), (ca, csa) = row["here"]
        (qb, sb), (cb, csb) = row["pyribs"]
        z = (qa - qb) / math.hypot(sa, sb) if sa > 0 or sb > 0 else math.nan
        print(
            f"{archive:9s} archive: QD-score here {qa:,.0f} ± {sa:,.0f}, pyribs {qb:,.0f} ± {sb:,.0f} "
            f"(difference {z:+.1f} s.e.); coverage here {ca:.4f} ± {csa:.4f}, pyribs {cb:.4f} ± {csb:.4f}"
        )


if __name__ == "__main__":
    main()
