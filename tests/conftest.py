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


@pytest.fixture(scope="session")
def maps_dir() -> Path:
    if not SHARED_MAPS.is_dir():
        pytest.skip(f"shared reference maps not found at {SHARED_MAPS}")
    return SHARED_MAPS
