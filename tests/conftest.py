"""Shared fixtures and paths for the test suite."""

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
# Real data lives beside the repository (../shared/data); tests skip cleanly without it.
SHARED_DATA = REPO.parent / "shared" / "data"


@pytest.fixture
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data is not present")
    return SHARED_DATA
