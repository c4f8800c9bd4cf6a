"""Independent checker for executed lifelong-MAPF paths.

Replays a simulation's executed paths and asserts the rules of the model, sharing no code
with the simulators (not even the scenario module): it reads only the layout family's declared
facts (:mod:`nca_qd.layouts`: blocked tiles, goal kinds, dwell times, their cycle) and applies
them with its own tile rules, its own goal rules, its own task counting. Used on every
simulation in the tests.

Rules checked:

* every position is on the map and on a traversable tile (warehouse: not ``@``;
  manufacturing: not a station);
* every step is a wait or a move to a 4-neighbour;
* no two agents on one tile at the same time (vertex conflict), no two agents swapping
  tiles along an edge in one step (swap conflict);
* each agent's goals follow the scenario's cycle of goal kinds (any start): warehouse goals
  alternate endpoint / workstation; manufacturing goals cycle through station kinds 0, 1, 2,
  each an endpoint 4-adjacent to a station of that kind with dwell 2, 5, 10;
* finished tasks recounted from the paths equal the simulator's ``tasks_per_step``. An
  agent works on its goals in order; a goal with dwell d is done at the timestep where the
  agent has stood on its cell for the arrival step plus d further consecutive timesteps.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from nca_qd.layouts import get_layout


class CheckError(AssertionError):
    """The executed paths break a rule of the model."""


@dataclass
class CheckReport:
    n_steps: int
    n_agents: int
    finished_tasks: int
    tasks_per_step: np.ndarray


def _rc(pos) -> tuple[int, int]:
    return int(pos[0]), int(pos[1])


def traversable_mask(rows: Sequence[str], scenario: str) -> np.ndarray:
    """Tiles agents may stand on, by the checker's own rules."""
    grid = np.array([list(r) for r in rows])
    return ~np.isin(grid, list(_task(scenario).blocked))


def _task(scenario: str):
    try:
        return get_layout(scenario, "scenario").task
    except Exception as exc:  # noqa: BLE001 - the checker reports, it does not raise user errors
        raise CheckError(f"checker does not know scenario {scenario!r}") from exc


def check_moves(paths: np.ndarray, traversable: np.ndarray) -> None:
    """Assert the movement rules on ``paths`` ``[S+1, N, 2]`` (row, col)."""
    paths = np.asarray(paths)
    if paths.ndim != 3 or paths.shape[2] != 2 or paths.shape[0] < 1:
        raise CheckError(f"paths must be [steps+1, agents, 2], got shape {paths.shape}")
    h, w = traversable.shape
    r, c = paths[..., 0].astype(np.int64), paths[..., 1].astype(np.int64)
    off = (r < 0) | (r >= h) | (c < 0) | (c >= w)
    if off.any():
        t, a = np.argwhere(off)[0]
        raise CheckError(f"agent {a} off the map at time {t}: {_rc(paths[t, a])}")
    blocked = ~traversable[r, c]
    if blocked.any():
        t, a = np.argwhere(blocked)[0]
        raise CheckError(f"agent {a} on a non-traversable tile at time {t}: {_rc(paths[t, a])}")
    step = np.abs(np.diff(r, axis=0)) + np.abs(np.diff(c, axis=0))
    if (step > 1).any():
        t, a = np.argwhere(step > 1)[0]
        raise CheckError(f"agent {a} jumps from {_rc(paths[t, a])} to {_rc(paths[t + 1, a])} at time {t + 1}")
    cell = r * w + c
    # Vertex conflicts: a repeated cell within one timestep.
    srt = np.sort(cell, axis=1)
    dup = srt[:, 1:] == srt[:, :-1]
    if dup.any():
        t, k = np.argwhere(dup)[0]
        agents = np.flatnonzero(cell[t] == srt[t, k])
        raise CheckError(
            f"vertex conflict at time {t}: agents {agents.tolist()} on {divmod(int(srt[t, k]), w)}"
        )
    # Swap conflicts: two moving agents on the same undirected edge in the same step (without
    # vertex conflicts this can only be a swap).
    src, dst = cell[:-1], cell[1:]
    moving = src != dst
    if moving.any():
        t_idx, a_idx = np.nonzero(moving)
        lo = np.minimum(src[moving], dst[moving])
        hi = np.maximum(src[moving], dst[moving])
        n_cells = h * w
        key = (t_idx.astype(np.int64) * n_cells + lo) * n_cells + hi
        uniq, counts = np.unique(key, return_counts=True)
        if (counts > 1).any():
            bad = uniq[counts > 1][0]
            agents = a_idx[key == bad]
            t = int(t_idx[key == bad][0])
            raise CheckError(f"swap conflict between agents {agents.tolist()} in the step to time {t + 1}")


