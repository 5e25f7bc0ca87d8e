"""Shared fixtures. Tests run from the repository root (pyproject.toml sets pythonpath)."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The real sample data beside the repository; a hard failure under CI when it is missing."""
    root = SHARED_DATA.resolve()
    if not root.is_dir():
        message = f"real sample data not found at {root} (expected ../shared/data beside the repo)"
        if os.environ.get("CI"):
            pytest.fail(message)
        pytest.skip(message)
    return root
