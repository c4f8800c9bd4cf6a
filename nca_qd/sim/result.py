"""The outcome of one lifelong-MAPF run, shared by every simulator (exact RHCR, JAX screen).

``throughput`` is finished tasks / T with T the full horizon, even when the run stopped early
(congestion or time limit). ``tasks_per_step[t-1]`` counts goals completed at time t;
``tile_visits[r, c]`` counts agent-timesteps spent on the tile over times 1..stop_time.
``paths`` (when recorded) is ``[stop_time + 1, n_agents, 2]`` (row, col); ``goals[a]`` is
``[k, 3]`` (row, col, dwell): the goals agent ``a`` was given, in order.
:func:`nca_qd.sim.checker.check_run` replays any of them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class RunResult:
    scenario: str
    seed: int
    n_agents: int
    T: int
    throughput: float
    success: bool
    congested: bool
    stop_time: int
    finished_tasks: int
    tasks_per_step: np.ndarray
    tile_visits: np.ndarray
    cpu_seconds: float
    wall_seconds: float
    goals: list[np.ndarray] = field(repr=False)
    paths: np.ndarray | None = field(default=None, repr=False)
    timed_out: bool = False

    def summary(self) -> dict:
        """The per-run figures printed by ``experiments.simulate`` (JSON-friendly)."""
        return {
            "seed": self.seed,
            "throughput": self.throughput,
            "success": self.success,
            "stop_time": self.stop_time,
            "cpu_seconds": round(self.cpu_seconds, 3),
            "timed_out": self.timed_out,
        }
