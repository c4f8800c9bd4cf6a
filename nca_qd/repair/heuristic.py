"""Fast greedy construction of a valid layout near the unrepaired one (no solver).

Both multi-agent domains have the same shape of constraints: *anchor* tiles (shelves; the three
station kinds) block movement and need an endpoint neighbour, endpoints need an anchor neighbour,
and the traversable tiles must stay connected. The construction therefore chooses the anchor set
first and the endpoints after it:

1. Start with no anchors (everything traversable, hence connected) and add cells as anchors in
   order of their estimated saving in weighted Hamming distance (a lazy greedy: savings only
   shrink as anchors are added). A cell is added only if it keeps three invariants, each checked
   on its 3x3 neighbourhood: its traversable 4-neighbours stay connected around it (so the whole
   traversable set stays connected), it keeps a free traversable neighbour (a future endpoint),
   and so does every anchor next to it.
2. Traversable cells next to an anchor keep an input endpoint, all others become empty; an anchor
   still without an endpoint gets one on a free neighbour (which the invariants guarantee).

A layout family's :class:`~nca_qd.layouts.base.Construction` says which anchors and which mode:
an exact count (the warehouse's N_s shelves), or anchors added while that saves distance, then
each kind made to occur (manufacturing's stations). The result is valid by construction (the
validator checks it),
not optimal: :mod:`nca_qd.repair.neighbourhood` improves it with exact window MILPs.
"""

from __future__ import annotations

import heapq

import numpy as np

from nca_qd.layouts.base import Construction
from nca_qd.layouts.rules import NEIGHBOURS, Rules

# The 8 cells around a cell in ring order; consecutive entries are 4-adjacent.
_RING = ((-1, -1), (-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1), (0, -1))
_RING_IS_FOUR = (False, True, False, True, False, True, False, True)


class _State:
    """Anchor set under construction with the counters the greedy needs."""

    def __init__(
        self, layout_in: np.ndarray, rules: Rules, anchors: tuple[int, ...], endpoint: int, empty: int
    ):
        self.h, self.w = layout_in.shape
        self.x_in = layout_in
        self.rules = rules
        self.anchor_tiles = anchors
        self.endpoint = endpoint
        self.empty = empty
        self.free = ~rules.fixed
        base = rules.fixed_layout if rules.fixed_layout is not None else np.full(layout_in.shape, empty)
        self.tile = np.where(self.free, empty, base).astype(np.int32)
        self.passable = rules.passable_mask(self.tile)
        self.n_anchor_nb = np.zeros(layout_in.shape, dtype=np.int32)  # anchors among neighbours
        self.weights = rules.objective_weights(layout_in)
        self.in_endpoint = layout_in == endpoint

    def nbrs(self, r: int, c: int):
        for dr, dc in NEIGHBOURS:
            rr, cc = r + dr, c + dc
            if 0 <= rr < self.h and 0 <= cc < self.w:
                yield rr, cc

    def free_passable_nbrs(self, r: int, c: int, exclude: tuple[int, int] | None = None) -> int:
        return sum(
            1
            for rr, cc in self.nbrs(r, c)
            if self.free[rr, cc] and self.passable[rr, cc] and (rr, cc) != exclude
        )

    def gain(self, r: int, c: int, kind: int) -> float:
        """Estimated drop of the weighted distance if ``(r, c)`` becomes an anchor of ``kind``."""
        wgt = float(self.weights[r, c])
        t_in = int(self.x_in[r, c])
        before = wgt if t_in in self.anchor_tiles else 0.0
        if t_in == self.endpoint and self.n_anchor_nb[r, c] == 0:
            before = wgt  # would end up empty anyway
        after = 0.0 if t_in == kind else wgt
        g = before - after
        has_endpoint = False
        for rr, cc in self.nbrs(r, c):
            if self.free[rr, cc] and self.passable[rr, cc] and self.in_endpoint[rr, cc]:
                has_endpoint = True
                if self.n_anchor_nb[rr, cc] == 0:
                    g += float(self.weights[rr, cc])
        if not has_endpoint:
            g -= 1.0
        return g

    def can_add(self, r: int, c: int) -> bool:
        if not (self.free[r, c] and self.passable[r, c]):
            return False
        if self.free_passable_nbrs(r, c) == 0:
            return False
        for rr, cc in self.nbrs(r, c):
            if (
                int(self.tile[rr, cc]) in self.anchor_tiles
                and self.free_passable_nbrs(rr, cc, exclude=(r, c)) == 0
            ):
                return False
        # Traversable 4-neighbours must lie on one run of traversable ring cells.
        ring = []
        for dr, dc in _RING:
            rr, cc = r + dr, c + dc
            ring.append(0 <= rr < self.h and 0 <= cc < self.w and bool(self.passable[rr, cc]))
        runs_with_four = 0
        start = next((i for i in range(8) if not ring[i]), None)
        if start is None:
            return True  # all 8 around are traversable
        in_run = False
        run_has_four = False
        for step in range(1, 9):
            j = (start + step) % 8
            if ring[j]:
                if not in_run:
                    in_run, run_has_four = True, False
                run_has_four |= _RING_IS_FOUR[j]
            elif in_run:
                in_run = False
                runs_with_four += run_has_four
        return runs_with_four <= 1

    def add(self, r: int, c: int, kind: int) -> None:
        self.tile[r, c] = kind
        self.passable[r, c] = False
        for rr, cc in self.nbrs(r, c):
            self.n_anchor_nb[rr, cc] += 1

    def finish(self) -> np.ndarray:
        """Endpoints for the chosen anchors (step 2 of the module docstring)."""
        out = self.tile.copy()
        free_pass = self.free & self.passable
        supported = self.n_anchor_nb > 0
        out[free_pass] = self.empty
        out[free_pass & supported & self.in_endpoint] = self.endpoint
        is_anchor = np.isin(out, list(self.anchor_tiles))
        for r, c in np.argwhere(is_anchor):
            if any(out[rr, cc] == self.endpoint for rr, cc in self.nbrs(r, c)):
                continue
            best, best_score = None, -1
            for rr, cc in self.nbrs(r, c):
                if self.free[rr, cc] and self.passable[rr, cc]:
                    score = sum(1 for r2, c2 in self.nbrs(rr, cc) if is_anchor[r2, c2])
                    if score > best_score:
                        best, best_score = (rr, cc), score
            if best is not None:
                out[best] = self.endpoint
        return out


