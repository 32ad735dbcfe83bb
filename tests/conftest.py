"""Shared fixtures: where problem files live."""

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture
def problems_dir() -> Path:
    """The shipped problem files."""
    return ROOT / "problems"


@pytest.fixture
def bad_dir() -> Path:
    """Deliberately invalid problem files used by the loader tests."""
    return ROOT / "tests" / "bad"
