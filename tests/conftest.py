"""Shared fixtures: where the real data lives (skipped with a reason when it is absent)."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

PROJECT_ROOT = Path(__file__).resolve().parents[1]


def shared_data_dir() -> Path:
    """``$TEAMSLAM_DATA`` or ``../shared/data`` next to the project root."""
    env = os.environ.get("TEAMSLAM_DATA")
    return Path(env) if env else (PROJECT_ROOT.parent / "shared" / "data")


def chromium_path() -> str | None:
    """The installed Chromium (or Chrome), or ``None``."""
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


@pytest.fixture
def chromium(tmp_path):
    """Headless Chromium as a function: ``chromium(*args, timeout=90)`` runs it with ``args``
    (``--dump-dom URL``, ``--screenshot=FILE URL``) in a fresh profile, every host but
    127.0.0.1 resolving to nothing (so any fetch from the network fails), and returns the
    ``CompletedProcess``.
    Skips with a reason when Chromium is not installed."""
    browser = chromium_path()
    if browser is None:
        pytest.skip("Chromium not installed (Debian: apt-get install chromium)")
    base = [
        browser,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--hide-scrollbars",
        "--no-first-run",
        f"--user-data-dir={tmp_path / 'chromium-profile'}",
        "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1",  # loopback only
        "--window-size=1280,1400",
    ]
    env = {**os.environ, "HOME": str(tmp_path)}

    def run(*args: str, timeout: float = 90) -> subprocess.CompletedProcess:
        return subprocess.run(
            [*base, *args], capture_output=True, text=True, timeout=timeout, env=env
        )

    return run


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


@pytest.fixture(scope="session")
def drifting_team():
    """Objects only, noisy odometry: every robot drifts, the shared objects can correct it."""
    from teamslam.sim import lissajous_team

    return lissajous_team(
        robots=3,
        steps=100,
        seed=2,
        odometry_translation_noise=0.05,
        odometry_rotation_noise=0.01,
        landmarks=10,
    )


@pytest.fixture(scope="session")
def drifting_runs(drifting_team):
    """Separate and consensus filters on ``drifting_team`` (window 10, objects only); several
    tests of two modules read them (run once per session)."""
    from teamslam.msckf import config_for, run_team

    cfg = config_for(drifting_team, {"filter.window": 10, "filter.use_geometric_features": False})
    return {
        name: run_team(drifting_team, cfg, consensus=c, progress=False)
        for name, c in (("separate", False), ("consensus", True))
    }


#: Modules whose tests listen on loopback ports (fixed, or derived from the process id), run
#: robot processes over Zenoh or make network namespaces: with pytest-xdist they run on one
#: worker, one after another, as in a serial run (two at once could pick the same port).
NETWORK_MODULES = frozenset(
    {
        "test_cluster",
        "test_driver",
        "test_foxglove",
        "test_live_robots",
        "test_netns",
        "test_rejoin",
        "test_ros2_input",
        "test_ros2_live",
        "test_runtime",
        "test_security",
    }
)

#: Modules that read a session fixture above with another module: scheduled with that one.
SHARED_SESSION_FIXTURES = {"test_msckf_centralised": "test_msckf"}


def work_unit(nodeid: str) -> str:
    """The unit of work of ``pytest -n N --dist loadscope`` that a test belongs to: its module
    (whose module fixtures, a dataset or a team run several tests read, are then built once),
    the module it shares a session fixture with, or ``network`` for :data:`NETWORK_MODULES`."""
    module = Path(nodeid.split("::", 1)[0]).stem
    module = SHARED_SESSION_FIXTURES.get(module, module)
    return "network" if module in NETWORK_MODULES else module


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "network: a test of NETWORK_MODULES (make test runs them after the rest, alone)"
    )


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark the tests of :data:`NETWORK_MODULES` ``network``: their robot processes are paced by
    timeouts and want the machine to themselves (``make test`` runs them after the others)."""
    for item in items:
        if item.path.stem in NETWORK_MODULES:
            item.add_marker(pytest.mark.network)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log):
    """``--dist loadscope`` (``make test``) with the scopes of :func:`work_unit`.

    pytest-xdist's own ``loadgroup`` (the ``xdist_group`` mark) rewrites a private node id
    field that pytest 9 no longer reads, so its groups are silently ignored; the scheduler
    hook is the documented way to choose the units of work."""
    if config.getvalue("dist") != "loadscope":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class ModuleScopeScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return work_unit(nodeid)

    return ModuleScopeScheduling(config, log)
