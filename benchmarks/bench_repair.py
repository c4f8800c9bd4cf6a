"""Repair time and Hamming distance (median and max) on generator outputs and the paper's example.

    .venv/bin/python -m benchmarks.bench_repair [--n-small 50] [--n-large 10] [--n-full 5]

(a) ``n_small`` random NCA generators (parameters ~ N(0, 0.2^2), the paper's sigma0) at 33x36,
    C = 50, warehouse (even) and manufacturing, default (neighbourhood) repair;
(b) the paper's unrepaired CMA-MAE warehouse layout (its CPLEX repair moved 32 tiles);
(c) ``n_large`` random generators at 101x102, C_eval = 200, each domain; the goal is every repair
    within 120 s;
(d) the cost of not solving one monolithic MILP: the first ``n_full`` inputs of (a), and (b),
    repaired with ``method=full`` (time limit ``--full-limit``), Hamming compared.
Prints one table; all repairs single-threaded.

    .venv/bin/python -m benchmarks.bench_repair --elites 30 [--runs results/<run>,...]

instead repairs the NCA layouts (at S, C = 50) of ``--elites`` elites of each shipped search
(drawn with ``--seed``) with the domain's repair settings at S under time limits
(``improve_windows: null``, as the shipped searches ran) and under work limits (the default
from 2026-11-28: LP relaxation and its exact rounding; ``--windows N``: with N windows after
it): per run and mode the median / mean / max seconds, how many are proven optimal or within
1 % of the proven bound, and the total distance.

    .venv/bin/python -m benchmarks.bench_repair --seval 5 [--runs ...] [--modes 'time;work;work, lazy']

repairs the 5 best elites of each run at S_eval (C_eval) with the evaluation's time-limited
neighbourhood repair and with the work-limited hybrid, one line per layout and mode.

    .venv/bin/python -m benchmarks.bench_repair --probe 7402,7408 --runs results/<run> [--probe-s 300]
    .venv/bin/python -m benchmarks.bench_repair --probe 4616 --probe-size eval --runs results/manufacturing_a5

where a repair's gap lies (issue 54): at S, the default repair of each named cell's NCA layout,
then the whole map's MILP warm-started from its layout for ``--probe-s`` seconds (does the
incumbent fall or the bound rise?), the MILP without connectivity and the LP with connectivity
as separator cuts (two other lower bounds, :mod:`benchmarks.repair_bounds`); at S_eval, the
whole map's LP relaxation from the neighbourhood's layout by primal simplex and by interior
point (seconds, iterations, bound).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from nca_qd.io import load_map, reference_maps_dir
from nca_qd.layouts import warehouse as wh
from nca_qd.nca import NCAGenerator
from nca_qd.repair import make_rules, repair
from nca_qd.repair.validator import check

PAPER = reference_maps_dir() / "warehouse" / "paper_cma-mae_a5_even_33x36_unrepaired.json"


def generated(domain: str, region: tuple[int, int], n: int, n_iters: int, seed: int) -> np.ndarray:
    """Full layouts from ``n`` random generators started from the domain seed."""
    from experiments.cli import compose_config
    from nca_qd.domains import make_domain

    dom = make_domain(compose_config("repair", [f"domain={domain}"]).domain)
    gen = NCAGenerator(dom.n_tiles)
    params = np.random.default_rng(seed).normal(0.0, 0.2, size=(n, gen.n_params))
    regions = np.asarray(gen.generate(params, dom.seed(region), n_iters))
    return dom.assemble(regions)


def run_set(label: str, domain: str, layouts, rows: list, **opts) -> list:
    results = []
    for lay in layouts:
        res = repair(domain, lay, **opts)
        ok = res.layout is not None and check(res.layout, make_rules(domain, lay.shape)) is None
        results.append((res, ok))
    times = [r.seconds for r, _ in results]
    ham = [r.hamming for r, _ in results if r.hamming is not None]
    statuses = {}
    for r, _ in results:
        statuses[r.status] = statuses.get(r.status, 0) + 1
    rows.append(
        (
            label,
            len(results),
            statistics.median(times),
            max(times),
            statistics.median(ham) if ham else float("nan"),
            max(ham) if ham else float("nan"),
            sum(ok for _, ok in results),
            ", ".join(f"{k} {v}" for k, v in sorted(statuses.items())),
        )
    )
    print(f"  done: {label}", flush=True)
    return results


RUNS = "results/warehouse_even_qd/cma_mae_a5_s0,results/warehouse_uneven_a5"


def elites(
    runs: str, n: int, seed: int, windows: int | None = None, modes_wanted: list[str] | None = None
) -> None:
    """Time-limited against work-limited repair (with the flow's LP and the rules-only one,
    ``connectivity: lazy``) on ``n`` elites of each run (module docstring); ``modes_wanted``:
    only these."""
    from experiments.cli import compose_config
    from nca_qd.domains import make_domain
    from nca_qd.evaluation.layouts import load_run
    from nca_qd.pipeline import generate, make_generator
    from nca_qd.scoring.jobs import repair_options

    print("run | mode | n | median s | mean s | max s | proven optimal | within 1 % | distance")
    for run in runs.split(","):
        cfg, archive = load_run(run)
        dom = make_domain(cfg["domain"])
        gen = make_generator(dom)
        work = repair_options(compose_config("run", [f"domain={cfg['domain']['name']}"]).domain, "train")
        if windows is not None:  # work limits with this window budget
            work = {**work, "improve_windows": windows}
        timed = {**work, "improve_windows": None}  # the time limits of the shipped searches
        filled = np.flatnonzero(np.isfinite(np.asarray(archive["objective"])))
        cells = np.random.default_rng(seed).choice(filled, size=min(n, len(filled)), replace=False)
        genotypes = np.asarray(archive["genotypes"])
        modes = {"time": timed, "work": work, "work, lazy": {**work, "connectivity": "lazy"}}
        modes = {m: o for m, o in modes.items() if modes_wanted is None or m in modes_wanted}
        out: dict[str, list] = {m: [] for m in modes}
        for cell in cells:
            lay = np.asarray(
                dom.assemble(generate(dom, gen, genotypes[cell][None], which="train")[0]), np.int32
            )
            for mode, opts in modes.items():
                out[mode].append(repair(cfg["domain"]["name"], lay, **opts))
        for mode, res in out.items():
            secs = [r.seconds for r in res]
            near = sum(
                r.objective is not None and r.objective - r.details["bound"] <= 0.01 * r.objective
                for r in res
            )
            print(
                f"{run} | {mode} | {len(res)} | {statistics.median(secs):.2f} | "
                f"{statistics.fmean(secs):.2f} | {max(secs):.2f} | "
                f"{sum(r.status == 'optimal' for r in res)} | {near} | "
                f"{sum(r.objective or 0 for r in res):.0f}",
                flush=True,
            )


def seval(runs: str, n: int, windows: int = 0, modes_wanted: list[str] | None = None) -> None:
    """The ``n`` best elites of each run at S_eval (C_eval): the time-limited repair the
    evaluation ran until 2026-11-28 (neighbourhood, 20 s of windows) against the work-limited
    hybrid (LP relaxation and its exact rounding, then ``windows`` windows), with the flow's LP
    and with the rules-only one (``connectivity: lazy``); ``modes_wanted``: only these."""
    from experiments.cli import compose_config
    from nca_qd.domains import make_domain
    from nca_qd.evaluation.layouts import load_run
    from nca_qd.pipeline import generate, make_generator
    from nca_qd.run_dir import select_elites
    from nca_qd.scoring.jobs import repair_options

    print("run | cell | mode | status | seconds | distance | proven bound | gap")
    for run in runs.split(","):
        cfg, archive = load_run(run)
        name = cfg["domain"]["name"]
        dom = make_domain(cfg["domain"])
        gen = make_generator(dom)
        base = repair_options(compose_config("run", [f"domain={name}"]).domain, "eval")
        modes = {
            "time": {**base, "method": "neighbourhood", "improve_windows": None, "improve_time_s": "auto"},
            "work": {**base, "method": "hybrid", "improve_windows": windows, "connectivity": "flow"},
            "work, lazy": {**base, "method": "hybrid", "improve_windows": windows, "connectivity": "lazy"},
        }
        if modes_wanted:
            modes = {m: o for m, o in modes.items() if m in modes_wanted}
        genotypes = np.asarray(archive["genotypes"])
        for cell in select_elites(np.asarray(archive["objective"]), n):
            lay = np.asarray(
                dom.assemble(generate(dom, gen, genotypes[cell][None], which="eval")[0]), np.int32
            )
            for mode, opts in modes.items():
                r = repair(name, lay, **opts)
                print(
                    f"{run} | {int(cell)} | {mode} | {r.status} | {r.seconds:.1f} | {r.objective} | "
                    f"{r.details['bound']:.0f} | {100 * r.details.get('gap', float('nan')):.2f} %",
                    flush=True,
                )


def probe(run: str, cells: list[int], seconds: float, size: str) -> None:
    """Where the gap of each cell's repair lies (module docstring, ``--probe``)."""
    import dataclasses

    from benchmarks.repair_bounds import separator_lp, without_connectivity
    from experiments.cli import compose_config
    from nca_qd.domains import make_domain
    from nca_qd.evaluation.layouts import load_run
    from nca_qd.pipeline import generate, make_generator
    from nca_qd.repair import tie_costs
    from nca_qd.repair.milp import solve_window
    from nca_qd.scoring.jobs import repair_options

    cfg, archive = load_run(run)
    name = cfg["domain"]["name"]
    dom = make_domain(cfg["domain"])
    gen = make_generator(dom)
    opts = repair_options(compose_config("run", [f"domain={name}"]).domain, size)
    genotypes = np.asarray(archive["genotypes"])
    print("cell | size | what | status | seconds | distance | bound | detail")
    for cell in cells:
        lay = np.asarray(dom.assemble(generate(dom, gen, genotypes[cell][None], which=size)[0]), np.int32)
        rules = make_rules(
            name, lay.shape, n_shelves=opts.get("n_shelves"), n_agents=opts.get("n_agents", 200)
        )
        rules = dataclasses.replace(rules, tie_costs=tie_costs(lay, rules, opts.get("seed", 0)))
        if size == "train":
            r = repair(name, lay, **opts)
            print(
                f"{cell} | S | default | {r.status} | {r.seconds:.1f} | {r.objective} | "
                f"{r.details['bound']:.0f} |"
            )
            res = solve_window(r.layout, lay, ~rules.fixed, rules, time_limit=seconds, warm_start=True)
            print(
                f"{cell} | S | MILP from it | {res.status} | {res.seconds:.1f} | {res.objective} | "
                f"{res.bound} | {res.nodes} nodes",
                flush=True,
            )
            st, obj, bound, sec = without_connectivity(r.layout, lay, rules, seconds)
            print(f"{cell} | S | MILP without connectivity | {st} | {sec:.1f} | {obj} | {bound} |")
            lp, rounds, cuts, sec = separator_lp(r.layout, lay, rules)
            print(
                f"{cell} | S | LP, connectivity by separator cuts | bound | {sec:.1f} | — | {lp} | "
                f"{rounds} rounds, {cuts} cuts",
                flush=True,
            )
            continue
        # the neighbourhood's valid layout (no improvement windows) as the LP's start
        start = repair(name, lay, **{**opts, "method": "neighbourhood", "improve_windows": 0}).layout
        for solver in ("simplex", "ipm"):
            res = solve_window(
                start,
                lay,
                ~rules.fixed,
                rules,
                time_limit=seconds,
                relaxation=True,
                iteration_limit=10_000_000,
                lp_solver=solver,
            )
            frac = None if res.fractional is None else int(res.fractional.sum())
            print(
                f"{cell} | S_eval | LP by {solver} | {res.status} | {res.seconds:.1f} | — | {res.bound} | "
                f"{res.iterations} iterations, {frac} cells fractional",
                flush=True,
            )


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-small", type=int, default=50)
    ap.add_argument("--n-large", type=int, default=10)
    ap.add_argument("--n-full", type=int, default=5)
    ap.add_argument("--full-limit", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--elites", type=int, default=0, help="repair this many elites of each --runs instead")
    ap.add_argument("--runs", default=RUNS)
    ap.add_argument(
        "--windows", type=int, default=None, help="(--elites, --seval) the work mode's window budget"
    )
    ap.add_argument(
        "--seval", type=int, default=0, help="repair this many best elites of each --runs at S_eval instead"
    )
    ap.add_argument(
        "--modes",
        default=None,
        help="(--seval, --elites) only these modes, separated by ';': time, work, 'work, lazy'",
    )
    ap.add_argument("--probe", default=None, metavar="CELL[,CELL]", help="where these cells' repair gap lies")
    ap.add_argument("--probe-s", type=float, default=300.0, help="(--probe) seconds per solve")
    ap.add_argument("--probe-size", choices=("train", "eval"), default="train")
    args = ap.parse_args([] if argv is None else argv)
    modes = None if args.modes is None else [m.strip() for m in args.modes.split(";")]
    if args.probe:
        probe(args.runs.split(",")[0], [int(c) for c in args.probe.split(",")], args.probe_s, args.probe_size)
        return
    if args.seval:
        seval(args.runs, args.seval, args.windows or 0, modes)
        return
    if args.elites:
        elites(args.runs, args.elites, args.seed, args.windows, modes)
        return
    rows: list = []
    compare: list = []
    t0 = time.perf_counter()
    for domain, region in (("warehouse_even", (33, 32)), ("manufacturing", (33, 36))):
        lays = generated(domain, region, args.n_small, 50, args.seed)
        small = run_set(f"(a) {domain} 33x36", domain, lays, rows)
        full = run_set(
            f"(d) {domain} 33x36 full MILP",
            domain,
            lays[: args.n_full],
            rows,
            method="full",
            time_limit_s=args.full_limit,
        )
        for (s, _), (f, _) in zip(small, full):
            compare.append((domain, s.hamming, f.hamming, f.status, s.seconds, f.seconds))
    if PAPER.is_file():
        lay = load_map(PAPER, wh.TILES).to_array(wh.TILES)
        ((s, _),) = run_set("(b) paper CMA-MAE a=5 even", "warehouse_even", [lay], rows)
        ((f, _),) = run_set(
            "(b) ... full MILP", "warehouse_even", [lay], rows, method="full", time_limit_s=args.full_limit
        )
        compare.append(("paper example", s.hamming, f.hamming, f.status, s.seconds, f.seconds))
    for domain, region in (("warehouse_even", (101, 98)), ("manufacturing", (101, 102))):
        lays = generated(domain, region, args.n_large, 200, args.seed + 1)
        run_set(f"(c) {domain} 101x102", domain, lays, rows)

    print(f"\nrepair benchmark ({time.perf_counter() - t0:.0f} s in all; 1 thread per repair)")
    head = ("set", "n", "t med s", "t max s", "Ham med", "Ham max", "valid", "statuses")
    print(" | ".join(head))
    for r in rows:
        print(f"{r[0]} | {r[1]} | {r[2]:.2f} | {r[3]:.2f} | {r[4]:.0f} | {r[5]:.0f} | {r[6]}/{r[1]} | {r[7]}")
    print(
        "\nneighbourhood vs full MILP (same input): domain | Ham nbhd | Ham full | full status | "
        "t nbhd s | t full s"
    )
    for c in compare:
        print(f"{c[0]} | {c[1]} | {c[2]} | {c[3]} | {c[4]:.2f} | {c[5]:.2f}")


if __name__ == "__main__":
    import sys

    main(sys.argv[1:])
