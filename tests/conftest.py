"""Shared fixtures: the real flight data beside the repository (skipped where absent)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from omnirotor.cli import use_numba_opt_default

# The tests compile at the omnirotor command's numba level (the command's own setter, before numba is imported:
# omnirotor.cli imports no numba), so the commands the tests start load the kernels the test process compiled, and
# the reverse. A NUMBA_OPT in the environment wins, as for the command (test_jit_cache checks the level in force).
NUMBA_OPT_PRESET = os.environ.get("NUMBA_OPT")
use_numba_opt_default()

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
FLIGHT_DATA = SHARED / "data" / "omnirotor-hover-flight"


@pytest.fixture
def flight_data() -> Path:
    """Folder of the authors' real hover data; skips the test when ../shared is not beside the repo."""
    if not (FLIGHT_DATA / "wrenchMap_reg1.mat").is_file():
        pytest.skip(f"real flight data not found at {FLIGHT_DATA} (../shared is not beside the checkout)")
    return FLIGHT_DATA
