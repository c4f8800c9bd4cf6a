"""Maps too large for memory are refused before the stage that would exhaust it starts."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from nca_qd import memory
from nca_qd.errors import NcaQdError
from nca_qd.sim.scenario import build_scenario

WAREHOUSE = ["w.e@e.w", "w.e@e.w", "w.....w"]


@pytest.fixture
def one_gib(monkeypatch):
    """A machine with 1 GiB available."""
    monkeypatch.setattr(memory, "available_bytes", lambda: 2**30)


def test_available_memory_is_read_from_the_machine():
    avail = memory.available_bytes()
    assert 2**26 < avail < 2**50  # between 64 MiB and a petabyte: a real figure, not a default


def test_an_estimate_above_the_available_memory_is_one_error_line(one_gib):
    with pytest.raises(NcaQdError) as err:
        memory.check(3 * 2**30, "growing 1 layout(s) of 5000x5000")
    msg = str(err.value)
    assert "\n" not in msg
    assert "growing 1 layout(s) of 5000x5000 is too large for memory" in msg
    assert "3.0 GiB needed, 1.0 GiB available" in msg
    memory.check(0.9 * 2**30, "fits")  # under the available memory: no error


def test_small_estimates_never_read_the_machine(monkeypatch):
    def boom():
        raise AssertionError("read /proc for a small map")

    monkeypatch.setattr(memory, "available_bytes", boom)
    memory.check(memory.FLOOR - 1, "a small map")


def test_simulation_estimate_counts_a_distance_table_per_goal_cell():
    scen = build_scenario(WAREHOUSE, "warehouse_even", n_agents=2)
    goals = set()
    for c in scen.classes:
        goals |= set(np.asarray(c.cells).tolist())
    assert scen.n_goal_cells == len(goals) == 10  # 4 endpoints, 6 workstations
    cells = 3 * 7
    assert scen.simulation_bytes(2) == 10 * cells * memory.DISTANCE_BYTES + 256 * (cells + 2)


def test_each_stage_refuses_a_map_too_large_for_the_machine(monkeypatch):
    # Real stages on a machine with 1,000 bytes free: the check fires before any work.
    monkeypatch.setattr(memory, "FLOOR", 0)
    monkeypatch.setattr(memory, "available_bytes", lambda: 1000)
    from nca_qd.layouts.warehouse import human_layout
    from nca_qd.repair import repair
    from nca_qd.sim.rhcr import simulate_scenario

    with pytest.raises(NcaQdError, match="60x70 human-designed warehouse is too large for memory"):
        human_layout((60, 70))
    with pytest.raises(NcaQdError, match="repairing a 3x7 layout is too large for memory"):
        repair("warehouse_even", np.zeros((3, 7), dtype=np.int32))
    scen = build_scenario(WAREHOUSE, "warehouse_even", n_agents=2)
    with pytest.raises(NcaQdError, match="exact simulation of the 3x7 map .* too large for memory"):
        simulate_scenario(scen, 2, 10, seed=0)


def test_growing_layouts_checks_the_whole_batch(monkeypatch):
    from experiments.cli import compose_config
    from nca_qd.domains import make_domain
    from nca_qd.pipeline import generate, make_generator

    domain = make_domain(compose_config("repair", ["domain=warehouse_even"]).domain)
    gen = make_generator(domain)
    sols = np.zeros((4, gen.n_params), dtype=np.float32)
    monkeypatch.setattr(memory, "FLOOR", 0)
    fits = memory.nca_bytes(4, 10 * 12)
    monkeypatch.setattr(memory, "available_bytes", lambda: fits)
    assert generate(domain, gen, sols, shape=(10, 12), n_iters=2).shape == (4, 10, 12)
    monkeypatch.setattr(memory, "available_bytes", lambda: fits - 1)
    with pytest.raises(NcaQdError, match=r"growing 4 layout\(s\) of 10x12 is too large for memory"):
        generate(domain, gen, sols, shape=(10, 12), n_iters=2)


_FRAGMENTED_HEAP = """
import ctypes, ctypes.util
from nca_qd import memory

def rss_kib():
    with open("/proc/self/status") as f:
        return next(int(l.split()[1]) for l in f if l.startswith("VmRSS:"))

libc = ctypes.CDLL(ctypes.util.find_library("c"))
libc.malloc.restype, libc.malloc.argtypes = ctypes.c_void_p, [ctypes.c_size_t]
libc.free.argtypes = [ctypes.c_void_p]
blocks = [libc.malloc(64 * 1024) for _ in range(4000)]  # 250 MiB on the heap, below mmap's threshold
for b in blocks:
    ctypes.memset(b, 1, 64 * 1024)
base = rss_kib()
for i, b in enumerate(blocks):
    if i % 50:  # every 50th block stays: the freed memory between them cannot be trimmed off the top
        libc.free(b)
held = rss_kib()
memory.check(memory.FLOOR, "a large map")
print(base, held, rss_kib())
"""


@pytest.mark.skipif(
    not Path("/proc/self/status").is_file() or not memory.release_freed(), reason="needs glibc and /proc"
)
def test_a_check_counts_what_this_process_freed_as_available():
    # Freed heap memory that glibc keeps made a sweep's second point refuse to start (8.1 GiB
    # needed, 7.1 available, on a 23 GiB machine where the first point had held the rest).
    out = subprocess.run(
        [sys.executable, "-c", _FRAGMENTED_HEAP], capture_output=True, text=True, check=True
    ).stdout.split()
    base, held, after = (int(x) for x in out)
    assert held > 0.9 * base  # freeing alone gave back almost nothing
    assert after < held - 200 * 1024  # the check handed back the ~245 MiB freed
