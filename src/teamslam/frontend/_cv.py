"""OpenCV, the optional ``images`` extra, imported on use (:func:`teamslam._optional.require`)."""

from __future__ import annotations

from types import ModuleType

from teamslam._optional import require

__all__ = ["require_cv2"]


def require_cv2(what: str = "the image front-end") -> ModuleType:
    """Import and return ``cv2``; :class:`~teamslam._optional.MissingExtra` (an
    :class:`~teamslam.errors.InputError`) naming the ``images`` extra when it is absent."""
    return require("cv2", "images", what)
