"""Shared fixtures: paths to the shared reference maps, a quiet progress bar."""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile
from pathlib import Path

import pytest

from nca_qd.io import reference_maps_dir

SHARED_MAPS = reference_maps_dir()

os.environ.setdefault("JAX_PLATFORMS", "cpu")
# One persistent compilation cache for the whole session, inherited by the subprocesses that
# the end-to-end tests start: each jitted program (a QD step, the screen, the NCA) compiles
# once per `make test` instead of once per process or per Experiment (the slow tests spent
# most of their time recompiling). Set before any test module imports jax.
if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
    _cache = tempfile.mkdtemp(prefix="nca_qd_jax_cache_")
    atexit.register(shutil.rmtree, _cache, ignore_errors=True)
    os.environ["JAX_COMPILATION_CACHE_DIR"] = _cache
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")


# A short maze run (5 iterations of 8): written once per session, read by test_run's checks
# and by the notebook test (which would otherwise train its own).
TINY_MAZE = [
    "domain=maze",
    "qd.n_emitters=2",
    "qd.batch_size=4",
    "qd.n_evals=40",
    "qd.checkpoint_every=2",
    "domain.agent.episodes=3",
    "output.n_best=2",
    "qd.progress=false",
]


@pytest.fixture(scope="session")
def full_run(tmp_path_factory):
    """(run directory, Experiment, final state) of the TINY_MAZE run; tests only read it."""
    from experiments.cli import compose_config
    from nca_qd.experiment import Experiment

    run_dir = tmp_path_factory.mktemp("full")
    exp = Experiment(compose_config("run", TINY_MAZE), run_dir)
    state = exp.run()
    return run_dir, exp, state


@pytest.fixture(scope="session")
def maps_dir() -> Path:
    if not SHARED_MAPS.is_dir():
        pytest.skip(f"shared reference maps not found at {SHARED_MAPS}")
    return SHARED_MAPS


@pytest.fixture
def slow_clock(monkeypatch):
    """``slow_clock(module, ...)``: those modules' ``time.perf_counter`` advances 100 ms per
    reading (a loaded machine, to the code that reads it)."""
    import itertools
    import time

    ticks = itertools.count()
    start = time.perf_counter()

    class SlowClock:
        @staticmethod
        def perf_counter():
            return start + 0.1 * next(ticks)

    def slow(*modules):
        for module in modules:
            monkeypatch.setattr(module, "time", SlowClock)

    return slow


@pytest.fixture
def ctrl_c_raises():
    """Ctrl-C raises KeyboardInterrupt in the test, as in a fresh process (an earlier test's Dask
    client may have left SIGINT ignored); the handler before it is restored after."""
    import signal

    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, old)


@pytest.fixture(scope="module")
def maps(tmp_path_factory):
    """A maps folder holding the 9x14 human-designed warehouse, as ``$NCA_QD_MAPS`` for the
    module's tests (the tiny evaluations' human baseline)."""
    from evaluate_helpers import write_human_maps

    root = write_human_maps(tmp_path_factory.mktemp("maps"))
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("NCA_QD_MAPS", str(root))
        yield root
