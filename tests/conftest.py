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


#: Modules whose tests listen on loopback ports (fixed, or derived from the process id), run
#: robot processes over Zenoh or make network namespaces. With ``pytest -n N`` (pytest-xdist,
#: ``--dist loadgroup``, as ``make test`` runs) they all go to one worker, one after another,
#: as in a serial run: two of them at once could pick the same port.
NETWORK_MODULES = frozenset(
    {"test_driver", "test_netns", "test_rejoin", "test_ros2_live", "test_runtime", "test_security"}
)


def pytest_configure(config: pytest.Config) -> None:
    # pytest-xdist registers this mark itself; without it the mark is inert but known
    config.addinivalue_line("markers", "xdist_group(name): run on one pytest-xdist worker")


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Name each test's ``xdist_group``: its module, so that a module's fixtures (a dataset,
    a team run several tests read) are built once, on one worker; the network modules share
    one group. Without pytest-xdist the mark is inert."""
    for item in items:
        module = item.path.stem
        item.add_marker(pytest.mark.xdist_group("network" if module in NETWORK_MODULES else module))
