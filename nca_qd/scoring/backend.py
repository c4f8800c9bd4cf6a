"""Where the pipeline's unit jobs run: one interface, a local process pool or a Dask cluster.

``make_backend(cfg)`` reads the ``eval`` config block:

- ``scheduler: null`` (default): :class:`LocalBackend`, a pool of ``workers`` processes
  (default: the CPUs available). Processes, not threads: HiGHS holds the GIL during a solve.
  The pool uses ``spawn`` so workers never inherit the parent's JAX threads. ``workers: 0``
  runs every job inline (debugging, tiny tests).
- ``scheduler: tcp://host:8786``: :class:`DaskBackend`, jobs go to that Dask distributed
  cluster, so a user who outgrows one machine adds workers, not code. An unreachable
  scheduler is an error, unless ``fallback_local: true``, which warns and runs locally.

Both return results in input order; ``map(..., on_result=f)`` also calls ``f(i, result)`` in
the calling thread as each job's final result arrives (e.g. to record it before the rest end).
A worker that dies loses nothing already returned: the local pool is rebuilt and only the
unfinished jobs are resubmitted; Dask reschedules the jobs of a lost worker itself. A job that
fails ``retries + 1`` times comes back as a :class:`JobFailed` in its slot, so the caller
records it and goes on.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from multiprocessing.connection import wait as wait_for_sentinels
from typing import Any

from nca_qd.errors import NcaQdError, require_bool

log = logging.getLogger(__name__)

OnResult = Callable[[int, Any], None]


@dataclass
class JobFailed:
    """Stands in the result list for a job that failed every attempt."""

    error: str


def available_cpus() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def _still_running(procs: list, timeout: float) -> list:
    """The processes of ``procs`` whose exit sentinel is not ready after ``timeout`` seconds."""
    pending = {proc.sentinel: proc for proc in procs}
    deadline = time.monotonic() + timeout
    while pending:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            break
        for sentinel in wait_for_sentinels(list(pending), remaining):
            pending.pop(sentinel)
    return list(pending.values())


class LocalBackend:
    """A process pool on this machine (``workers=0``: inline, in this process)."""

    name = "local"

    def __init__(self, workers: int | None = None, retries: int = 2):
        self.workers = available_cpus() if workers is None else int(workers)
        self.retries = int(retries)
        self._pool: ProcessPoolExecutor | None = None
        self._aborted = False  # set by abort(), e.g. from the main thread while map() runs in another

    def _executor(self) -> ProcessPoolExecutor:
        if self._pool is None:
            self._pool = ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"))
        return self._pool

    def map(self, fn: Callable, *args: Sequence[Any], on_result: OnResult | None = None) -> list[Any]:
        jobs = list(zip(*args))
        if self.workers == 0:
            inline = []
            for i, job in enumerate(jobs):
                inline.append(self._inline(fn, job))
                if on_result is not None:
                    on_result(i, inline[-1])
            return inline
        results: list[Any] = [None] * len(jobs)
        attempts = [0] * len(jobs)
        todo = list(range(len(jobs)))
        self._aborted = False
        while todo:
            pool = self._executor()
            futures = {pool.submit(fn, *jobs[i]): i for i in todo}
            todo = []
            broken = False
            try:
                for fut in as_completed(futures):
                    if self._aborted:  # aborted from another thread: no job is resubmitted
                        raise KeyboardInterrupt
                    i = futures[fut]
                    try:
                        results[i] = fut.result()
                    except BrokenProcessPool as exc:  # a worker died: this job is retried
                        broken = True
                        attempts[i] += 1
                        if attempts[i] > self.retries:
                            results[i] = JobFailed(f"worker died {attempts[i]} times: {exc}")
                        else:
                            todo.append(i)
                            continue
                    except Exception as exc:  # noqa: BLE001 - a job's own error: retried, then kept
                        attempts[i] += 1
                        if attempts[i] > self.retries:
                            results[i] = JobFailed(f"{type(exc).__name__}: {exc}")
                        else:
                            todo.append(i)
                            continue
                    if on_result is not None:
                        on_result(i, results[i])
            except KeyboardInterrupt:  # Ctrl-C or SIGTERM: stop now, not after the running jobs
                self.abort()
                raise
            if broken:
                log.warning("a worker process died; %d job(s) resubmitted to a new pool", len(todo))
                self._pool.shutdown(wait=False, cancel_futures=True)
                self._pool = None
        return results

    def _inline(self, fn: Callable, job: tuple) -> Any:
        for attempt in range(self.retries + 1):
            try:
                return fn(*job)
            except Exception as exc:  # noqa: BLE001
                if attempt == self.retries:
                    return JobFailed(f"{type(exc).__name__}: {exc}")
        return None  # pragma: no cover

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def abort(self) -> None:
        """Drop the pool at once: queued jobs are cancelled and running workers terminated
        (their jobs' results would be discarded anyway; an interrupted run resumes from its
        checkpoint). Without this, SIGTERM would wait for minutes-long RHCR runs to finish.
        Called from another thread while :meth:`map` runs, it makes that map raise
        KeyboardInterrupt instead of resubmitting the killed jobs."""
        self._aborted = True
        if self._pool is None:
            return
        pool, self._pool = self._pool, None
        workers = list(getattr(pool, "_processes", {}).values())  # no public API before 3.14
        pool.shutdown(wait=False, cancel_futures=True)
        for proc in workers:
            if proc.exitcode is None:
                proc.terminate()
        # Wait on the exit sentinels, not proc.join(): the pool's own manager thread reaps
        # these workers too, and two threads in waitpid() on one pid leave the loser unaware
        # that its process ended (seen on a loaded 2-core CI machine).
        left = _still_running(workers, timeout=5.0)
        for proc in left:  # one that outlived SIGTERM
            proc.kill()
        _still_running(left, timeout=5.0)

    def describe(self) -> str:
        return "inline" if self.workers == 0 else f"local process pool ({self.workers} workers)"


class DaskBackend:
    """Jobs on a Dask distributed cluster (``pip install 'nca-qd[cluster]'``)."""

    name = "dask"

    def __init__(self, scheduler: str, retries: int = 2, connect_timeout_s: float = 10.0):
        try:
            from distributed import Client
        except ImportError:
            raise NcaQdError(
                "eval.scheduler needs Dask distributed: pip install 'nca-qd[cluster]' (or dask distributed)"
            ) from None
        self.scheduler, self.retries = scheduler, int(retries)
        self._futures: list[Any] = []
        self._aborted = False
        try:
            self.client = Client(scheduler, timeout=f"{connect_timeout_s}s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise NcaQdError(
                f"cannot reach the Dask scheduler at {scheduler}: "
                f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
            ) from None

    def map(self, fn: Callable, *args: Sequence[Any], on_result: OnResult | None = None) -> list[Any]:
        from distributed import as_completed as dask_completed

        jobs = list(zip(*args))
        if not jobs:
            return []
        self._aborted = False
        futures = [self.client.submit(fn, *job, pure=False, retries=self.retries) for job in jobs]
        self._futures = futures
        index = {fut.key: i for i, fut in enumerate(futures)}
        results: list[Any] = [None] * len(jobs)
        for fut in dask_completed(futures):
            if self._aborted:
                raise KeyboardInterrupt
            i = index[fut.key]
            try:
                results[i] = fut.result()
            except Exception as exc:  # noqa: BLE001 - failed every retry, or its worker kept dying
                results[i] = JobFailed(f"{type(exc).__name__}: {exc}")
            if on_result is not None:
                on_result(i, results[i])
        return results

    def abort(self) -> None:
        """Cancel the jobs of the running :meth:`map` (called from another thread, it makes
        that map raise KeyboardInterrupt)."""
        self._aborted = True
        if self._futures:
            self.client.cancel(self._futures)

    def close(self) -> None:
        self.client.close()

    def describe(self) -> str:
        n = len(self.client.scheduler_info().get("workers", {}))
        return f"Dask cluster at {self.scheduler} ({n} workers)"


Backend = LocalBackend | DaskBackend


def make_backend(cfg: Mapping[str, Any] | None) -> Backend:
    """The backend an ``eval`` config block asks for (see the module docstring)."""
    cfg = dict(cfg or {})
    retries = int(cfg.get("retries", 2))
    scheduler = cfg.get("scheduler")
    if scheduler:
        try:
            return DaskBackend(str(scheduler), retries, float(cfg.get("connect_timeout_s", 10)))
        except NcaQdError as exc:
            if not require_bool("eval.fallback_local", cfg.get("fallback_local", False)):
                raise
            log.warning("%s; running locally (eval.fallback_local=true)", exc)
    workers = cfg.get("workers")
    if workers is not None and (isinstance(workers, bool) or int(workers) < 0):
        raise NcaQdError(f"eval.workers must be an integer >= 0, got {workers!r}")
    return LocalBackend(None if workers is None else int(workers), retries)


def map_jobs(
    backend: Backend, fn: Callable, jobs: Iterable[tuple], on_result: OnResult | None = None
) -> list[Any]:
    """``backend.map`` over a list of argument tuples (``on_result``: see the module doc)."""
    jobs = list(jobs)
    if not jobs:
        return []
    return backend.map(fn, *zip(*jobs), on_result=on_result)
