"""The evaluation backends: the local process pool (order, failures, a dead worker, an interrupt)
and Dask (a cluster, an unreachable scheduler)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

from nca_qd.errors import NcaQdError
from nca_qd.scoring.backend import JobFailed, LocalBackend, make_backend, map_jobs


# ------------------------------------------------------------------------------- backends
def _square(x):
    return x * x


def _fail_on_odd(x):
    if x % 2:
        raise ValueError(f"odd {x}")
    return x


def _die_once(marker_dir, x):
    """Kills its worker process the first time it sees ``x == 3`` (a marker file remembers)."""
    marker = Path(marker_dir) / f"died_{x}"
    if x == 3 and not marker.exists():
        marker.write_text("x")
        os._exit(1)
    return x + 100


@pytest.mark.parametrize("workers", [0, 2])
def test_local_backend_keeps_order_and_reports_failures(workers):
    be = LocalBackend(workers, retries=1)
    try:
        assert be.map(_square, range(7)) == [x * x for x in range(7)]
        out = be.map(_fail_on_odd, range(4))
        assert out[0] == 0 and out[2] == 2
        assert isinstance(out[1], JobFailed) and "odd 1" in out[1].error
        assert map_jobs(be, _square, []) == []
        seen: dict[int, object] = {}
        out = map_jobs(be, _fail_on_odd, [(x,) for x in range(4)], on_result=seen.__setitem__)
        assert sorted(seen) == [0, 1, 2, 3]  # every final result once, failures included
        assert all(seen[i] == out[i] for i in (0, 2)) and isinstance(seen[1], JobFailed)
    finally:
        be.close()


def test_a_dead_worker_loses_no_returned_result_and_its_job_is_retried(tmp_path):
    be = LocalBackend(2, retries=2)
    try:
        out = be.map(_die_once, [str(tmp_path)] * 6, range(6))
    finally:
        be.close()
    assert out == [x + 100 for x in range(6)]
    assert (tmp_path / "died_3").exists()  # the worker did die
    (tmp_path / "again").mkdir()
    be = LocalBackend(2, retries=2)
    seen: list[tuple[int, int]] = []
    try:  # the retried job's result is reported once, when it finally arrives
        be.map(_die_once, [str(tmp_path / "again")] * 6, range(6), on_result=lambda i, r: seen.append((i, r)))
    finally:
        be.close()
    assert sorted(seen) == [(x, x + 100) for x in range(6)]


def test_an_interrupt_stops_the_pool_without_waiting_for_running_jobs():
    """SIGTERM / Ctrl-C during a batch of long jobs (minutes of RHCR): map raises at once and
    the workers are gone, instead of close() waiting for the jobs to finish."""
    import signal
    import threading

    from experiments.cli import _raise_interrupt

    be = LocalBackend(2, retries=0)
    be.map(_square, range(2))  # the workers are up
    workers = list(be._pool._processes.values())
    previous = signal.signal(signal.SIGTERM, _raise_interrupt)  # as the entry points do
    timer = threading.Timer(1.0, os.kill, (os.getpid(), signal.SIGTERM))
    timer.start()
    t0 = time.perf_counter()
    try:
        with pytest.raises(KeyboardInterrupt):
            be.map(time.sleep, [60.0] * 4)
    finally:
        signal.signal(signal.SIGTERM, previous)
        timer.cancel()
    be.close()
    assert time.perf_counter() - t0 < 15
    # A killed worker closes its pipes before the kernel has finished tearing it down, so
    # give the exit a moment; a worker still sleeping through its job would run for a minute.
    deadline = time.monotonic() + 5.0
    while any(_process_runs(p.pid) for p in workers) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert workers and not any(_process_runs(p.pid) for p in workers)


def _process_runs(pid: int) -> bool:
    """Whether the kernel still runs ``pid`` (gone or a zombie: it does not), read from /proc
    rather than from multiprocessing's bookkeeping."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):  # gone before, or while, /proc was read (ESRCH)
        return False
    return stat.rsplit(")", 1)[1].split()[0] not in ("Z", "X")


def test_dask_backend_runs_jobs_on_a_cluster():
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None
    ) as cluster:
        be = make_backend({"scheduler": cluster.scheduler_address})
        try:
            assert be.name == "dask"
            assert be.map(_square, range(5)) == [0, 1, 4, 9, 16]
            out = be.map(_fail_on_odd, [2, 3])
            assert out[0] == 2 and isinstance(out[1], JobFailed)
        finally:
            be.close()


def test_unreachable_scheduler_is_a_clear_error_or_falls_back():
    pytest.importorskip("distributed")
    cfg = {"scheduler": "tcp://127.0.0.1:9", "connect_timeout_s": 1}
    with pytest.raises(NcaQdError, match="cannot reach the Dask scheduler at tcp://127.0.0.1:9"):
        make_backend(cfg)
    be = make_backend({**cfg, "fallback_local": True, "workers": 0})
    assert be.name == "local"
