"""Small layouts shared by the simulator tests (exact RHCR and the JAX screen)."""

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
