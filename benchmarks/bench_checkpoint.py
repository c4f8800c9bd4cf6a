"""Sparse checkpoints (``make bench``): size, write time, and what the compact state changes.

Prints

* the size and write time of a maze checkpoint at the paper's final coverage (0.54 of 41,472
  cells, ~22,400 elites; the optimisation archive sharing ``--shared`` of its elites with the
  result archive: 77 % after 3,750 evaluations of a real maze run, 58 % after 11,250, so
  0.5 by default) and at 1,500 elites, compact and exact;
* how far CMA-ES's covariance moves from its start in a run (||C - I||_F / ||I||_F and the
  eigenvalue range after 50 / 100 / 200 generations) and what the compact covariance leaves out;
* the sphere benchmark resumed 5 times from compact checkpoints against the uninterrupted run,
  same seed (d = 100: 15 emitters x 36; d = 2,000: 5 x 10, the warehouse search's shape).

    python -m benchmarks.bench_checkpoint [--quick]
"""

from __future__ import annotations

import argparse
import functools
import os
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

from nca_qd.evaluation.stats import mean_se_ci
from nca_qd.qd import checkpoint as ck
from nca_qd.qd.benchmarks import normalised_qd_score, sphere_batch_objective, sphere_spec
from nca_qd.qd.emitters import ESEmitters
from nca_qd.qd.loop import QDLoop


def sphere_resumed(
    dim: int,
    n_emitters: int,
    batch: int,
    iters: int,
    resumes: int,
    seed: int = 0,
    policy: ck.CheckpointPolicy = ck.CheckpointPolicy(),  # noqa: B008 - frozen, immutable
    workdir: Path | None = None,
    probe: tuple[int, ...] = (),
) -> tuple[float, float, list[dict]]:
    """Normalised QD-score of the sphere run uninterrupted and resumed ``resumes`` times from
    checkpoints (evenly spaced), same seed; plus covariance figures at the ``probe`` iterations."""
    spec, emitter, loop = _sphere_loop(dim, n_emitters, batch)
    n_cells = int(np.prod(spec.cells))
    stops = {round(iters * (k + 1) / (resumes + 1)) for k in range(resumes)}
    drift: list[dict] = []

    def run(resume: bool) -> float:
        state = loop.init(jax.random.PRNGKey(seed))
        metrics = {}
        with tempfile.TemporaryDirectory(dir=workdir) as tmp:
            path = Path(tmp) / "checkpoint.npz"
            for it in range(1, iters + 1):
                state, metrics, _ = loop.step(state)
                if not resume and it in probe:
                    drift.append(covariance_figures(state, it))
                if resume and it in stops:
                    ck.save_checkpoint(path, state, emitter, policy)
                    state, _ = ck.load_checkpoint(path, loop.init(jax.random.PRNGKey(seed)), emitter)
        return normalised_qd_score(metrics["qd_score"], n_cells)

    return run(False), run(True), drift


@functools.lru_cache(maxsize=4)
def _sphere_loop(dim: int, n_emitters: int, batch: int) -> tuple:
    """One loop per shape, so runs that differ only in seed share its jitted programs (the
    loop is stateless: state in, state out)."""
    spec = sphere_spec(n=dim)
    emitter = ESEmitters(n_emitters, batch, dim, 0.5)
    return spec, emitter, QDLoop(emitter, sphere_batch_objective(), dim, spec)


def covariance_figures(state, iteration: int) -> dict:
    """Per emitter: generations since its (re)start, ||C - I||_F / ||I||_F, eigenvalue range."""
    from nca_qd.qd.emitters import lowrank_offdiagonal

    es = state.emitter_state.es
    out = []
    for c, g in zip(np.asarray(es.C, np.float64), np.asarray(es.generation_counter)):
        d = c.shape[0]
        ev = np.linalg.eigvalsh((c + c.T) / 2)
        left = lowrank_offdiagonal(c, 8)[3]
        out.append((int(g), np.linalg.norm(c - np.eye(d)) / np.sqrt(d), ev[0], ev[-1], left))
    return {"iteration": iteration, "emitters": out}


def print_drift(drift: list[dict]) -> None:
    for row in drift:
        e = row["emitters"]
        gens = sorted({g for g, *_ in e})
        rel = max(r for _, r, *_ in e)
        lo, hi = min(x[2] for x in e), max(x[3] for x in e)
        left = max(x[4] for x in e)
        print(
            f"  after {row['iteration']:>3} iterations (generations since restart {gens[0]}..{gens[-1]}): "
            f"||C - I||/||I|| <= {rel:.2e}, eigenvalues in [{lo:.5f}, {hi:.5f}], "
            f"compact covariance (rank 8) would leave out ||dC||_F / mean diag <= {left:.2g}"
        )


