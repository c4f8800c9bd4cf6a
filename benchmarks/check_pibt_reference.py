"""Side by side: this core's lifelong PIBT (``planner="pibt"``) against the PIBT step of its
author's public minimal implementation, Kei18/pypibt (``pypibt/pibt.py``, ``PIBT.step``).

    git clone https://github.com/Kei18/pypibt /tmp/pypibt      # outside this repository
    python -m benchmarks.check_pibt_reference --pypibt /tmp/pypibt --agents 50,100,200 --seeds 0-4

For each run of ours (recorded paths and goal log), the reference's step is driven lock-step:
the same positions, goals, dwell states and priorities (timesteps since the goal was assigned,
plus our per-agent tie-breaker; an agent dwelling at a station first, so that it keeps its
cell), its distance tables with pibt2's tie-break (a cell occupied now counts half a step
further), and its candidate shuffle fed by our random stream (xoshiro256** seeded with
``seed ^ 0x5DEECE66D``, our candidate order, our Fisher-Yates). Nothing else of the reference
is replaced, so a difference in any agent's next cell at any step is a difference in the PIBT
algorithm itself. Prints one line per run and the count of identical runs. The reference is
imported from the given checkout, never copied here.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from benchmarks.check_pibt_swap_reference import int_list

M64 = (1 << 64) - 1
ROOT = Path(__file__).resolve().parents[1]
MAPS = {  # name: (layout file, scenario)
    "warehouse_even_human": (
        "results/warehouse_even_qd/cma_mae_a5_s0/evaluation/layouts/human_33x36.json",
        "warehouse_even",
    ),
    "manufacturing_human": ("results/manufacturing_a5/evaluation/layouts/human_33x36.json", "manufacturing"),
    "warehouse_even_nca4472": (
        "results/warehouse_even_qd/cma_mae_a5_s0/evaluation/layouts/nca_c4472_33x36.json",
        "warehouse_even",
    ),
    "warehouse_uneven_nca5930": (
        "results/warehouse_uneven_a5/evaluation/layouts/nca_c5930_33x36.json",
        "warehouse_uneven",
    ),
    "manufacturing_nca4616": (
        "results/manufacturing_a5/evaluation/layouts/nca_c4616_33x36.json",
        "manufacturing",
    ),
}


class CoreRng:
    """The core's generator (src/rng.hpp) in Python: xoshiro256** seeded by splitmix64."""

    def __init__(self, seed: int) -> None:
        x, self.s = seed & M64, []
        for _ in range(4):
            x = (x + 0x9E3779B97F4A7C15) & M64
            z = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) & M64
            z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & M64
            self.s.append(z ^ (z >> 31))

    def next(self) -> int:
        s = self.s
        rotl = lambda x, k: ((x << k) | (x >> (64 - k))) & M64  # noqa: E731
        result = (rotl((s[1] * 5) & M64, 7) * 9) & M64
        t = (s[1] << 17) & M64
        s[2] ^= s[0]
        s[3] ^= s[1]
        s[1] ^= s[2]
        s[0] ^= s[3]
        s[2] ^= t
        s[3] = rotl(s[3], 45)
        return result

    def uniform(self) -> float:
        return (self.next() >> 11) * 2.0**-53

    def below(self, n: int) -> int:  # Lemire's unbiased bounded integer, as the core
        m = self.next() * n
        if (m & M64) < n:
            threshold = ((1 << 64) - n) % n
            while (m & M64) < threshold:
                m = self.next() * n
        return m >> 64


class CoreShuffle:
    """Stands in for the reference's random generator: its ``shuffle`` of the candidates
    becomes the core's (candidates up, right, down, left, own cell; Fisher-Yates with the
    core's stream), skipped for dwelling agents (the core reserves them without a shuffle)."""

    def __init__(self, rng: CoreRng, free: np.ndarray) -> None:
        self.rng, self.free, self.skip = rng, free, set()

    def shuffle(self, cells: list) -> None:
        own = cells[0]
        if own in self.skip:
            return
        r, c = own
        cand = [
            (r + dr, c + dc)
            for dr, dc in ((-1, 0), (0, 1), (1, 0), (0, -1))
            if 0 <= r + dr < self.free.shape[0]
            and 0 <= c + dc < self.free.shape[1]
            and self.free[r + dr, c + dc]
        ] + [own]
        assert sorted(cand) == sorted(cells), (cand, cells)
        for x in range(len(cand) - 1, 0, -1):
            y = self.rng.below(x + 1)
            cand[x], cand[y] = cand[y], cand[x]
        cells[:] = cand


class OccupiedLast:
    """A reference distance table with pibt2's tie-break: cells occupied now half a step further."""

    def __init__(self, table, pibt) -> None:
        self.table, self.pibt = table, pibt

    def get(self, cell):
        return self.table.get(cell) + (0.5 if self.pibt.occupied_now[cell] != self.pibt.NIL else 0.0)


