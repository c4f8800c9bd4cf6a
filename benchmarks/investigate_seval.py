"""Why a generator that flows at S congests at S_eval: its layouts at C_eval and nearby
iteration counts, their repairs (default and near-optimal) and exact RHCR on each.

    python -m benchmarks.investigate_seval layouts --run-dir results/warehouse_uneven_a5 --out inv.npz \
        [--top 10] [--iters 200,201,300,400]
    python -m benchmarks.investigate_seval polish --npz inv.npz --domain warehouse_uneven \
        --budget 420 --workers 16 [--keys c5930_C200,...] --out polished.npz
    python -m benchmarks.investigate_seval exact --npz inv.npz --domain warehouse_uneven \
        --agents 1000 [--keys ...] [--which repaired] [--seeds 10] --jsonl runs.jsonl

``layouts``: the best generator at S at each of ``--iters`` and the next ``--top`` - 1 at C_eval,
generated at S_eval, repaired with the run's S_eval options (``key__unrepaired`` /
``key__repaired``), with the NCA's and the repair's tile counts printed. ``phase``: the best
``--top`` at S scored as the search scores them (repair at S, N_e exact runs of T = 1,000) at
C and at C + 1 .. C + ``--extra``: how the archive would rank them by the lower score. ``polish``: the repair
with the whole-map MILP warm-started from the default result for ``--budget`` seconds (one
layout per process), printing the proven bound and gap (``key__polished``). ``exact``: RHCR at
T = 5,000 on each layout, one JSON line per layout (appended to ``--jsonl``).
Results of 2026-11-28 and what they show: docs/reproducing.md (warehouse uneven at S_eval).
"""

from __future__ import annotations

import argparse
import json
import time
from multiprocessing import Pool

import numpy as np


def _load(run_dir: str):
    from nca_qd.domains import make_domain
    from nca_qd.evaluation.layouts import load_run
    from nca_qd.pipeline import make_generator

    cfg, archive = load_run(run_dir)
    d = cfg["domain"]
    dom = make_domain(d)
    return d, dom, make_generator(dom), archive


def layouts(args) -> None:
    from nca_qd.pipeline import generate
    from nca_qd.repair import repair, tiles_of
    from nca_qd.run_dir import select_elites
    from nca_qd.scoring.jobs import repair_options

    d, dom, gen, archive = _load(args.run_dir)
    cells = select_elites(np.asarray(archive["objective"]), args.top)
    genotypes = np.asarray(archive["genotypes"])
    c_eval = dom.nca_iters("eval")
    jobs = [(int(cells[0]), int(c)) for c in args.iters.split(",")] + [(int(c), c_eval) for c in cells[1:]]
    if args.cells:  # these cells at C_eval instead
        jobs = [(int(c), c_eval) for c in args.cells.split(",")]
    opts = repair_options(d, "eval")
    tiles = tiles_of(d["name"])
    out = {}
    for cell, n_iters in jobs:
        region = generate(dom, gen, genotypes[cell][None], which="eval", n_iters=n_iters)[0]
        lay = np.asarray(dom.assemble(region), dtype=np.int32)
        res = repair(d["name"], lay, **opts)
        key = f"c{cell}_C{n_iters}"
        out[f"{key}__unrepaired"], out[f"{key}__repaired"] = lay, res.layout
        counts = " ".join(
            f"{t!r} {int((lay == i).sum())}->{int((res.layout == i).sum())}"
            for i, t in enumerate(tiles)
            if res.layout is not None
        )
        print(
            f"{key}: {res.status}, Hamming {res.hamming}, Delta {res.similarity:.3f}, {res.seconds:.1f} s, "
            f"bound {res.details['bound']:.0f}; tiles NCA->repaired {counts}",
            flush=True,
        )
    np.savez_compressed(args.out, **out)


def phase(args) -> None:
    from nca_qd.pipeline import generate
    from nca_qd.repair import repair, tiles_of
    from nca_qd.run_dir import select_elites
    from nca_qd.scoring.jobs import repair_options
    from nca_qd.sim.rhcr import simulate_many

    d, dom, gen, archive = _load(args.run_dir)
    objective = np.asarray(archive["objective"])
    cells = select_elites(objective, args.top)
    genotypes = np.asarray(archive["genotypes"])
    opts = repair_options(d, "train")
    tiles, c0 = tiles_of(d["name"]), dom.nca_iters("train")
    sim = d["simulation"]
    n_agents, T, n_runs = int(d["n_agents"]["train"]), int(sim["T"]), int(sim["n_runs"])
    for cell in cells:
        scores = []
        for n_iters in range(c0, c0 + args.extra + 1):
            region = generate(dom, gen, genotypes[cell][None], which="train", n_iters=n_iters)[0]
            res = repair(d["name"], np.asarray(dom.assemble(region), dtype=np.int32), **opts)
            if res.layout is None:
                scores.append(float("nan"))
                continue
            rows = ["".join(tiles[i] for i in r) for r in res.layout]
            runs = simulate_many(rows, d["name"], n_agents, T, list(range(n_runs)), threads=args.threads)
            scores.append(float(np.mean([r.throughput for r in runs])))
        line = {"cell": int(cell), "archive": round(float(objective[cell]), 3)}
        line.update({f"C{c0 + i}": round(v, 3) for i, v in enumerate(scores)})
        line["lowest"] = round(float(np.nanmin(scores)), 3)
        print(json.dumps(line), flush=True)
        if args.jsonl:
            with open(args.jsonl, "a") as f:
                f.write(json.dumps(line) + "\n")