def maze_checkpoint_sizes(n_elites: int, shared: float, workdir: Path) -> None:
    """Size / write time of the maze's checkpoint with ``n_elites`` elites in both archives."""
    from experiments.cli import compose_config
    from nca_qd.experiment import Experiment

    cfg = compose_config("run", ["domain=maze", "qd.progress=false"])
    exp = Experiment(cfg, workdir / "maze")
    state = exp.initial_state()
    n, d = state.res_archive.genotypes.shape
    rng = np.random.default_rng(0)
    cells = rng.choice(n, n_elites, replace=False)
    g = np.zeros((n, d), np.float32)
    g[cells] = rng.normal(0, 0.3, (n_elites, d)).astype(np.float32)
    f = np.full((n, 1), -np.inf, np.float32)
    f[cells, 0] = rng.integers(0, 2, n_elites)
    desc = np.zeros((n, 2), np.float32)
    desc[cells] = rng.uniform(0, 200, (n_elites, 2))
    res = state.res_archive.replace(genotypes=g, fitnesses=f, descriptors=desc)
    g_opt = g.copy()
    other = rng.choice(cells, int(round((1 - shared) * n_elites)), replace=False)
    g_opt[other] += rng.normal(0, 0.05, (other.size, d)).astype(np.float32)
    opt = state.opt_archive.replace(genotypes=g_opt, fitnesses=f, descriptors=desc)
    state = state.replace(res_archive=res, opt_archive=opt)
    for policy in (ck.CheckpointPolicy(), ck.CheckpointPolicy(exact=True)):
        path = workdir / "ck.npz"
        t0 = time.perf_counter()
        ck.save_checkpoint(path, state, exp.loop.emitter, policy)
        t_write = time.perf_counter() - t0
        t0 = time.perf_counter()
        ck.load_checkpoint(path, exp.initial_state(), exp.loop.emitter)
        t_read = time.perf_counter() - t0
        print(
            f"  {n_elites:,} elites ({shared:.0%} shared), {'exact' if policy.exact else 'compact'}: "
            f"{os.path.getsize(path) / 1e6:.1f} MB, write {t_write:.2f} s, read {t_read:.2f} s"
        )


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="smaller sphere runs")
    ap.add_argument("--seeds", type=int, default=8, help="sphere runs at d=100")
    ap.add_argument(
        "--shared",
        type=float,
        default=0.5,
        help="share of optimisation elites that are the result elite of their cell",
    )
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        print("maze checkpoint (256 x 162 cells, d = 1,730, 5 CMA-ES emitters):")
        maze_checkpoint_sizes(22_400, args.shared, work)
        maze_checkpoint_sizes(1_500, args.shared, work)
        # (d, emitters, batch, iterations, seeds): one trajectory's QD-score varies by a few
        # per cent from another's (d=100: sd 0.75 of 46.2 over 11 seeds), so the means of the
        # same seeds are compared.
        cases = [(100, 15, 36, 100 if args.quick else 500, args.seeds)]
        if not args.quick:
            cases.append((2000, 5, 10, 200, 3))
        for dim, n_em, batch, iters, seeds in cases:
            probe = tuple(p for p in (50, 100, 200) if p <= iters)
            t0 = time.perf_counter()
            full, resumed, drift = [], [], []
            for seed in range(seeds):
                f, r, dr = sphere_resumed(
                    dim, n_em, batch, iters, 5, seed=seed, workdir=work, probe=probe if seed == 0 else ()
                )
                full.append(f)
                resumed.append(r)
                drift += dr
            gap = (np.mean(resumed) - np.mean(full)) / np.mean(full)
            print(
                f"sphere d={dim} ({n_em} x {batch}, {iters} iterations, seeds 0-{seeds - 1}): "
                f"QD-score uninterrupted {_mean_se(full)}, resumed 5 times from compact "
                f"checkpoints {_mean_se(resumed)} ({gap:+.2%}; target within 2 %; per seed "
                + ", ".join(f"{(r - f) / f:+.1%}" for f, r in zip(full, resumed))
                + f") [{time.perf_counter() - t0:.0f} s]"
            )
            print_drift(drift)


def _mean_se(xs: list[float]) -> str:
    m, se = mean_se_ci(xs)[:2]
    return f"{m:.3f} ± {se:.3f}"


if __name__ == "__main__":
    main()
