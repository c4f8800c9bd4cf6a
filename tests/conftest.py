"""Shared fixtures: paths to the shared reference maps, a quiet progress bar."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_MAPS = REPO.parent / "shared" / "reference" / "maps"

os.environ.setdefault("JAX_PLATFORMS", "cpu")


@pytest.fixture(scope="session")
def maps_dir() -> Path:
    if not SHARED_MAPS.is_dir():
        pytest.skip(f"shared reference maps not found at {SHARED_MAPS}")
    return SHARED_MAPS
