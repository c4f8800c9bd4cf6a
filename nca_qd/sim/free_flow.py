"""Free-flow throughput of a lifelong-MAPF scenario, and the screen's RHCR estimate built on it.

**Free flow**: the tasks per step if no agent ever waited for another. An agent's goals cycle
through the scenario's classes; a goal of class ``b`` after one of class ``a`` is a weighted
draw from ``b``'s cells, independent of where the agent is, so the expected cost of that leg is
``E[d(a, b)] + dwell_b`` (true shortest-path distance on the traversable tiles). With ``n``
agents and a cycle of ``k`` legs, free-flow throughput = ``n * k / sum of the legs' costs``.
It depends on the layout alone (no simulation) and is an upper bound on any simulator's.

**Why the screen needs it.** Where RHCR flows its throughput is a near-constant share of free
flow (measured at 33x36, 200 agents, T=1,000: 0.90-0.96 of it, most layouts 0.93-0.95), while
the PIBT screen's share varies more from layout to layout (its moves lack RHCR's lookahead, and
how much that costs depends on the aisles). On the search's own layouts, which mostly flow,
free flow ranks RHCR's throughput better than the screen's own throughput does (150 random
layouts of the warehouse search's memo, ``bench_screen``'s ``search`` part: Spearman 0.90
against 0.60).
The screen is kept for what free flow cannot know: whether a layout congests, and how badly.
:func:`rhcr_estimate` gives a layout whose screened runs all flowed ``efficiency * free flow``;
a layout with a congested screened run gets a fitted share of free flow from the screen's
mean throughput and mean stop time (both over free flow / T), capped at ``efficiency``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import shortest_path

from nca_qd.host_blas import one_thread
from nca_qd.sim.scenario import Scenario

__all__ = [
    "mean_leg_cost",
    "free_flow_throughput",
    "rhcr_estimate",
    "CONGESTED_MODEL",
    "CONGESTED_MODEL_V3",
]

# RHCR's share of free flow on a layout with a congested screened run (of 5; PIBT screen,
# crowding rule): a + b * mean screened throughput / free flow + c * mean stop time / T.
# Least squares on the 30 such layouts of benchmarks/bench_screen.py's generator with seed 0
# (RHCR: 5 seeds, 200 agents, T=1,000, warehouse_even, pbs_max_nodes=2000), exact simulator
# version 4; held out, on the generator's seed-1 set (the bench's fidelity figures), Spearman of
# RHCR's mean throughput against the estimate 0.721 (the screen's own throughput) -> 0.816.
# The default of ``eval.screen_congested`` (experiments/conf/run.yaml).
CONGESTED_MODEL = (0.458, 4.529, -2.608)
# The same fit against exact simulator version 3 (held out: 0.801 -> 0.875 then, 0.797 against
# version 4): what a run config without ``eval.screen_congested`` used, and keeps using.
CONGESTED_MODEL_V3 = (0.313, 4.882, -2.644)


def _grid_graph(traversable: np.ndarray) -> tuple[csr_matrix, np.ndarray]:
    """The 4-connected graph of the traversable tiles and each tile's node index (-1: blocked)."""
    h, w = traversable.shape
    index = np.full((h, w), -1, dtype=np.int64)
    flat = np.flatnonzero(traversable.ravel())
    index.ravel()[flat] = np.arange(flat.size)
    src, dst = [], []
    for dy, dx in ((0, 1), (1, 0)):
        both = traversable[: h - dy, : w - dx] & traversable[dy:, dx:]
        ys, xs = np.nonzero(both)
        src.append(index[ys, xs])
        dst.append(index[ys + dy, xs + dx])
    s, d = np.concatenate(src), np.concatenate(dst)
    graph = coo_matrix((np.ones(s.size), (s, d)), shape=(flat.size, flat.size))
    return graph.tocsr(), index


def mean_leg_cost(scen: Scenario) -> float:
    """Expected steps per goal without waiting: mean over the cycle's legs of
    ``E[distance to the next goal] + its dwell``."""
    graph, index = _grid_graph(scen.traversable)
    node = index.ravel()
    cycle = list(scen.cycle)
    total = 0.0
    for a, b in zip(cycle, cycle[1:] + cycle[:1]):
        ca, cb = scen.classes[a], scen.classes[b]
        dist = shortest_path(graph, unweighted=True, directed=False, indices=node[ca.cells])
        dist = dist[:, node[cb.cells]]
        wa = ca.weights / ca.weights.sum()
        wb = cb.weights / cb.weights.sum()
        with one_thread():  # the same last bits on any number of cores (nca_qd.host_blas)
            total += float(wa @ dist @ wb) + cb.dwell
    return total / len(cycle)


def free_flow_throughput(scen: Scenario, n_agents: int) -> float:
    """Tasks per step if no agent ever waited: ``n_agents / mean_leg_cost``."""
    return n_agents / mean_leg_cost(scen)


def rhcr_estimate(
    throughput: ArrayLike,
    success: ArrayLike,
    stop_fraction: ArrayLike,
    free_flow: ArrayLike,
    efficiency: float,
    congested: tuple[float, float, float] = CONGESTED_MODEL,
) -> np.ndarray:
    """RHCR's mean throughput estimated from screened runs ``[..., runs]`` of layouts ``[...]``
    (their throughput, verdict and stop time / T; the layouts' ``free_flow``). All runs flowed:
    ``efficiency * free_flow`` (``efficiency``: RHCR's share of free flow where it flows, a
    calibrated constant of the domain and density). Otherwise ``free_flow`` times
    ``a + b * mean(throughput) / free_flow + c * mean(stop_fraction)`` (``congested``), kept
    within ``[0, efficiency]``."""
    thr, ok = np.asarray(throughput, dtype=float), np.asarray(success, dtype=bool)
    stop = np.asarray(stop_fraction, dtype=float)
    if thr.shape != ok.shape or thr.shape != stop.shape or thr.ndim == 0 or thr.shape[-1] == 0:
        raise ValueError(
            f"rhcr_estimate needs runs on the last axis, got {thr.shape}, {ok.shape} and {stop.shape}"
        )
    flow = np.asarray(free_flow, dtype=float)
    a, b, c = congested
    share = np.clip(a + b * thr.mean(-1) / flow + c * stop.mean(-1), 0.0, efficiency)
    return flow * np.where(ok.all(-1), efficiency, share)
