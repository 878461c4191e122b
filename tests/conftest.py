"""Shared fixtures and paths for the test suite."""

import os
import tempfile
from pathlib import Path

import pytest
from hypothesis import settings

# Property tests draw their examples from a fixed seed, so a run (and CI) is reproducible;
# `HYPOTHESIS_PROFILE=explore pytest` draws new random examples on every run to hunt
# for counterexamples, which then belong in an @example.
settings.register_profile("repeatable", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "repeatable"))

# Caches the code keeps across runs (PF-LLR's calibrated thresholds) go to a folder of
# this test session, never the user's ~/.cache: every run starts cold.
os.environ.setdefault("RAIM_STUDIO_CACHE_DIR", tempfile.mkdtemp(prefix="raim-test-cache-"))

REPO = Path(__file__).resolve().parents[1]
# Real data lives beside the repository (../shared/data); tests skip cleanly without it.
SHARED_DATA = REPO.parent / "shared" / "data"


@pytest.fixture
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data is not present")
    return SHARED_DATA


@pytest.fixture(scope="module")
def dash():
    """An in-process dashboard server on a free port, one per test module (the dashboard
    tests drive its sessions without a browser)."""
    from app.server import Dashboard

    d = Dashboard(port=0, verbose=False)
    yield d
    d.stop()
