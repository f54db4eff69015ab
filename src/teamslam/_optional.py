"""The optional extras: their modules imported on use, or a one-line error naming the extra.

A run over a dataset in one process needs none of them. Robots as processes need the
``network`` extra (Zenoh; cryptography for a secured team), ROS 2 bags, MCAP and live topics
the ``ros2`` extra (rosbags; xxhash for rmw_zenoh's ids), images the ``images`` extra (OpenCV),
studies on a Dask cluster the ``cluster`` extra (dask.distributed), a live view for Foxglove the
``foxglove`` extra (foxglove-sdk).
Every import of those modules goes through :func:`require`: the module, or
:class:`MissingExtra` — an :class:`~teamslam.errors.InputError`, so ``teamslam`` exits with
status 2 — whose text says what needs which extra and how to install it.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from teamslam.errors import InputError, InternalError

__all__ = ["EXTRAS", "MissingExtra", "require"]

#: The top-level modules each extra provides (``pyproject.toml`` installs their distributions).
EXTRAS = {
    "network": ("zenoh", "cryptography"),
    "ros2": ("rosbags", "xxhash"),
    "images": ("cv2",),
    "cluster": ("dask", "distributed"),
    "foxglove": ("foxglove",),
}


class MissingExtra(InputError):
    """A command needs an optional extra that is not installed; the text names it."""


def require(module: str, extra: str, what: str) -> ModuleType:
    """Import ``module`` (dotted names allowed) of the optional ``extra``; return it.

    Parameters
    ----------
    module
        The module to import, e.g. ``"zenoh"`` or ``"cryptography.x509"``.
    extra
        The extra whose package provides it (a key of :data:`EXTRAS`).
    what
        The feature that needs it, as the subject of "… needs the '<extra>' extra".

    Raises
    ------
    MissingExtra
        When the extra's top-level package cannot be imported.
    """
    top = module.partition(".")[0]
    if top not in EXTRAS.get(extra, ()):
        raise InternalError(f"{top} is not a module of an extra named {extra!r}")
    try:
        __import__(top)  # the builtin hook, so that an import blocked there counts as missing
    except ImportError as exc:
        missing = isinstance(exc, ModuleNotFoundError) and exc.name == top
        why = "" if missing else f" ({top} does not import: {exc})"
        raise MissingExtra(
            f"{what} needs the '{extra}' extra{why}: pip install 'teamslam[{extra}]'"
        ) from exc
    return importlib.import_module(module)
