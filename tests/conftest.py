"""Shared fixtures."""

from __future__ import annotations

from pathlib import Path

import pytest

#: Real (read-only, third-party) data next to the repository; see each folder's SOURCE.txt.
REAL_DATA_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real"


@pytest.fixture(scope="session")
def real_data_dir() -> Path:
    """../shared/data/real; tests using it are skipped when it is absent."""
    if not REAL_DATA_DIR.is_dir():
        pytest.skip(f"real data not available at {REAL_DATA_DIR}")
    return REAL_DATA_DIR
