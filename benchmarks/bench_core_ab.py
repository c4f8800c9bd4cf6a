"""Two builds of the C++ core side by side: identical decisions, and which is faster.

A change to the exact simulator's speed must not change a single decision (a running search's
memo and an evaluation's records stay valid only then). This runs the same cases with two
builds of ``_core`` (each a folder holding a ``_core*.so``; ``installed`` is the one this
environment imports), alternating the builds ``--rounds`` times, each run in its own process:

* ``memo`` cases: repaired layouts a search scored (``--run-dir``'s ``eval_memo.npz``, drawn
  with a fixed seed) at the search's settings (200 agents, T = 1,000, 2,000 PBS nodes a call);
* ``reference`` cases: the shared reference maps, crowded enough that planning calls fail and
  the best node's repair runs (33x36 warehouse, uneven and manufacturing, and 101x102 with
  1,400 agents);
* ``long`` cases: S_eval as an evaluation runs it (101x102, 1,400 agents, the evaluation's
  5,000 PBS nodes a call) for longer: the paper's layout, which flows, and the human one,
  which jams after failed calls.

No CPU-time limit per call (time must not decide anything here). Per run it compares
throughput, stop time, finished tasks, failed calls, PBS nodes, A* expansions and digests of
tasks per step, tile visits and nodes per call; then prints whether every run is identical and
the CPU of each build (the sum over runs of each run's fastest round: the machine's other load
moves single rounds) and each run's (``per_run``: name, seed, old, new). Build the other core
outside the repository, e.g. from another checkout:

    pip install --no-deps --target /tmp/core_new <other checkout>   # builds its _core
    python -m benchmarks.bench_core_ab --old installed --new /tmp/core_new/nca_qd/sim/rhcr \\
        --run-dir results/warehouse_even_qd/cma_mae_a5_s0 --layouts 8 --rounds 3

Exit status 1 when any decision differs.
"""

from __future__ import annotations

import argparse
import glob
import hashlib
import importlib.util
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REFERENCE = [  # (map under the shared reference maps, scenario, agents, T, PBS nodes a call)
    ("warehouse/human_33x36.json", "warehouse_even", 200, 600, 2000),
    ("warehouse/human_33x36.json", "warehouse_even", 250, 600, 300),
    ("warehouse/paper_cma-mae_a5_even_33x36.json", "warehouse_uneven", 300, 600, 500),
    ("manufacturing/human_33x36.json", "manufacturing", 200, 600, 2000),
    ("manufacturing/human_33x36.json", "manufacturing", 300, 400, 300),
    ("warehouse/paper_cma-mae_a5_even_101x102.json", "warehouse_even", 1400, 60, 5000),
    ("warehouse/human_101x102.json", "warehouse_even", 1400, 200, 500),
]


LONG = [  # the same, S_eval for longer
    ("warehouse/paper_cma-mae_a5_even_101x102.json", "warehouse_even", 1400, 1000, 5000),
    ("warehouse/human_101x102.json", "warehouse_even", 1400, 300, 5000),
]


def _load_core(build: str) -> None:
    """Make ``nca_qd.sim.rhcr`` import the core of ``build`` (a folder) instead of its own."""
    if build == "installed":
        return
    found = glob.glob(str(Path(build) / "_core*.so"))
    if not found:
        sys.exit(f"error: no _core*.so in {build}")
    spec = importlib.util.spec_from_file_location("nca_qd.sim.rhcr._core", found[0])
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["nca_qd.sim.rhcr._core"] = module
    spec.loader.exec_module(module)


def _digest(a) -> str:
    return hashlib.sha1(np.ascontiguousarray(np.asarray(a)).tobytes()).hexdigest()[:16]


def _cases(run_dir: str | None, n_layouts: int, seeds: list[int], which: list[str]) -> list[dict]:
    from nca_qd.io import array_to_rows, load_map, reference_maps_dir
    from nca_qd.layouts.warehouse import TILES

    cases = []
    if "memo" in which and run_dir:
        z = np.load(Path(run_dir) / "eval_memo.npz")
        found = np.flatnonzero(z["repair_found"])
        for i in np.random.default_rng(0).choice(found, min(n_layouts, found.size), replace=False):
            rows = array_to_rows(z["repair_layouts"][i], TILES)
            cases += [
                dict(
                    name=f"memo {i}",
                    rows=rows,
                    scenario="warehouse_even",
                    agents=200,
                    T=1000,
                    nodes=2000,
                    seed=s,
                )
                for s in seeds
            ]
    for kind, table in (("reference", REFERENCE), ("long", LONG)):
        if kind not in which:
            continue
        maps = reference_maps_dir()
        for path, scenario, agents, T, nodes in table:
            rows = load_map(maps / path).rows
            cases += [
                dict(
                    name=f"{path} {agents} T={T}",
                    rows=rows,
                    scenario=scenario,
                    agents=agents,
                    T=T,
                    nodes=nodes,
                    seed=s,
                )
                for s in seeds
            ]
    return cases


