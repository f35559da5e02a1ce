"""Shared fixtures: the real flight data beside the repository (skipped where absent)."""

from __future__ import annotations

from pathlib import Path

import pytest

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
FLIGHT_DATA = SHARED / "data" / "omnirotor-hover-flight"


@pytest.fixture
def flight_data() -> Path:
    """Folder of the authors' real hover data; skips the test when ../shared is not beside the repo."""
    if not (FLIGHT_DATA / "wrenchMap_reg1.mat").is_file():
        pytest.skip(f"real flight data not found at {FLIGHT_DATA} (../shared is not beside the checkout)")
    return FLIGHT_DATA
