"""teamslam: multi-robot SLAM by filtering, with consensus and consistency measured."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("teamslam")
except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
    __version__ = "0+unknown"

from teamslam import dvi, gaussian, geometry, graph

__all__ = ["__version__", "dvi", "gaussian", "geometry", "graph"]