def _worker(build: str, cases_file: str, out: str) -> None:
    """Run every case with ``build``'s core; one JSON record per run into ``out``."""
    _load_core(build)
    from nca_qd.sim.rhcr import simulate

    records = []
    for c in json.loads(Path(cases_file).read_text()):
        r = simulate(
            c["rows"],
            c["scenario"],
            c["agents"],
            c["T"],
            c["seed"],
            pbs_max_nodes=c["nodes"],
            plan_time_limit_s=None,
        )
        decisions = dict(
            throughput=r.throughput,
            stop=r.stop_time,
            finished=r.finished_tasks,
            failed=int(r.pbs_failures),
            nodes=int(r.pbs_nodes),
            expansions=int(r.low_level_expansions),
            tasks=_digest(r.tasks_per_step),
            visits=_digest(r.tile_visits),
            calls=_digest(r.call_nodes),
        )
        records.append(dict(name=c["name"], seed=c["seed"], decisions=decisions, cpu=r.cpu_seconds))
    Path(out).write_text(json.dumps(records))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--old", default="installed", help="folder of the first build's _core*.so, or 'installed'")
    p.add_argument("--new", required=True, help="folder of the second build's _core*.so, or 'installed'")
    p.add_argument("--run-dir", default="results/warehouse_even_qd/cma_mae_a5_s0", help="memo cases' search")
    p.add_argument("--layouts", type=int, default=8, help="memo layouts drawn")
    p.add_argument("--seeds", default="0", help="comma-separated simulation seeds")
    p.add_argument("--cases", default="memo,reference", help="memo, reference, long (comma-separated)")
    p.add_argument("--rounds", type=int, default=3, help="runs of each build, alternating")
    p.add_argument("--worker", nargs=3, metavar=("BUILD", "CASES", "OUT"), help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.worker:
        _worker(*a.worker)
        return 0
    seeds = [int(s) for s in a.seeds.split(",")]
    cases = _cases(a.run_dir, a.layouts, seeds, a.cases.split(","))
    with tempfile.TemporaryDirectory() as tmp:
        cases_file = Path(tmp) / "cases.json"
        cases_file.write_text(json.dumps(cases))
        runs: dict[str, list[list[dict]]] = {"old": [], "new": []}
        for k in range(a.rounds):
            for which, build in (("old", a.old), ("new", a.new)):
                out = Path(tmp) / f"{which}_{k}.json"
                cmd = [
                    sys.executable,
                    "-m",
                    "benchmarks.bench_core_ab",
                    "--new",
                    build,
                    "--worker",
                    build,
                    str(cases_file),
                    str(out),
                ]
                subprocess.run(cmd, check=True)
                runs[which].append(json.loads(out.read_text()))
    ref = runs["old"][0]
    differ = [
        (r["name"], r["seed"])
        for rounds in runs.values()
        for records in rounds
        for r, r0 in zip(records, ref)
        if r["decisions"] != r0["decisions"]
    ]
    cpu = {w: sum(min(rs[i]["cpu"] for rs in runs[w]) for i in range(len(ref))) for w in runs}
    failed = sum(r["decisions"]["failed"] > 0 for r in ref)
    print(
        json.dumps(
            dict(
                runs=len(ref),
                runs_with_failed_calls=failed,
                identical=not differ,
                differing=sorted(set(differ))[:10],
                cpu_old=round(cpu["old"], 2),
                cpu_new=round(cpu["new"], 2),
                speedup=round(cpu["old"] / cpu["new"], 3),
                per_run=[
                    [r["name"], r["seed"], round(min(rs[i]["cpu"] for rs in runs["old"]), 2)]
                    + [round(min(rs[i]["cpu"] for rs in runs["new"]), 2)]
                    for i, r in enumerate(ref)
                ],
            )
        )
    )
    return 0 if not differ else 1


if __name__ == "__main__":
    sys.exit(main())
