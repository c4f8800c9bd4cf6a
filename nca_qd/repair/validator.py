"""Independent validity check of a layout: graph search and counting, no MILP.

The repair's output is trusted only after this check: it shares nothing with the MILP but the
:class:`~nca_qd.layouts.rules.Rules` data, and reports each violated constraint with a location
(row, column) so that a failure says what is wrong and where.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from nca_qd.layouts.rules import Rules, has_neighbour_in

_FOUR = ndimage.generate_binary_structure(2, 1)


@dataclass(frozen=True)
class Violation:
    """One violated constraint: which (``constraint``), where (``cell`` or None) and a message."""

    constraint: str
    cell: tuple[int, int] | None
    message: str

    def __str__(self) -> str:
        return self.message


def _cell(mask: np.ndarray) -> tuple[int, int]:
    r, c = np.argwhere(mask)[0]
    return int(r), int(c)


def violations(layout: np.ndarray, rules: Rules, limit: int = 20) -> list[Violation]:
    """All violated constraints of ``layout`` (at most ``limit`` per constraint), empty if valid."""
    layout = np.asarray(layout)
    out: list[Violation] = []
    tiles = rules.tiles
    if layout.shape != rules.shape:
        return [
            Violation(
                "shape",
                None,
                f"layout is {layout.shape[0]}x{layout.shape[1]}, expected {rules.shape[0]}x{rules.shape[1]}",
            )
        ]
    if layout.min() < 0 or layout.max() >= len(tiles):
        return [Violation("alphabet", None, "tile index outside the alphabet")]

    # (fixed) cells that the domain keeps unchanged.
    if rules.fixed_layout is not None:
        bad = rules.fixed & (layout != rules.fixed_layout)
        for r, c in np.argwhere(bad)[:limit]:
            out.append(
                Violation(
                    "fixed",
                    (int(r), int(c)),
                    f"fixed tile changed at ({r}, {c}): {tiles[layout[r, c]]!r}, "
                    f"must be {tiles[rules.fixed_layout[r, c]]!r}",
                )
            )
    free = ~rules.fixed
    bad_free = free & ~np.isin(layout, list(rules.free_tiles))
    for r, c in np.argwhere(bad_free)[:limit]:
        out.append(
            Violation("alphabet", (int(r), int(c)), f"tile {tiles[layout[r, c]]!r} not allowed at ({r}, {c})")
        )

    # (connectivity) passable tiles form one 4-connected component; reach-only tiles touch it.
    passable = rules.passable_mask(layout)
    labels, n_comp = ndimage.label(passable, structure=_FOUR)
    if n_comp > 1:
        sizes = np.bincount(labels.ravel())[1:]
        main = int(np.argmax(sizes)) + 1
        anchor = _cell(labels == main)
        for k in range(1, n_comp + 1):
            if k == main or len(out) >= 4 * limit:
                continue
            r, c = _cell(labels == k)
            out.append(
                Violation(
                    "connectivity",
                    (r, c),
                    f"tile ({r}, {c}) cannot reach ({anchor[0]}, {anchor[1]}) "
                    f"({n_comp} separate traversable regions)",
                )
            )
    if rules.reach_only:
        reach = np.isin(layout, list(rules.reach_only)) & ~has_neighbour_in(passable)
        for r, c in np.argwhere(reach)[:limit]:
            out.append(
                Violation(
                    "connectivity", (int(r), int(c)), f"{tiles[layout[r, c]]!r} at ({r}, {c}) is unreachable"
                )
            )

    # (adjacency) every A tile has a B 4-neighbour.
    for rule in rules.adjacency:
        has_b = has_neighbour_in(np.isin(layout, list(rule.needs)))
        bad = np.isin(layout, list(rule.tiles)) & ~has_b
        for r, c in np.argwhere(bad)[:limit]:
            out.append(
                Violation(
                    "adjacency", (int(r), int(c)), f"{rule.name}: {tiles[layout[r, c]]!r} at ({r}, {c})"
                )
            )

    # (counts)
    for rule in rules.counts:
        n = int(np.isin(layout, list(rule.tiles)).sum())
        ok = n == rule.value if rule.op == "==" else n >= rule.value
        if not ok:
            out.append(Violation("count", None, f"{rule.name}: {n} (must be {rule.op} {rule.value})"))
    return out


def check(layout: np.ndarray, rules: Rules) -> Violation | None:
    """The first violation of ``layout``, or None when it is valid."""
    found = violations(layout, rules, limit=1)
    return found[0] if found else None


def is_valid(layout: np.ndarray, rules: Rules) -> bool:
    return check(layout, rules) is None


def violation_mask(layout: np.ndarray, rules: Rules) -> np.ndarray:
    """``[h, w]`` bool: cells involved in a local violation (adjacency, small components, fixed).

    Count violations are global and have no cells; the repair's neighbourhood grows around
    this mask (see :mod:`nca_qd.repair.neighbourhood`).
    """
    layout = np.asarray(layout)
    mask = np.zeros(layout.shape, dtype=bool)
    if rules.fixed_layout is not None:
        mask |= rules.fixed & (layout != rules.fixed_layout)
    mask |= ~rules.fixed & ~np.isin(layout, list(rules.free_tiles))
    passable = rules.passable_mask(layout)
    labels, n_comp = ndimage.label(passable, structure=_FOUR)
    if n_comp > 1:
        sizes = np.bincount(labels.ravel())
        sizes[0] = 0
        main = int(np.argmax(sizes))
        mask |= (labels > 0) & (labels != main)
    if rules.reach_only:
        mask |= np.isin(layout, list(rules.reach_only)) & ~has_neighbour_in(passable)
    for rule in rules.adjacency:
        has_b = has_neighbour_in(np.isin(layout, list(rule.needs)))
        mask |= np.isin(layout, list(rule.tiles)) & ~has_b
    return mask
