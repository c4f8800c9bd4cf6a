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
The screen is kept for what free flow cannot know: whether a layout congests.
:func:`rhcr_estimate` therefore takes each screened run's verdict and replaces a flowing run's
throughput by ``efficiency * free flow``; a congested run keeps its own throughput (tasks done
before the stop, over T), scaled like RHCR's.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import shortest_path

from nca_qd.sim.scenario import Scenario

__all__ = ["mean_leg_cost", "free_flow_throughput", "rhcr_estimate"]


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
        total += float(wa @ dist @ wb) + cb.dwell
    return total / len(cycle)


def free_flow_throughput(scen: Scenario, n_agents: int) -> float:
    """Tasks per step if no agent ever waited: ``n_agents / mean_leg_cost``."""
    return n_agents / mean_leg_cost(scen)


def rhcr_estimate(
    throughput: ArrayLike, success: ArrayLike, free_flow: ArrayLike, efficiency: float, congested_scale: float
) -> np.ndarray:
    """RHCR's mean throughput estimated from screened runs ``[..., runs]`` of layouts ``[...]``
    (their ``free_flow``): a run that flowed counts ``efficiency * free_flow``, a congested one
    ``congested_scale`` times its own throughput; the mean over the last axis. ``efficiency``
    is RHCR's share of free flow where it flows (a calibrated constant of the domain and
    density); ``congested_scale`` the screen's usual scale."""
    thr, ok = np.asarray(throughput, dtype=float), np.asarray(success, dtype=bool)
    if thr.shape != ok.shape or thr.ndim == 0 or thr.shape[-1] == 0:
        raise ValueError(f"rhcr_estimate needs runs on the last axis, got {thr.shape} and {ok.shape}")
    flowing = efficiency * np.asarray(free_flow, dtype=float)[..., None]
    return np.where(ok, flowing, congested_scale * thr).mean(-1)
