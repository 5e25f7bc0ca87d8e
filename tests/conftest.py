"""Shared fixtures. Tests run from the repository root (pyproject.toml sets pythonpath)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from omegaconf import OmegaConf

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO / OmegaConf.load(REPO / "configs" / "paths" / "default.yaml").data_dir  # ../shared/data


def require_data_dir(root: Path) -> Path:
    """The resolved folder; a missing one fails the test under CI (``CI`` set) and skips it elsewhere."""
    root = root.resolve()
    if not root.is_dir():
        message = f"real sample data not found at {root} (expected ../shared/data beside the repo)"
        if os.environ.get("CI"):
            pytest.fail(message)
        pytest.skip(message)
    return root


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The real sample data beside the repository (../shared/data)."""
    return require_data_dir(SHARED_DATA)
