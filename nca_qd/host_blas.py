"""One BLAS thread for host linear algebra on a search's path, so results do not depend on cores.

numpy's OpenBLAS splits some routines across as many threads as the process may use, and with
another thread count it returns other last bits: the eigenvectors of a CMA-ES covariance
(``eigh``) and large matrix-vector products both differ between one thread and two. A search
fed by them diverges, by a rounding at first and then by its whole trajectory, from the same
search on a machine with another number of cores or pinned to one (docs/benchmarks.md has the
measurement). Every host BLAS call whose result a search depends on runs inside
:func:`one_thread`; single-threaded, the largest of them (the ``eigh`` of a 1,730-dimensional
covariance, a few times per iteration at most) costs little more than two threads did.
"""

from __future__ import annotations

from typing import Any

_CONTROLLER: Any = None  # threadpoolctl controller, created on first use (it scans the loaded libraries)


def one_thread() -> Any:
    """A context manager that limits the process's BLAS libraries to one thread inside it."""
    global _CONTROLLER
    from threadpoolctl import ThreadpoolController

    _CONTROLLER = _CONTROLLER or ThreadpoolController()
    return _CONTROLLER.limit(limits=1, user_api="blas")
