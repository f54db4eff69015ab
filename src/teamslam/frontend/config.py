"""Every setting of the stereo front-end, in units that do not depend on the image size.

Lengths in the image are given as shares of the image diagonal (``*_share``) and turned into
pixels for a given image by :meth:`FrontendConfig.pixels`; depths are in metres and become a
disparity range through the camera's ``fx · b``. Nothing is tuned to one resolution.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from teamslam.errors import InputError

__all__ = ["FrontendConfig", "PixelSettings", "frontend_table", "resolve_frontend"]

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

_ZERO_MEANS_OFF = ("max_track_warp",)


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
    detection_interval
        New corners are looked for in every this many frames (1: every frame; always in the
        first); in the frames between, the tracks that ended are not replaced. Detection and
        the stereo search of the new corners are a frame's cost that does not follow a track.
    max_track_length
        Most frames a track is followed (0: no limit); a longer one ends and its corner may
        start a new track with a fresh template and id. Aligned to its first appearance, a
        track's error grows with its age as the view changes, and the error is the same from
        frame to frame.
    max_track_warp
        Largest change of a track's appearance since its first sighting, unit-free: the
        largest ``|log σ|`` of the singular values ``σ`` of the track's affine warp (0.1 is
        a patch grown, shrunk or sheared by about 10 %; 0: no limit). A track past it ends,
        and its corner may start a new track with a fresh template and id. Unlike
        ``max_track_length`` it does not depend on the frame rate: a track ends when the
        view of its patch has changed, not after a number of frames.
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
    stereo_from_guess
        Match a tracked point whose disparity in the previous frame is known by pyramidal
        Lucas–Kanade from that disparity into the right image and back (the left–right
        check), instead of searching the row by NCC. New points are always searched.
    stereo_affine_iterations
        Gauss–Newton steps aligning each left patch in the right image with an affine warp,
        gain and offset after the Lucas–Kanade refinement (0: translation-only Lucas–Kanade).
        On slanted surfaces the two cameras see a patch foreshortened differently, and a
        translation-only match is biased by the same amount frame after frame along a track
        (set 0 when time matters more).
    box_patch_samples
        A detector's box is searched for in the right image by its patch at the level of an
        image pyramid (2 × 2 means per level) where it has at most this many samples; the peak
        is then refined down the pyramid to full resolution (or, for a box of more than 16
        times as many pixels, to a patch of 16 times as many samples): the cost of a box does
        not grow with its size.
    box_ncc_min
        Least normalised cross-correlation of a box's patch with its right-image match.
    box_uniqueness
        A box's match is ambiguous (the box stays monocular) when the best correlation three
        samples or more away from the peak (samples of the coarse search) reaches this share of
        the peak's.
    box_row_overlap
        Least overlap of the row spans of a left and a right box (intersection over union) for
        the detector's right-image box to be paired with the left one.
    box_width_probability
        A left and a right box of one object show the same width unless one image sees it cut
        (by an occluder or the border), and then their centres' difference is not its
        disparity: a pair is kept when ``log(w_r / w_l)`` lies within this probability of its
        distribution, learned from the pairs seen so far (median, 1.4826 × median absolute
        deviation); the others' right centres are searched by the patch.
    marker_dictionary
        ArUco / AprilTag family of the fiducial markers (``None``: no markers).
    marker_row_share
        Largest row difference of a marker's centre between left and right (rectified).
    marker_min_perimeter_share
        Smallest marker perimeter looked for, share of the larger image side (OpenCV's
        ``minMarkerPerimeterRate``; 0.08 is a side of 13 px in a 640-px image: smaller
        markers are not measured to a pixel anyway, and fewer candidate contours are
        faster).
    marker_threshold_passes
        Adaptive-threshold window sizes tried by the marker detector (OpenCV's 3 to 23 px
        in this many steps; each pass is one thresholding and contour search of the image).
    marker_corner_window
        Sub-pixel corner refinement window of a marker, as a share of the marker's module
        (one of its black or white squares; OpenCV's ``relativeCornerRefinmentWinSize``,
        whose window is at most 5 px). At OpenCV's own 0.3, a marker of 26 px side (4×4
        bits plus the border: a module of 4.3 px) is refined in a window of about one
        pixel.
    vo_reprojection_share, vo_min_inliers
        RANSAC threshold of stereo visual odometry (share of the diagonal) and the least
        number of inliers for a motion to be accepted.
    """

    max_features: int = 400
    feature_spacing_share: float = 0.012
    corner_quality: float = 0.005
    corner_block_share: float = 0.006
    lk_window_share: float = 0.026
    lk_levels: int = 2
    forward_backward_share: float = 0.0006
    affine_refinement: bool = True
    affine_iterations: int = 2
    template_ncc_min: float = 0.93
    refine_track_share: float = 0.0025
    detection_interval: int = 1
    max_track_length: int = 0
    max_track_warp: float = 0.2
    min_depth: float = 0.5
    max_depth: float = 100.0
    ncc_window_share: float = 0.014
    ncc_min: float = 0.7
    uniqueness: float = 0.97
    left_right_share: float = 0.0013
    refine_share: float = 0.0013
    stereo_from_guess: bool = True
    stereo_affine_iterations: int = 2
    box_patch_samples: int = 400
    box_ncc_min: float = 0.7
    box_uniqueness: float = 0.95
    box_row_overlap: float = 0.5
    box_width_probability: float = 0.99
    marker_dictionary: str | None = "4x4_250"
    marker_row_share: float = 0.003
    marker_min_perimeter_share: float = 0.08
    marker_threshold_passes: int = 2
    marker_corner_window: float = 0.4
    vo_reprojection_share: float = 0.0013
    vo_min_inliers: int = 12

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in _ZERO_MEANS_OFF:
                if not (np.isfinite(value) and value >= 0):
                    raise InputError(f"front-end setting {f.name} must be 0 (off) or positive")
            elif isinstance(value, float) and not (np.isfinite(value) and value > 0):
                raise InputError(f"front-end setting {f.name} must be a positive number")
        if self.marker_min_perimeter_share >= 4 or self.marker_threshold_passes < 1:
            raise InputError(
                "marker_min_perimeter_share < 4 and marker_threshold_passes ≥ 1 needed"
            )
        if self.detection_interval < 1:
            raise InputError("detection_interval must be at least 1 (every frame)")
        if self.max_track_length < 0 or self.max_track_length == 1:
            raise InputError("max_track_length must be 0 (no limit) or at least 2 frames")
        if self.max_features < 1 or self.lk_levels < 0 or self.vo_min_inliers < 4:
            raise InputError("max_features ≥ 1, lk_levels ≥ 0 and vo_min_inliers ≥ 4 needed")
        if not self.min_depth < self.max_depth:
            raise InputError("front-end: min_depth must be below max_depth")
        if self.stereo_affine_iterations < 0:
            raise InputError("stereo_affine_iterations ≥ 0 needed")
        if self.affine_iterations < 1 or self.template_ncc_min >= 1:
            raise InputError("affine_iterations ≥ 1 and template_ncc_min < 1 needed")
        if self.corner_quality >= 1 or self.ncc_min >= 1 or self.uniqueness > 1:
            raise InputError("corner_quality and ncc_min must be < 1, uniqueness ≤ 1")
        if self.box_ncc_min >= 1 or self.box_uniqueness > 1 or self.box_row_overlap > 1:
            raise InputError("box_ncc_min < 1, box_uniqueness ≤ 1 and box_row_overlap ≤ 1 needed")
        if self.box_width_probability >= 1:
            raise InputError("box_width_probability must be below 1")
        if self.box_patch_samples < 9:
            raise InputError("box_patch_samples ≥ 9 needed (a patch of 3 × 3 samples)")
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


