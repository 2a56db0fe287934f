"""Shared test fixtures: where the shared test data lives, and common hypothesis settings."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import settings

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"

settings.register_profile("default", deadline=None, max_examples=100)
settings.load_profile("default")


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """../shared/data, or skip with the reason when this checkout has no ../shared beside it."""
    if not (SHARED_DATA / "README.md").is_file():
        pytest.skip(f"test data not found at {SHARED_DATA} (clone with ../shared beside the repo)")
    return SHARED_DATA