def check_goals(goals: Sequence[np.ndarray], rows: Sequence[str], scenario: str) -> None:
    """Assert each agent's goal sequence follows the scenario's task rules."""
    grid = np.array([list(r) for r in rows])
    h, w = grid.shape
    goal_kinds = _task(scenario).goals
    n_kinds = len(goal_kinds)
    for a, seq in enumerate(goals):
        seq = np.asarray(seq)
        options = []  # per goal: the kinds it can be
        for r, c, dwell in seq.tolist():
            if not (0 <= r < h and 0 <= c < w):
                raise CheckError(f"agent {a}: goal {(r, c)} off the map")
            tile = grid[r, c]
            near = {
                grid[rr, cc]
                for rr, cc in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1))
                if 0 <= rr < h and 0 <= cc < w
            }
            fits = {
                k
                for k, g in enumerate(goal_kinds)
                if g.tile == tile and g.dwell == dwell and (g.next_to is None or g.next_to in near)
            }
            if not fits:
                raise CheckError(
                    f"agent {a}: goal {(r, c)} is {tile!r} with dwell {dwell}: no "
                    f"matching kind of goal in {scenario} "
                    f"({', '.join(g.name for g in goal_kinds)})"
                )
            options.append(fits)
        # The kinds must follow the cycle: some start kind explains the whole sequence.
        possible = set(options[0]) if options else set()
        for i, fits in enumerate(options[1:], start=1):
            possible = {(k + 1) % n_kinds for k in possible} & fits
            if not possible:
                prev = " or ".join(goal_kinds[k].name for k in sorted(options[i - 1]))
                nxt = " or ".join(goal_kinds[k].name for k in sorted(fits))
                raise CheckError(
                    f"agent {a}: goal kind {nxt} may not follow {prev} (goal {i} of its sequence)"
                )


def recount_tasks(paths: np.ndarray, goals: Sequence[np.ndarray]) -> np.ndarray:
    """Goals completed at each time 1..S, replaying each agent's path through its goals."""
    paths = np.asarray(paths)
    steps = paths.shape[0] - 1
    done = np.zeros(steps, dtype=np.int64)
    for a, seq in enumerate(goals):
        seq = [tuple(g) for g in np.asarray(seq).tolist()]
        k = 0  # index of the goal being worked on
        since = None  # time of arrival on goal k's cell, while staying there
        track = paths[:, a, :].tolist()
        for t in range(1, steps + 1):
            pos = tuple(track[t])
            while k < len(seq) and pos == seq[k][:2]:
                if since is None:
                    since = t
                if t - since < seq[k][2]:
                    break
                done[t - 1] += 1
                k += 1
                since = None
            else:
                if k >= len(seq) or pos != seq[k][:2]:
                    since = None
    return done


def check_run(result, rows: Sequence[str], scenario: str | None = None) -> CheckReport:
    """Check a simulation result that recorded its paths (``record_paths=True``).

    ``result`` needs ``paths``, ``goals``, ``tasks_per_step``, ``stop_time``, ``T`` and
    ``throughput`` (as :class:`nca_qd.sim.rhcr.SimResult` has).
    """
    scenario = scenario or result.scenario
    if result.paths is None:
        raise CheckError("the result has no paths; simulate with record_paths=True")
    paths = np.asarray(result.paths)
    if paths.shape[0] != result.stop_time + 1:
        raise CheckError(f"{paths.shape[0]} path rows for stop_time {result.stop_time}")
    check_moves(paths, traversable_mask(rows, scenario))
    check_goals(result.goals, rows, scenario)
    recount = recount_tasks(paths, result.goals)
    claimed = np.asarray(result.tasks_per_step)
    if claimed.shape[0] != result.T or claimed[result.stop_time :].any():
        raise CheckError("tasks_per_step must have T entries, zero after the stop time")
    if not np.array_equal(recount, claimed[: result.stop_time]):
        t = int(np.flatnonzero(recount != claimed[: result.stop_time])[0])
        raise CheckError(
            f"finished tasks differ at time {t + 1}: recounted {recount[t]}, "
            f"simulator says {claimed[t]} (total {recount.sum()} vs {claimed.sum()})"
        )
    total = int(recount.sum())
    if not np.isclose(result.throughput, total / result.T):
        raise CheckError(f"throughput {result.throughput} != {total} / {result.T}")
    return CheckReport(paths.shape[0] - 1, paths.shape[1], total, recount)