def _parse_value(name: str, text: str, default) -> object:
    """A ``--frontend-set`` value in the type of the setting ``name``."""
    text = text.strip()
    if name == "marker_dictionary":
        return None if text.lower() in ("none", "null", "off", "") else text
    if isinstance(default, bool):
        lowered = text.lower()
        if lowered in ("1", "true", "yes", "on"):
            return True
        if lowered in ("0", "false", "no", "off"):
            return False
        raise InputError(f"front-end setting {name}: expected true or false, got {text!r}")
    try:
        return int(text) if isinstance(default, int) else float(text)
    except ValueError:
        kind = "an integer" if isinstance(default, int) else "a number"
        raise InputError(f"front-end setting {name}: expected {kind}, got {text!r}") from None


def resolve_frontend(
    assignments: list[str] | None = None, file_values: dict | None = None, file_name: str = "file"
) -> tuple[FrontendConfig, dict[str, str]]:
    """Front-end settings from defaults, a file's values and ``NAME=VALUE`` assignments.

    Parameters
    ----------
    assignments
        ``NAME=VALUE`` strings (``frontend.NAME=VALUE`` accepted too); the last one of a name
        wins, and they win over ``file_values``.
    file_values
        Settings read from a file (``{name: value}``).
    file_name
        How the file is named as a source.

    Returns
    -------
    (FrontendConfig, sources)
        The settings and, per field, where its value came from: ``default``, the file's
        name, or ``--frontend-set``.
    """
    defaults = FrontendConfig()
    known = {f.name: getattr(defaults, f.name) for f in fields(FrontendConfig)}
    values: dict[str, object] = {}
    sources = dict.fromkeys(known, "default")
    for name, value in (file_values or {}).items():
        if name not in known:
            raise InputError(f"{file_name}: unknown front-end setting {name!r}")
        values[name] = _parse_value(name, str(value), known[name])
        sources[name] = file_name
    for text in assignments or []:
        name, sep, value = text.partition("=")
        name = name.strip().removeprefix("frontend.")
        if not sep or not name:
            raise InputError(f"--frontend-set expects NAME=VALUE, got {text!r}")
        if name not in known:
            raise InputError(
                f"unknown front-end setting {name!r}; the settings are " + ", ".join(known)
            )
        values[name] = _parse_value(name, value, known[name])
        sources[name] = "--frontend-set"
    return FrontendConfig(**values), sources


def frontend_table(config: FrontendConfig, sources: dict[str, str]) -> str:
    """One line per front-end setting: name, value, source."""
    width = max(len(f.name) for f in fields(config))
    lines = [f"{'front-end setting':<{width}}  {'value':<12} source"]
    for f in fields(config):
        value = getattr(config, f.name)
        lines.append(f"{f.name:<{width}}  {value!s:<12} {sources.get(f.name, 'default')}")
    return "\n".join(lines)
