"""Fiducial markers (ArUco / AprilTag families through ``cv2.aruco``) as stereo objects.

A marker's id is its object id, global across robots (tags are physical objects). The
measured point is the marker's centre, the intersection of the diagonals of its four refined
corners — under perspective the exact image of the square's centre. Left and right detections
are paired by id; a pair is kept when the two centres lie on the same row (rectified images,
within ``marker_row_share``) at a disparity inside the depth range.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from teamslam.frontend._cv import require_cv2
from teamslam.frontend.config import FrontendConfig

__all__ = ["MarkerDetector", "Markers", "diagonal_centre"]


@dataclass(frozen=True)
class Markers:
    """Markers found in one image: ``ids (M,)``, ``corners (M, 4, 2)``, ``centres (M, 2)``."""

    ids: np.ndarray
    corners: np.ndarray
    centres: np.ndarray


def diagonal_centre(corners: np.ndarray) -> np.ndarray:
    """``(..., 4, 2)`` quadrilateral corners → ``(..., 2)`` intersection of its diagonals."""
    c = np.asarray(corners, dtype=float)
    p, q = c[..., 0, :], c[..., 2, :]
    s, t = c[..., 1, :], c[..., 3, :]
    d1, d2 = q - p, t - s
    den = d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0]
    rel = s - p
    lam = (rel[..., 0] * d2[..., 1] - rel[..., 1] * d2[..., 0]) / den
    return p + lam[..., None] * d1


class MarkerDetector:
    """ArUco / AprilTag detection with sub-pixel corners.

    Parameters
    ----------
    config
        Front-end settings (``marker_dictionary``).
    """

    def __init__(self, config: FrontendConfig | None = None) -> None:
        cv2 = require_cv2()
        self.config = config or FrontendConfig()
        name = self.config.opencv_dictionary()
        self._detector = None
        if name is not None:
            dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))
            params = cv2.aruco.DetectorParameters()
            params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
            params.relativeCornerRefinmentWinSize = self.config.marker_corner_window
            params.minMarkerPerimeterRate = self.config.marker_min_perimeter_share
            lo, hi = params.adaptiveThreshWinSizeMin, params.adaptiveThreshWinSizeMax
            passes = self.config.marker_threshold_passes
            params.adaptiveThreshWinSizeStep = (
                hi - lo + 1 if passes == 1 else max(1, -(-(hi - lo) // (passes - 1)))
            )
            self._detector = cv2.aruco.ArucoDetector(dictionary, params)

    def detect(self, image: np.ndarray) -> Markers:
        """Markers in one grey image (ids unique: a repeated id is dropped)."""
        if self._detector is None:
            return Markers(np.zeros(0, np.int64), np.zeros((0, 4, 2)), np.zeros((0, 2)))
        corners, ids, _ = self._detector.detectMarkers(image)
        if ids is None or len(ids) == 0:
            return Markers(np.zeros(0, np.int64), np.zeros((0, 4, 2)), np.zeros((0, 2)))
        ids = ids.ravel().astype(np.int64)
        corners = np.stack([c.reshape(4, 2) for c in corners]).astype(float)
        unique, counts = np.unique(ids, return_counts=True)
        keep = np.isin(ids, unique[counts == 1])
        ids, corners = ids[keep], corners[keep]
        order = np.argsort(ids)
        ids, corners = ids[order], corners[order]
        return Markers(ids, corners, diagonal_centre(corners))

    def detect_stereo(
        self,
        left: np.ndarray,
        right: np.ndarray,
        disparity_range: tuple[float, float],
        row_tolerance: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Markers seen in both images of a rectified pair: ``(ids (M,), z (M, 4))``."""
        a = self.detect(left)
        if a.ids.size == 0:
            return np.zeros(0, np.int64), np.zeros((0, 4))
        # the right image only where the left markers can appear: their rows, shifted left by
        # up to the largest disparity (plus a margin of a marker's size)
        h, w = right.shape
        pad = float(np.ptp(a.corners, axis=1).max()) + row_tolerance
        top = max(0, int(a.corners[..., 1].min() - pad))
        bottom = min(h, int(np.ceil(a.corners[..., 1].max() + pad)) + 1)
        first = max(0, int(a.corners[..., 0].min() - disparity_range[1] - pad))
        last = min(w, int(np.ceil(a.corners[..., 0].max() + pad)) + 1)
        b = self.detect(np.ascontiguousarray(right[top:bottom, first:last]))
        shift = np.array([first, top], dtype=float)
        b = Markers(b.ids, b.corners + shift, b.centres + shift)
        ids, ia, ib = np.intersect1d(a.ids, b.ids, return_indices=True)
        z = np.concatenate([a.centres[ia], b.centres[ib]], axis=1).reshape(-1, 4)
        disparity = z[:, 0] - z[:, 2]
        ok = (
            (np.abs(z[:, 1] - z[:, 3]) <= row_tolerance)
            & (disparity >= disparity_range[0])
            & (disparity <= disparity_range[1])
            & (disparity > 0)
        )
        return ids[ok], z[ok]