def _polish_one(job):
    from nca_qd.repair import repair

    key, lay, domain, opts, budget = job
    res = repair(domain, lay, **dict(opts, method="hybrid", milp_time_s=budget, time_limit_s=budget + 300))
    line = {
        "layout": key,
        "status": res.status,
        "hamming": res.hamming,
        "objective": res.objective,
        "bound": res.details.get("bound"),
        "gap": res.details.get("gap"),
        "seconds": round(res.seconds, 1),
    }
    return line, res.layout


def polish(args) -> None:
    from experiments.cli import compose_config
    from nca_qd.scoring.jobs import repair_options

    d = compose_config("repair", [f"domain={args.domain}"]).domain
    opts = repair_options(d, "eval")
    z = np.load(args.npz)
    keys = _keys(z, args.keys)
    jobs = [(k, z[f"{k}__unrepaired"], args.domain, opts, float(args.budget)) for k in keys]
    with Pool(max(1, min(args.workers, len(jobs)))) as pool:
        results = pool.map(_polish_one, jobs, chunksize=1)
    for line, _ in results:
        print(json.dumps(line), flush=True)
    np.savez_compressed(
        args.out, **{f"{line['layout']}__polished": lay for line, lay in results if lay is not None}
    )


def exact(args) -> None:
    from nca_qd.repair import tiles_of
    from nca_qd.sim.rhcr import simulate_many

    z = np.load(args.npz)
    tiles = tiles_of(args.domain)
    for key in _keys(z, args.keys):
        lay = z[f"{key}__{args.which}"]
        rows = ["".join(tiles[i] for i in r) for r in lay]
        t0 = time.perf_counter()
        runs = simulate_many(
            rows, args.domain, args.agents, args.T, list(range(args.seeds)), threads=args.threads
        )
        ok = [r.throughput for r in runs if r.success]
        line = {
            "layout": key,
            "which": args.which,
            "agents": args.agents,
            "T": args.T,
            "runs": len(runs),
            "success": len(ok),
            "throughput": round(float(np.mean(ok)), 3) if ok else None,
            "stop_times": [int(r.stop_time) for r in runs],
            "seconds": round(time.perf_counter() - t0, 1),
        }
        print(json.dumps(line), flush=True)
        if args.jsonl:
            with open(args.jsonl, "a") as f:
                f.write(json.dumps(line) + "\n")


def _keys(z, only: str | None) -> list[str]:
    keys = sorted({k.split("__")[0] for k in z.files})
    return [k for k in keys if not only or k in only.split(",")]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="part", required=True)
    a = sub.add_parser("layouts")
    a.add_argument("--run-dir", required=True)
    a.add_argument("--out", required=True)
    a.add_argument("--top", type=int, default=10)
    a.add_argument("--iters", default="200,201,300,400")
    a.add_argument("--cells", default=None, help="comma-separated cells, each at C_eval")
    p = sub.add_parser("phase")
    p.add_argument("--run-dir", required=True)
    p.add_argument("--top", type=int, default=20)
    p.add_argument("--extra", type=int, default=1)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--jsonl", default=None)
    b = sub.add_parser("polish")
    b.add_argument("--npz", required=True)
    b.add_argument("--domain", required=True)
    b.add_argument("--budget", type=float, default=420.0)
    b.add_argument("--workers", type=int, default=2)
    b.add_argument("--keys", default=None)
    b.add_argument("--out", required=True)
    c = sub.add_parser("exact")
    c.add_argument("--npz", required=True)
    c.add_argument("--domain", required=True)
    c.add_argument("--agents", type=int, required=True)
    c.add_argument("--T", type=int, default=5000)
    c.add_argument("--seeds", type=int, default=10)
    c.add_argument("--threads", type=int, default=2)
    c.add_argument("--which", default="repaired", choices=("repaired", "polished", "unrepaired"))
    c.add_argument("--keys", default=None)
    c.add_argument("--jsonl", default=None)
    args = ap.parse_args(argv)
    {"layouts": layouts, "phase": phase, "polish": polish, "exact": exact}[args.part](args)


if __name__ == "__main__":
    main()
