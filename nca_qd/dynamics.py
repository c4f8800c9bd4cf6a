"""Does an NCA generator settle? Its layouts just after the C iterations it is scored at.

The paper grows layouts at S_eval with more iterations than at S "because the NCA generators
need more iterations to converge to a stable state", and an NCA layout scales only if what the
generator draws at C is what it keeps drawing. A trained generator's layouts at iterations
``C, C+1, ..., C+k`` fall into one of four kinds:

- ``still``: iteration C+1 changes at most ``tol`` of the cells (a fixed point);
- ``travelling``: C+1 is C's layout moved by at most ``max_shift`` cells in each direction
  (mismatch on the overlap at most ``shift_tol``): a pattern that scrolls across the map,
  the same layout up to where it is cut at the border;
- ``period_2``: C+2 is C's layout, moved or not, but C+1 is not (two alternating phases,
  which can hold different tile counts: the layout then depends on the parity of C);
- ``other``: none of these within ``k`` iterations (chaotic, or still on its way).

Besides the kind, each generator gets the largest swing of a tile's share of the map over
``C..C+k`` (how much the layout's make-up depends on where its iterations stop) and the share
of cells whose two largest output channels are exactly equal at C (a saturated sigmoid
outputs 1.0 on both; the argmax then chooses by channel index).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

KINDS = ("still", "travelling", "period_2", "other")


@dataclass(frozen=True)
class Thresholds:
    """tol: share of cells a still layout may change; shift_tol: mismatch allowed on the
    overlap of a moved layout; max_shift: the largest move looked for, in cells."""

    tol: float = 0.01
    shift_tol: float = 0.05
    max_shift: int = 2


def shifted_mismatch(a: np.ndarray, b: np.ndarray, max_shift: int) -> tuple[float, int, int]:
    """Least share of differing cells between ``b`` and ``a`` moved by ``(dy, dx)``, over moves
    of at most ``max_shift`` each way, compared on the overlap only; and that move."""
    h, w = a.shape
    best = (float((a != b).mean()), 0, 0)
    for dy in range(-max_shift, max_shift + 1):
        for dx in range(-max_shift, max_shift + 1):
            if (dy, dx) == (0, 0):
                continue
            # b[y, x] against a[y - dy, x - dx]: a's content moved by (dy, dx)
            sa = a[max(0, -dy) : h - max(0, dy), max(0, -dx) : w - max(0, dx)]
            sb = b[max(0, dy) : h - max(0, -dy), max(0, dx) : w - max(0, -dx)]
            m = float((sa != sb).mean())
            if m < best[0]:
                best = (m, dy, dx)
    return best


def classify(layouts: np.ndarray, n_tiles: int, th: Thresholds = Thresholds()) -> dict[str, float | str]:
    """The kind of one generator from its layouts ``[k + 1, H, W]`` at ``C .. C + k`` (k >= 2)."""
    if layouts.shape[0] < 3:
        raise ValueError("classify needs the layouts of at least C, C+1 and C+2")
    a0, a1, a2 = layouts[0], layouts[1], layouts[2]
    lag1, lag2 = float((a0 != a1).mean()), float((a0 != a2).mean())
    moved1 = shifted_mismatch(a0, a1, th.max_shift)
    moved2 = shifted_mismatch(a0, a2, th.max_shift)
    if lag1 <= th.tol:
        kind = "still"
    elif moved1[0] <= th.shift_tol:
        kind = "travelling"
    elif min(lag2, moved2[0]) <= th.shift_tol:
        kind = "period_2"
    else:
        kind = "other"
    shares = np.stack([(layouts == t).mean(axis=(1, 2)) for t in range(n_tiles)], axis=1)  # [k+1, n]
    swing = float((shares.max(axis=0) - shares.min(axis=0)).max())
    return {
        "kind": kind,
        "changed_1": lag1,
        "changed_2": lag2,
        "moved_mismatch_1": moved1[0],
        "moved_mismatch_2": moved2[0],
        "share_swing": swing,
    }


def summarise(kinds: list[str]) -> dict[str, float]:
    """Share of each kind (in :data:`KINDS` order)."""
    n = max(1, len(kinds))
    return {k: sum(1 for x in kinds if x == k) / n for k in KINDS}


def count_misses(layout: np.ndarray, counts) -> list[dict[str, float | int | str]]:
    """How far a full layout (before repair) is from each count rule (``nca_qd.layouts.rules.
    CountRule``: ``count(tiles) == value`` or ``>= value``). A generator that settles at S can
    still grow a different make-up at S_eval (the paper's alpha = 0 generator draws a quarter of
    the 2,250 shelves its warehouse needs at 101x102), and the repair then draws the rest: the
    layout scored is the repair's, not the generator's. ``miss``: the count's relative distance
    from what the rule allows (0 when it holds)."""
    out = []
    for rule in counts:
        got = int(np.isin(layout, sorted(rule.tiles)).sum())
        short = rule.value - got if rule.op == ">=" else abs(rule.value - got)
        miss = max(0, short) / max(1, rule.value)
        out.append({"name": rule.name, "op": rule.op, "value": int(rule.value), "got": got, "miss": miss})
    return out