def lockstep(PIBT, DistTable, rows: list[str], scenario: str, n: int, seed: int, T: int) -> dict:
    """Replays our run through the reference's step; the first step where they differ."""
    from nca_qd.sim import rhcr
    from nca_qd.sim.scenario import build_scenario

    ours = rhcr.simulate(rows, scenario, n_agents=n, T=T, seed=seed, planner="pibt", record_paths=True)
    free = build_scenario(rows, scenario, n_agents=n).traversable
    paths = np.asarray(ours.paths)
    rng = CoreRng(seed ^ 0x5DEECE66D)
    tie = [rng.uniform() for _ in range(n)]
    goals = [np.asarray(g) for g in ours.goals]
    index, elapsed, arrived, stayed = [0] * n, [0] * n, [False] * n, [0] * n
    start = [tuple(map(int, paths[0, a])) for a in range(n)]
    pibt = PIBT(free.copy(), start, list(start))
    pibt.rng = hook = CoreShuffle(rng, free)
    tables: dict = {}

    def goal(a: int) -> tuple[tuple[int, int], int]:
        g = goals[a][index[a]]
        return (int(g[0]), int(g[1])), int(g[2])

    def set_table(a: int) -> None:
        cell = goal(a)[0]
        if cell not in tables:
            tables[cell] = DistTable(pibt.grid, cell)
        pibt.dist_tables[a] = OccupiedLast(tables[cell], pibt)

    for a in range(n):
        set_table(a)
    for t in range(paths.shape[0] - 1):
        now = [tuple(map(int, paths[t, a])) for a in range(n)]
        nxt = [tuple(map(int, paths[t + 1, a])) for a in range(n)]
        hook.skip.clear()
        priority = []
        for a in range(n):
            dwelling = arrived[a] and stayed[a] < goal(a)[1]
            if dwelling:
                hook.skip.add(now[a])
            priority.append((1e9 if dwelling else elapsed[a]) + tie[a])
        ref = pibt.step(now, priority)
        differ = [a for a in range(n) if tuple(ref[a]) != nxt[a]]
        if differ:
            return {
                "identical": False,
                "step": t,
                "differing_agents": differ[:5],
                "stop_time": ours.stop_time,
            }
        for a in range(n):  # the goal bookkeeping of the core (and of nca_qd/sim/checker.py)
            elapsed[a] += 1
            if goal(a)[0] != nxt[a]:
                arrived[a] = False
            elif arrived[a]:
                stayed[a] += 1
            else:
                arrived[a], stayed[a] = True, 0
            while arrived[a] and stayed[a] >= goal(a)[1]:
                arrived[a], index[a], elapsed[a] = False, index[a] + 1, 0
                set_table(a)
                if goal(a)[0] == nxt[a]:
                    arrived[a], stayed[a] = True, 0
    return {"identical": True, "steps": paths.shape[0] - 1, "stop_time": ours.stop_time}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--pypibt", required=True, help="a checkout of github.com/Kei18/pypibt")
    p.add_argument("--maps", default=",".join(MAPS), help=f"comma-separated, of {', '.join(MAPS)}")
    p.add_argument("--agents", default="50,100,200")
    p.add_argument("--seeds", default="0-4")
    p.add_argument("--T", type=int, default=1000)
    args = p.parse_args()
    try:
        agents, seeds = int_list(args.agents), int_list(args.seeds)
    except ValueError:
        print(
            f"error: --agents {args.agents!r} / --seeds {args.seeds!r}: expected e.g. 50,100 / 0-4",
            file=sys.stderr,
        )
        return 2
    if not agents or not seeds or min(agents) < 1 or min(seeds) < 0 or args.T < 1:
        print("error: --agents, --T must be positive and --seeds non-negative", file=sys.stderr)
        return 2
    src = Path(args.pypibt)
    if not (src / "pypibt" / "pibt.py").is_file():
        print(f"error: {src} is not a checkout of Kei18/pypibt (no pypibt/pibt.py)", file=sys.stderr)
        return 2
    unknown = set(args.maps.split(",")) - set(MAPS)
    if unknown:
        print(f"error: unknown map(s) {', '.join(sorted(unknown))}", file=sys.stderr)
        return 2
    sys.path.insert(0, str(src))
    from pypibt.dist_table import DistTable
    from pypibt.pibt import PIBT

    same = total = 0
    for name in args.maps.split(","):
        path, scenario = MAPS[name]
        rows = json.loads((ROOT / path).read_text())["layout"]
        for n in agents:
            for seed in seeds:
                res = lockstep(PIBT, DistTable, rows, scenario, n, seed, args.T)
                same, total = same + res["identical"], total + 1
                print(json.dumps({"map": name, "agents": n, "seed": seed, **res}), flush=True)
    print(f"identical at every step: {same} of {total} runs")
    return 0 if same == total else 1


if __name__ == "__main__":
    sys.exit(main())