def _greedy(state: _State, kind_of, n_target: int | None, max_anchors: int) -> int:
    """Add anchors by lazy greedy; ``n_target`` exact count or None (while the gain is positive)."""
    h, w = state.h, state.w
    heap: list[tuple[float, int]] = []
    for r in range(h):
        for c in range(w):
            if state.free[r, c]:
                heap.append((-state.gain(r, c, kind_of(r, c)), r * w + c))
    heapq.heapify(heap)
    added = 0
    limit = max_anchors if n_target is None else min(n_target, max_anchors)
    for _ in range(3):  # cells rejected now may become addable once neighbours are anchors
        rejected: list[tuple[float, int]] = []
        while heap and added < limit:
            neg, idx = heapq.heappop(heap)
            r, c = divmod(idx, w)
            if not state.passable[r, c]:
                continue
            g = state.gain(r, c, kind_of(r, c))
            if heap and -g > heap[0][0] + 1e-9 and -g > neg + 1e-9:
                heapq.heappush(heap, (-g, idx))
                continue
            if n_target is None and g <= 0:
                heapq.heappush(heap, (-g, idx))
                break
            if state.can_add(r, c):
                state.add(r, c, kind_of(r, c))
                added += 1
            else:
                rejected.append((-g, idx))
        if added >= limit or not rejected or (n_target is None):
            break
        heap = list(heap) + rejected
        heapq.heapify(heap)
    return added


def fixed_count_layout(
    layout_in: np.ndarray, rules: Rules, shelf: int, endpoint: int, empty: int, n_shelves: int
) -> np.ndarray | None:
    """A valid layout near ``layout_in`` with exactly ``n_shelves`` anchors of tile ``shelf``
    (the warehouse's shelves; None if none found)."""
    state = _State(layout_in, rules, (shelf,), endpoint, empty)
    added = _greedy(state, lambda r, c: shelf, n_shelves, n_shelves)
    if added != n_shelves:
        return None
    return state.finish()


def balanced_kinds_layout(
    layout_in: np.ndarray, rules: Rules, stations: tuple[int, ...], endpoint: int, empty: int, n_agents: int
) -> np.ndarray | None:
    """A valid layout near ``layout_in`` with anchors of every kind in ``stations`` and at least
    ``n_agents`` traversable tiles (manufacturing's stations; None if none found)."""
    state = _State(layout_in, rules, stations, endpoint, empty)
    counts = {s: 0 for s in stations}

    def kind_of(r: int, c: int) -> int:
        t = int(layout_in[r, c])
        if t in counts:
            return t
        return min(stations, key=lambda s: (counts[s], s))

    max_anchors = int(state.free.sum()) - int(n_agents)
    if max_anchors < len(stations):
        return None

    orig_add = state.add

    def add(r: int, c: int, kind: int) -> None:  # keeps the kind balance up to date
        orig_add(r, c, kind)
        counts[kind] += 1

    state.add = add  # type: ignore[method-assign]
    added = _greedy(state, kind_of, None, max_anchors)
    # Every kind at least once: a new station where it costs least, else relabel a spare one.
    for kind in stations:
        if counts[kind] > 0:
            continue
        best, best_gain = None, -np.inf
        if added < max_anchors:
            for r, c in np.argwhere(state.free & state.passable):
                if state.can_add(int(r), int(c)):
                    g = state.gain(int(r), int(c), kind)
                    if g > best_gain:
                        best, best_gain = (int(r), int(c)), g
        if best is not None:
            state.add(*best, kind)
            added += 1
            continue
        spare = [s for s in stations if counts[s] >= 2]
        if not spare:
            return None
        donor = max(spare, key=lambda s: counts[s])
        r, c = np.argwhere(state.tile == donor)[0]
        state.tile[r, c] = kind
        counts[donor] -= 1
        counts[kind] += 1
    return state.finish()


def greedy_layout(
    layout_in: np.ndarray, rules: Rules, construction: Construction, n_agents: int
) -> np.ndarray | None:
    """The greedy construction a layout family's :class:`Construction` asks for: exactly the
    count its rules fix for the anchors (warehouse shelves), or anchors while they save distance
    with every kind present and ``n_agents`` traversable tiles left (manufacturing)."""
    c = construction
    if c.exact_count:
        anchors = frozenset(c.anchors)
        target = next(r.value for r in rules.counts if r.op == "==" and r.tiles == anchors)
        return fixed_count_layout(layout_in, rules, c.anchors[0], c.endpoint, c.empty, target)
    return balanced_kinds_layout(layout_in, rules, c.anchors, c.endpoint, c.empty, n_agents)
