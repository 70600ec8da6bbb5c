"""Shared fixtures: the real terrain data of ../shared/data, skipped with a reason when absent."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

# The project root's sibling folder shared/data, unless APPROXTREE_DATA points elsewhere.
DEFAULT_DATA_DIR = Path(__file__).resolve().parents[2] / "shared" / "data"
DATA_DIR = Path(os.environ.get("APPROXTREE_DATA", DEFAULT_DATA_DIR))


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """The shared real-data folder; tests that need it skip when it is missing."""
    if not DATA_DIR.is_dir():
        pytest.skip(f"real terrain data not found at {DATA_DIR} (set APPROXTREE_DATA)")
    return DATA_DIR


def data_file(data_dir: Path, relative: str) -> Path:
    """A file of the shared data folder, skipping the test with a reason when it is absent."""
    path = data_dir / relative
    if not path.exists():
        pytest.skip(f"real data file {path} is absent")
    return path
