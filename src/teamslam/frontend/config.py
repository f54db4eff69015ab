"""Every setting of the stereo front-end, in units that do not depend on the image size.

Lengths in the image are given as shares of the image diagonal (``*_share``) and turned into
pixels for a given image by :meth:`FrontendConfig.pixels`; depths are in metres and become a
disparity range through the camera's ``fx · b``. Nothing is tuned to one resolution.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from teamslam.errors import InputError

__all__ = ["FrontendConfig", "PixelSettings"]

_DICTIONARIES = {
    "4x4_50": "DICT_4X4_50",
    "4x4_100": "DICT_4X4_100",
    "4x4_250": "DICT_4X4_250",
    "4x4_1000": "DICT_4X4_1000",
    "5x5_250": "DICT_5X5_250",
    "6x6_250": "DICT_6X6_250",
    "7x7_250": "DICT_7X7_250",
    "aruco_original": "DICT_ARUCO_ORIGINAL",
    "apriltag_16h5": "DICT_APRILTAG_16h5",
    "apriltag_25h9": "DICT_APRILTAG_25h9",
    "apriltag_36h10": "DICT_APRILTAG_36h10",
    "apriltag_36h11": "DICT_APRILTAG_36h11",
}


@dataclass(frozen=True)
class FrontendConfig:
    """Settings of tracking, stereo matching, markers and visual odometry.

    Attributes
    ----------
    max_features
        Most feature tracks kept at once.
    feature_spacing_share
        Least distance between two features (and the empty radius around a track in which no
        new corner is taken), share of the image diagonal.
    corner_quality
        ``qualityLevel`` of Shi–Tomasi corners: a corner's score relative to the best one.
    corner_block_share
        Corner detection window, share of the diagonal.
    lk_window_share, lk_levels
        Lucas–Kanade window (share of the diagonal) and pyramid levels.
    forward_backward_share
        Largest forward–backward tracking error kept, share of the diagonal.
    affine_refinement, affine_iterations, template_ncc_min, refine_track_share
        Align each track to its first appearance (affine warp with gain and offset, that many
        Gauss–Newton steps); end a track whose aligned patch correlates below
        ``template_ncc_min`` with its template, or moves more than ``refine_track_share`` of
        the diagonal from the frame-to-frame track.
    min_depth, max_depth
        Depth range (metres) of stereo matches: the disparity search range is
        ``[fx·b / max_depth, fx·b / min_depth]``.
    ncc_window_share
        Stereo matching window (NCC), share of the diagonal.
    ncc_min
        Least normalised cross-correlation of a stereo match.
    uniqueness
        A match is ambiguous (rejected) when the best NCC away from the peak reaches this
        share of the peak's.
    left_right_share
        Largest difference between a left→right match and the right→left match back, share of
        the diagonal (the left–right check, which rejects occlusions).
    refine_share
        Largest change of the disparity when refined by Lucas–Kanade along the row, and
        largest row offset of the refined match, share of the diagonal (the outlier gate).
    marker_dictionary
        ArUco / AprilTag family of the fiducial markers (``None``: no markers).
    marker_row_share
        Largest row difference of a marker's centre between left and right (rectified).
    vo_reprojection_share, vo_min_inliers
        RANSAC threshold of stereo visual odometry (share of the diagonal) and the least
        number of inliers for a motion to be accepted.
    """

    max_features: int = 400
    feature_spacing_share: float = 0.012
    corner_quality: float = 0.005
    corner_block_share: float = 0.006
    lk_window_share: float = 0.026
    lk_levels: int = 3
    forward_backward_share: float = 0.0006
    affine_refinement: bool = True
    affine_iterations: int = 3
    template_ncc_min: float = 0.93
    refine_track_share: float = 0.0025
    min_depth: float = 0.5
    max_depth: float = 100.0
    ncc_window_share: float = 0.014
    ncc_min: float = 0.7
    uniqueness: float = 0.97
    left_right_share: float = 0.0013
    refine_share: float = 0.0013
    marker_dictionary: str | None = "4x4_250"
    marker_row_share: float = 0.003
    vo_reprojection_share: float = 0.0013
    vo_min_inliers: int = 12

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, float) and not (np.isfinite(value) and value > 0):
                raise InputError(f"front-end setting {f.name} must be a positive number")
        if self.max_features < 1 or self.lk_levels < 0 or self.vo_min_inliers < 4:
            raise InputError("max_features ≥ 1, lk_levels ≥ 0 and vo_min_inliers ≥ 4 needed")
        if not self.min_depth < self.max_depth:
            raise InputError("front-end: min_depth must be below max_depth")
        if self.affine_iterations < 1 or self.template_ncc_min >= 1:
            raise InputError("affine_iterations ≥ 1 and template_ncc_min < 1 needed")
        if self.corner_quality >= 1 or self.ncc_min >= 1 or self.uniqueness > 1:
            raise InputError("corner_quality and ncc_min must be < 1, uniqueness ≤ 1")
        if self.marker_dictionary is not None and self.marker_dictionary not in _DICTIONARIES:
            raise InputError(
                f"marker_dictionary {self.marker_dictionary!r} unknown; use one of "
                + ", ".join(_DICTIONARIES)
            )

    def pixels(self, image_size: tuple[int, int]) -> PixelSettings:
        """The settings in pixels for images of ``(width, height)``."""
        diag = float(np.hypot(*image_size))

        def odd(share: float, least: int) -> int:
            n = max(least, round(share * diag))
            return n if n % 2 else n + 1

        return PixelSettings(
            spacing=max(2.0, self.feature_spacing_share * diag),
            corner_block=odd(self.corner_block_share, 3),
            lk_window=odd(self.lk_window_share, 9),
            forward_backward=self.forward_backward_share * diag,
            refine_track=self.refine_track_share * diag,
            ncc_half=odd(self.ncc_window_share, 9) // 2,
            left_right=self.left_right_share * diag,
            refine=self.refine_share * diag,
            marker_row=self.marker_row_share * diag,
            vo_reprojection=self.vo_reprojection_share * diag,
        )

    def disparity_range(self, fx_baseline: float) -> tuple[float, float]:
        """``(least, largest)`` disparity in pixels for a camera with ``fx · b``."""
        return fx_baseline / self.max_depth, fx_baseline / self.min_depth

    def opencv_dictionary(self) -> str | None:
        """The OpenCV constant name of :attr:`marker_dictionary`."""
        return None if self.marker_dictionary is None else _DICTIONARIES[self.marker_dictionary]


@dataclass(frozen=True)
class PixelSettings:
    """:class:`FrontendConfig` lengths in pixels for one image size."""

    spacing: float
    corner_block: int
    lk_window: int
    forward_backward: float
    refine_track: float
    ncc_half: int
    left_right: float
    refine: float
    marker_row: float
    vo_reprojection: float
