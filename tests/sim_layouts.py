"""Small layouts shared by the simulator tests (exact RHCR and the JAX screen)."""

from collections import deque

import numpy as np
from hypothesis import strategies as st

WAREHOUSE = [
    "............",
    "w.eeee.eeeew",
    "..@@@@.@@@@.",
    "..eeee.eeee.",
    "w..........w",
    "..eeee.eeee.",
    "..@@@@.@@@@.",
    "w.eeee.eeeew",
    "............",
]
MANUFACTURING = [
    "............",
    "..ee....ee..",
    ".e00e..e11e.",
    "..ee....ee..",
    "............",
    "..ee....ee..",
    ".e22e..e22e.",
    "..ee....ee..",
    "............",
]


@st.composite
def small_warehouses(draw):
    """9 x 12 grids: random shelves/endpoints inside, workstations on the left/right border."""
    rng = np.random.default_rng(draw(st.integers(0, 2**31 - 1)))
    grid = rng.choice(list("....@e"), size=(9, 12))
    grid[:, 0] = "."
    grid[:, -1] = "."
    grid[rng.integers(0, 9), 0] = "w"
    grid[rng.integers(0, 9), -1] = "w"
    grid[rng.integers(0, 9), rng.integers(1, 11)] = "e"
    return ["".join(r) for r in grid]


def bfs_distances(grid: np.ndarray, start: int, unreachable: int) -> np.ndarray:
    """Independent breadth-first distances from one flat cell over the True cells of ``grid``
    (4-connected), ``unreachable`` where there is no path (everywhere if ``start`` is blocked)."""
    h, w = grid.shape
    out = np.full(h * w, unreachable, np.int64)
    if start < 0 or not grid.flat[start]:
        return out
    out[start] = 0
    todo = deque([start])
    while todo:
        c = todo.popleft()
        r, k = divmod(c, w)
        for rr, kk in ((r - 1, k), (r + 1, k), (r, k - 1), (r, k + 1)):
            n = rr * w + kk
            if 0 <= rr < h and 0 <= kk < w and grid[rr, kk] and out[n] == unreachable:
                out[n] = out[c] + 1
                todo.append(n)
    return out
