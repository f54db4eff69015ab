"""teamslam: multi-robot SLAM by filtering, with consensus and consistency measured.

Importing the package is cheap: its subpackages and the names below are loaded the first time
they are used (``teamslam.MsckfConfig`` imports :mod:`teamslam.msckf`, ``import teamslam.errors``
loads no numerical library).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from teamslam._lazy import attach
from teamslam._version import __version__

_SUBMODULES = (
    "cli",
    "datasets",
    "dvi",
    "ekf2d",
    "errors",
    "eval",
    "gaussian",
    "geometry",
    "graph",
    "linalg",
    "msckf",
    "ros2",
    "runtime",
    "sim",
    "testing",
    "textio",
)
_NAMES = {
    "MsckfConfig": "teamslam.msckf",
    "run_team": "teamslam.msckf",
    "run": "teamslam.api",
    "write_run": "teamslam.api",
    "load_run": "teamslam.api",
}

__all__ = [
    "MsckfConfig",
    "__version__",
    "datasets",
    "dvi",
    "ekf2d",
    "gaussian",
    "geometry",
    "graph",
    "load_run",
    "msckf",
    "run",
    "run_team",
    "sim",
    "write_run",
]

__getattr__, __dir__ = attach(__name__, _SUBMODULES, _NAMES)


if TYPE_CHECKING:  # what a type checker and an IDE see; nothing is imported at run time
    from teamslam import datasets, dvi, ekf2d, gaussian, geometry, graph, msckf, sim
    from teamslam.api import load_run, run, write_run
    from teamslam.msckf import MsckfConfig, run_team
