"""teamslam: multi-robot SLAM by filtering, with consensus and consistency measured."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("teamslam")
except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
    __version__ = "0+unknown"

from teamslam import datasets, dvi, ekf2d, gaussian, geometry, graph, msckf, sim
from teamslam.msckf import MsckfConfig, run_team

__all__ = [
    "MsckfConfig",
    "__version__",
    "datasets",
    "dvi",
    "ekf2d",
    "gaussian",
    "geometry",
    "graph",
    "msckf",
    "run_team",
    "sim",
]
