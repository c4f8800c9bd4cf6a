"""Will a map fit in memory? Estimates for the stages whose memory grows with the map, checked
before the stage starts.

A map too large for the machine would otherwise run for minutes and then be killed by the
kernel, which leaves no message a user can act on (and, for an evaluation, no clue which
layout did it). The stages check their estimate here and raise :class:`NcaQdError` with one
line -- what needs how much, what is available -- which the commands turn into exit 2.

The per-cell figures are peak resident memory measured on real maps and rounded up
(docs/benchmarks.md, "Memory against map size"). They are estimates: a check refuses only what
needs more than the memory available when it starts, and small maps (under ``FLOOR`` bytes)
are not checked at all, so the search's thousands of small calls never read ``/proc``.

What this process freed counts as available: glibc keeps freed heap memory (the simulators'
distance tables, ~140 KB each at 140x500, come from the heap once its mmap threshold has
risen) instead of returning it to the kernel, so a sweep's second point saw its first point's
gigabytes as taken and refused to start. A check hands such memory back (``malloc_trim``)
before it reads what is available.
"""

from __future__ import annotations

import ctypes
import functools
import os

from nca_qd.errors import NcaQdError

# Growing a layout (one generator): JAX's buffers of the NCA's 32-channel hidden layer.
NCA_BYTES_PER_CELL = 320
# The MILP repair (HiGHS; the neighbourhood windows, then the LP of the whole map).
REPAIR_BYTES_PER_CELL = 16_384
# A human-designed layout drawn and written out (index array, tile rows, JSON text).
HUMAN_BYTES_PER_CELL = 32
# The exact simulators keep one shortest-distance table (uint16 per cell) per goal cell they
# have used; over a long run with many agents nearly every goal cell is used.
DISTANCE_BYTES = 2
# Below this an estimate is not checked.
FLOOR = 256 * 2**20


def available_bytes() -> int:
    """Memory the kernel could give this process now (``MemAvailable``; the whole RAM where
    ``/proc/meminfo`` is missing)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))


@functools.cache
def _malloc_trim():
    """glibc's ``malloc_trim`` among the symbols this process already has; None elsewhere."""
    try:
        trim = ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError, TypeError):
        return None
    trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
    return trim


def release_freed() -> bool:
    """Return the heap memory this process freed but the C allocator still holds to the kernel
    (glibc's ``malloc_trim(0)``); False where there is no such call (another C library)."""
    trim = _malloc_trim()
    if trim is None:
        return False
    trim(0)
    return True


def _gib(n: float) -> str:
    return f"{n / 2**30:.1f} GiB"


def check(needed: float, what: str, hint: str = "use a smaller map") -> None:
    """Raise :class:`NcaQdError` when ``needed`` bytes exceed the memory available now (what
    this process freed counted as available: :func:`release_freed` first)."""
    if needed < FLOOR:
        return
    release_freed()
    avail = available_bytes()
    if needed > avail:
        raise NcaQdError(
            f"{what} is too large for memory: about {_gib(needed)} needed, {_gib(avail)} available; {hint}"
        )


def nca_bytes(batch: int, cells: int) -> int:
    """Growing ``batch`` layouts of ``cells`` cells each."""
    return int(batch) * int(cells) * NCA_BYTES_PER_CELL


def repair_bytes(cells: int) -> int:
    """Repairing one layout of ``cells`` cells."""
    return int(cells) * REPAIR_BYTES_PER_CELL


def human_bytes(cells: int) -> int:
    """Drawing one human-designed layout of ``cells`` cells."""
    return int(cells) * HUMAN_BYTES_PER_CELL


def simulation_bytes(cells: int, goal_cells: int, agents: int) -> int:
    """One exact simulation: the distance tables of every goal cell, plus per-cell and
    per-agent state (a few hundred bytes each, generously)."""
    return int(goal_cells) * int(cells) * DISTANCE_BYTES + 256 * (int(cells) + int(agents))
