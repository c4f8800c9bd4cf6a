"""Shared fixtures: paths to the shared reference maps, a quiet progress bar."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from nca_qd.io import reference_maps_dir

SHARED_MAPS = reference_maps_dir()

os.environ.setdefault("JAX_PLATFORMS", "cpu")


@pytest.fixture(scope="session")
def maps_dir() -> Path:
    if not SHARED_MAPS.is_dir():
        pytest.skip(f"shared reference maps not found at {SHARED_MAPS}")
    return SHARED_MAPS
