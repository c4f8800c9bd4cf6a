"""Layouts in the formats other multi-agent path finding tools read.

- **MovingAI** (the MAPF benchmark's format): a ``.map`` grid (``type octile``, ``height``,
  ``width``, ``map``, then one row per line: ``.`` free, ``@`` blocked) and a ``.scen`` of one
  start and goal per agent (``version 1``; per line: bucket, map file, width, height, start
  column and row, goal column and row, shortest path length) — a one-shot instance: each agent's
  first goal of the domain's task cycle.
- **League of Robot Runners** (the lifelong MAPF competition's start kit): the same ``.map``,
  an ``.agents`` file (count, then one start per line), a ``.tasks`` file (count, then one task
  per line: its errands in order) and the problem ``.json`` (``mapFile``, ``agentFile``,
  ``taskFile``, ``teamSize``, ``numTasksReveal``). Locations are linearised as
  ``row * width + column``. A task is one cycle of the domain's goals (warehouse: an endpoint,
  then a workstation; manufacturing: one station of each kind), each goal drawn as this
  project's simulators draw it (the uneven warehouse's left workstations five times as likely).

- **json**: the paper's map file (``name``, ``n_row``, ``n_col``, ``layout``), which this
  project's commands read (``experiments.simulate layout=``, ``experiments.repair``).

Starts are distinct free cells drawn from ``seed``; the same seed gives the same files.
"""

from __future__ import annotations

import json
from collections import deque

import numpy as np

from nca_qd.errors import NcaQdError
from nca_qd.sim.scenario import Scenario

FORMATS = ("movingai", "lorr", "json")


def movingai_map(scen: Scenario) -> str:
    """The MovingAI ``.map`` text of a scenario's grid."""
    h, w = scen.shape
    rows = ["".join("." if free else "@" for free in row) for row in scen.traversable]
    return "\n".join(["type octile", f"height {h}", f"width {w}", "map", *rows]) + "\n"


def _starts(scen: Scenario, n_agents: int, rng: np.random.Generator) -> np.ndarray:
    free = np.flatnonzero(scen.traversable.ravel())
    if not 0 < n_agents <= free.size:
        raise NcaQdError(f"agents must be in 1..{free.size} (the layout's free cells), got {n_agents}")
    return rng.choice(free, size=n_agents, replace=False)


def _goal(scen: Scenario, k: int, rng: np.random.Generator) -> int:
    cls = scen.classes[scen.cycle[k % len(scen.cycle)]]
    return int(rng.choice(cls.cells, p=cls.weights / cls.weights.sum()))


def distances_from(traversable: np.ndarray, source: int) -> np.ndarray:
    """Shortest 4-connected path lengths from the flat cell ``source`` (-1: unreachable)."""
    h, w = traversable.shape
    free = traversable.ravel()
    dist = np.full(h * w, -1, dtype=np.int64)
    dist[source] = 0
    queue = deque([source])
    while queue:
        v = queue.popleft()
        r, c = divmod(v, w)
        for rr, cc in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)):
            u = rr * w + cc
            if 0 <= rr < h and 0 <= cc < w and free[u] and dist[u] < 0:
                dist[u] = dist[v] + 1
                queue.append(u)
    return dist


def movingai_scen(scen: Scenario, map_name: str, n_agents: int, seed: int = 0) -> str:
    """The MovingAI ``.scen`` text: ``n_agents`` distinct starts, each with a first goal."""
    rng = np.random.default_rng(seed)
    starts = _starts(scen, n_agents, rng)
    h, w = scen.shape
    lines = ["version 1"]
    for s in starts:
        g = _goal(scen, 0, rng)
        length = int(distances_from(scen.traversable, int(s))[g])
        (sr, sc), (gr, gc) = divmod(int(s), w), divmod(g, w)
        lines.append(f"0\t{map_name}\t{w}\t{h}\t{sc}\t{sr}\t{gc}\t{gr}\t{length}")
    return "\n".join(lines) + "\n"


def lorr_files(
    scen: Scenario, name: str, n_agents: int, n_tasks: int, seed: int = 0, reveal: float = 1.0
) -> dict[str, str]:
    """The League of Robot Runners problem: file name -> text (``<name>.json`` is the input)."""
    if n_tasks < 1:
        raise NcaQdError(f"tasks must be at least 1, got {n_tasks}")
    if reveal <= 0:
        raise NcaQdError(f"reveal must be positive, got {reveal}")
    rng = np.random.default_rng(seed)
    starts = _starts(scen, n_agents, rng)
    per_task = len(scen.cycle)
    tasks = [" ".join(str(_goal(scen, k, rng)) for k in range(per_task)) for _ in range(n_tasks)]
    problem = {
        "mapFile": f"{name}.map",
        "agentFile": f"{name}.agents",
        "taskFile": f"{name}.tasks",
        "teamSize": int(n_agents),
        "numTasksReveal": float(reveal),
    }
    return {
        f"{name}.map": movingai_map(scen),
        f"{name}.agents": "\n".join([str(n_agents), *map(str, starts.tolist())]) + "\n",
        f"{name}.tasks": "\n".join([str(n_tasks), *tasks]) + "\n",
        f"{name}.json": json.dumps(problem, indent=2) + "\n",
    }


def export_files(
    scen: Scenario,
    fmt: str,
    name: str,
    n_agents: int,
    n_tasks: int = 1000,
    seed: int = 0,
    reveal: float = 1.0,
) -> dict[str, str]:
    """The files of ``fmt`` (:data:`FORMATS`) for a scenario: file name -> text."""
    if fmt == "movingai":
        return {
            f"{name}.map": movingai_map(scen),
            f"{name}.scen": movingai_scen(scen, f"{name}.map", n_agents, seed),
        }
    if fmt == "lorr":
        return lorr_files(scen, name, n_agents, n_tasks, seed, reveal)
    if fmt == "json":
        h, w = scen.shape
        mapfile = {"name": name, "n_row": h, "n_col": w, "layout": list(scen.rows)}
        return {f"{name}.json": json.dumps(mapfile, indent=4)}
    raise NcaQdError(f"unknown format {fmt!r} (known: {', '.join(FORMATS)})")
