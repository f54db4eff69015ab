"""Lazy access to OpenCV, the optional ``images`` extra."""

from __future__ import annotations

from types import ModuleType

from teamslam.errors import InputError

__all__ = ["require_cv2"]


def require_cv2() -> ModuleType:
    """Import and return ``cv2``; raise :class:`InputError` naming the extra when it is absent."""
    try:
        import cv2
    except ImportError:
        raise InputError(
            "images need OpenCV, which is not installed: pip install teamslam[images]"
        ) from None
    return cv2
