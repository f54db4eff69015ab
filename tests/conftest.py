"""Shared fixtures: where the real data lives (skipped with a reason when it is absent)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

PROJECT_ROOT = Path(__file__).resolve().parents[1]


def shared_data_dir() -> Path:
    """``$TEAMSLAM_DATA`` or ``../shared/data`` next to the project root."""
    env = os.environ.get("TEAMSLAM_DATA")
    return Path(env) if env else (PROJECT_ROOT.parent / "shared" / "data")


@pytest.fixture(scope="session")
def shared_data() -> Path:
    path = shared_data_dir()
    if not path.is_dir():
        pytest.skip(f"real data not found at {path} (set TEAMSLAM_DATA to its location)")
    return path


@pytest.fixture(scope="session")
def kitti00_dir(shared_data: Path) -> Path:
    path = shared_data / "distributed-msckf" / "kitti00"
    if not path.is_dir():
        pytest.skip(f"KITTI 00 reference data not found at {path}")
    return path
