"""Stereo camera files and rectification.

A camera file is YAML (written by :func:`teamslam.sim.render.write_camera_file`):
``image_width``, ``image_height``, ``left`` and ``right`` (``K`` and ``distortion``),
``T_left_right`` (the right camera in the left camera frame) and optionally ``T_cam_body``
(default: body x forward, y left, z up). An already rectified pair is used as it is; otherwise
OpenCV's ``stereoRectify`` gives the rectifying rotations and a common pinhole camera, and
``T_cam_body`` is rotated with the rectified left frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from teamslam.errors import InputError
from teamslam.frontend._cv import require_cv2
from teamslam.geometry.camera import StereoCamera, check_stereo
from teamslam.textio import yaml_problem

__all__ = ["DEFAULT_T_CAM_BODY", "StereoRig", "load_camera", "rig_from_camera_info"]

DEFAULT_T_CAM_BODY = np.array(
    [[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)


@dataclass
class StereoRig:
    """A calibrated stereo pair and its rectification.

    Attributes
    ----------
    image_size
        ``(width, height)`` of the raw images.
    K_left, K_right, distortion_left, distortion_right
        Raw intrinsics and OpenCV distortion coefficients.
    T_left_right
        Pose of the right camera in the raw left camera frame.
    T_cam_body
        Body → raw left optical frame.
    """

    image_size: tuple[int, int]
    K_left: np.ndarray
    K_right: np.ndarray
    distortion_left: np.ndarray
    distortion_right: np.ndarray
    T_left_right: np.ndarray
    T_cam_body: np.ndarray = field(default_factory=lambda: DEFAULT_T_CAM_BODY.copy())

    def __post_init__(self) -> None:
        self._maps = None
        self._rectified = None

    @classmethod
    def rectified(
        cls,
        image_size: tuple[int, int],
        camera: StereoCamera,
        T_cam_body: np.ndarray | None = None,
    ) -> StereoRig:
        """The rig of an already rectified pair (no distortion, both cameras ``camera``'s
        intrinsics), e.g. a renderer's; ``T_cam_body`` defaults to the usual optical frame."""
        K = camera.intrinsics
        body = DEFAULT_T_CAM_BODY.copy() if T_cam_body is None else np.asarray(T_cam_body, float)
        return cls(image_size, K, K, np.zeros(5), np.zeros(5), camera.T_left_right, body)

    @property
    def already_rectified(self) -> bool:
        """No distortion, equal intrinsics, right camera along the left's x axis."""
        t = self.T_left_right
        return bool(
            not np.any(self.distortion_left)
            and not np.any(self.distortion_right)
            and np.allclose(self.K_left, self.K_right)
            and np.allclose(t[:3, :3], np.eye(3), atol=1e-12)
            and np.allclose(t[1:3, 3], 0.0, atol=1e-12)
            and t[0, 3] > 0
        )

    def _rectify_setup(self) -> None:
        if self._rectified is not None:
            return
        if self.already_rectified:
            self._rectified = (StereoCamera(self.K_left, self.T_left_right), np.eye(3))
            self._R_right = np.eye(3)
            self._projections = None
            return
        cv2 = require_cv2()
        T_right_left = np.linalg.inv(self.T_left_right)
        r1, r2, p1, p2, *_ = cv2.stereoRectify(
            self.K_left,
            self.distortion_left,
            self.K_right,
            self.distortion_right,
            self.image_size,
            T_right_left[:3, :3].copy(),
            T_right_left[:3, 3].reshape(3, 1).copy(),
            flags=cv2.CALIB_ZERO_DISPARITY,
            alpha=0,
        )
        baseline = -p2[0, 3] / p2[0, 0]
        if not baseline > 0:
            raise InputError(
                "camera: after rectification the right camera is not to the right of the left "
                f"(baseline {baseline:.4g}); check T_left_right"
            )
        K = p1[:3, :3].copy()
        self._R_right = r2
        self._projections = (p1, p2)
        self._rectified = (
            StereoCamera.from_baseline(K[0, 0], K[1, 1], K[0, 2], K[1, 2], baseline),
            r1,
        )
        size = self.image_size
        self._maps = (
            cv2.initUndistortRectifyMap(
                self.K_left, self.distortion_left, r1, p1, size, cv2.CV_32FC1
            ),
            cv2.initUndistortRectifyMap(
                self.K_right, self.distortion_right, r2, p2, size, cv2.CV_32FC1
            ),
        )

    @property
    def camera(self) -> StereoCamera:
        """The rectified stereo camera the measurements are in."""
        self._rectify_setup()
        return self._rectified[0]

    @property
    def R_rect_left(self) -> np.ndarray:
        """Rotation from the raw left frame to the rectified left frame."""
        self._rectify_setup()
        return self._rectified[1]

    @property
    def R_rect_right(self) -> np.ndarray:
        """Rotation from the raw right frame to the rectified right frame."""
        self._rectify_setup()
        return self._R_right

    @property
    def P_rect_left(self) -> np.ndarray:
        """``(3, 4)`` projection of the rectified left image (``[K_rect | 0]``)."""
        self._rectify_setup()
        if self._projections is not None:
            return np.asarray(self._projections[0], float).copy()
        return np.hstack([self.camera.intrinsics, np.zeros((3, 1))])

    @property
    def T_rect_body(self) -> np.ndarray:
        """Body → rectified left optical frame."""
        rot = np.eye(4)
        rot[:3, :3] = self.R_rect_left
        return rot @ self.T_cam_body

    def check_images(self, left: np.ndarray, right: np.ndarray, where: str = "") -> None:
        """:class:`InputError` unless both images are 8-bit grey of the rig's size (the
        message starts with ``where``, or the side's name)."""
        w, h = self.image_size
        for name, img in (("left", left), ("right", right)):
            if img.ndim != 2 or img.shape != (h, w) or img.dtype != np.uint8:
                raise InputError(
                    f"{where or name}: {name} image is {img.shape} {img.dtype}, "
                    f"expected {h}×{w} 8-bit grey"
                )

    def rectify_points(self, uv: np.ndarray, side: str = "left") -> np.ndarray:
        """Raw-image pixels ``(N, 2)`` of one camera (``side``: ``"left"`` or ``"right"``) →
        the same points' pixels in that camera's rectified image (OpenCV's ``undistortPoints``
        with the rectifying rotation and projection); a copy for an already rectified pair."""
        if side not in ("left", "right"):
            raise ValueError(f"side must be 'left' or 'right', got {side!r}")
        self._rectify_setup()
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        if self._projections is None or len(uv) == 0:
            return uv.copy()
        cv2 = require_cv2()
        left = side == "left"
        out = cv2.undistortPoints(
            uv.reshape(-1, 1, 2),
            self.K_left if left else self.K_right,
            self.distortion_left if left else self.distortion_right,
            R=self.R_rect_left if left else self.R_rect_right,
            P=self._projections[0 if left else 1],
        )
        return out.reshape(-1, 2).astype(np.float64)

    def rectify(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rectified images (the inputs themselves when the pair is already rectified)."""
        self._rectify_setup()
        if self._maps is None:
            return left, right
        cv2 = require_cv2()
        (lx, ly), (rx, ry) = self._maps
        return (
            cv2.remap(left, lx, ly, cv2.INTER_LINEAR),
            cv2.remap(right, rx, ry, cv2.INTER_LINEAR),
        )


def _matrix(data, key: str, shape: tuple[int, ...], where: str) -> np.ndarray:
    try:
        m = np.asarray(data[key], dtype=float)
    except (KeyError, TypeError, ValueError):
        raise InputError(f"{where}: missing or non-numeric {key}") from None
    if m.shape != shape or not np.all(np.isfinite(m)):
        raise InputError(f"{where}: {key} must be a finite {shape} array, got shape {m.shape}")
    return m


def rig_from_camera_info(left, right, T_cam_body: np.ndarray | None = None) -> StereoRig:
    """A :class:`StereoRig` from a pair of ``sensor_msgs/CameraInfo`` messages.

    ROS semantics: ``R`` rotates each raw camera frame into the common rectified frame and
    the right ``P`` holds ``−fx · b`` in ``P[0, 3]``; so the raw right camera sits at
    ``R_leftᵀ · (b, 0, 0)`` in the raw left frame, rotated by ``R_leftᵀ · R_right``.
    """
    mats = []
    for side, info in (("left", left), ("right", right)):
        K = np.asarray(info.k, dtype=float).reshape(3, 3)
        R = np.asarray(info.r, dtype=float).reshape(3, 3)
        P = np.asarray(info.p, dtype=float).reshape(3, 4)
        D = np.asarray(info.d, dtype=float).ravel()
        if not (np.all(np.isfinite(K)) and K[0, 0] > 0 and K[1, 1] > 0):
            raise InputError(f"camera info ({side}): K is not a camera matrix")
        if not np.any(R):
            R = np.eye(3)
        mats.append((K, R, P, D if D.size else np.zeros(5)))
    (K_l, R_l, _, D_l), (K_r, R_r, P_r, D_r) = mats
    if not P_r[0, 0] > 0:
        raise InputError("right camera info: P[0, 0] must be positive")
    baseline = -P_r[0, 3] / P_r[0, 0]
    if not baseline > 0:
        raise InputError(
            f"right camera info: P[0, 3] = {P_r[0, 3]} gives baseline {baseline}; "
            "the right camera info must carry −fx·b"
        )
    T_left_right = np.eye(4)
    T_left_right[:3, :3] = R_l.T @ R_r
    T_left_right[:3, 3] = R_l.T @ np.array([baseline, 0.0, 0.0])
    for side, K in (("left", K_l), ("right", K_r)):
        try:  # each camera through the one stereo-camera check, as a camera file's
            check_stereo(K, T_left_right)
        except InputError as exc:
            raise InputError(f"camera info ({side}): {exc}") from None
    size = (int(left.width), int(left.height))
    if (int(right.width), int(right.height)) != size:
        raise InputError("left and right camera infos give different image sizes")
    body = DEFAULT_T_CAM_BODY.copy() if T_cam_body is None else np.asarray(T_cam_body, float)
    return StereoRig(size, K_l, K_r, D_l, D_r, T_left_right, body)


def load_camera(path: str | Path) -> StereoRig:
    """Read a stereo camera file (see the module docstring); errors name the file and key."""
    import yaml

    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise InputError(f"{path}: cannot read camera file ({exc.strerror or exc})") from None
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: camera file is not valid YAML: {yaml_problem(exc)}") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: camera file must be a mapping")
    where = str(path)
    try:
        size = (int(data["image_width"]), int(data["image_height"]))
    except (KeyError, TypeError, ValueError):
        raise InputError(f"{path}: image_width and image_height are required integers") from None
    if min(size) <= 0:
        raise InputError(f"{path}: image size must be positive")
    cams = []
    for side in ("left", "right"):
        sec = data.get(side)
        if not isinstance(sec, dict):
            raise InputError(f"{path}: section {side} (K, distortion) is required")
        K = _matrix(sec, "K", (3, 3), f"{where}: {side}")
        dist = np.asarray(sec.get("distortion", np.zeros(5)), dtype=float).ravel()
        if dist.size not in (4, 5, 8, 12, 14) or not np.all(np.isfinite(dist)):
            raise InputError(f"{path}: {side}.distortion needs 4, 5, 8, 12 or 14 finite numbers")
        cams.append((K, dist))
    T_left_right = _matrix(data, "T_left_right", (4, 4), where)
    T_cam_body = (
        _matrix(data, "T_cam_body", (4, 4), where)
        if "T_cam_body" in data
        else DEFAULT_T_CAM_BODY.copy()
    )
    for name, t in (("T_left_right", T_left_right), ("T_cam_body", T_cam_body)):
        if not np.allclose(t[:3, :3] @ t[:3, :3].T, np.eye(3), atol=1e-6):
            raise InputError(f"{path}: {name} rotation is not orthonormal")
    for side, (K, _) in zip(("left", "right"), cams, strict=True):
        try:  # each raw camera through the one stereo-camera check
            check_stereo(K, T_left_right)
        except InputError as exc:
            raise InputError(f"{path}: {side}: {exc}") from None
    return StereoRig(size, cams[0][0], cams[1][0], cams[0][1], cams[1][1], T_left_right, T_cam_body)
