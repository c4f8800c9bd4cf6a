"""Small layouts shared by the simulator tests (exact RHCR and the JAX screen)."""

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
