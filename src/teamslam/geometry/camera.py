"""Rectified stereo pinhole camera: projection of points in the left camera frame, with Jacobian.

A stereo observation of a point ``p_cam`` (left optical frame: x right, y down, z forward) is
``(u_l, v_l, u_r, v_r)``: its pixel in the left image and in the right image. The right camera
sits at pose ``T_left_right`` in the left frame (for a rectified rig, a translation of the
baseline ``b`` along x), so ``p_right = T_left_right⁻¹ p_cam``, and both cameras share the
intrinsics ``K``. With ``K = I`` the measurements are normalised image coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from teamslam.errors import InputError

__all__ = ["StereoCamera", "check_stereo", "in_image"]


@dataclass(frozen=True)
class StereoCamera:
    """A rectified stereo pair.

    Attributes
    ----------
    intrinsics
        ``K`` (3×3) shared by both cameras.
    T_left_right
        Pose of the right camera in the left camera frame (4×4).
    """

    intrinsics: np.ndarray
    T_left_right: np.ndarray

    def __post_init__(self) -> None:
        k, t = check_stereo(self.intrinsics, self.T_left_right)
        object.__setattr__(self, "intrinsics", k)
        object.__setattr__(self, "T_left_right", t)

    @classmethod
    def from_baseline(
        cls, fx: float, fy: float, cx: float, cy: float, baseline: float
    ) -> StereoCamera:
        """A rectified pair with the right camera ``baseline`` metres along the left's x axis."""
        k = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        t = np.eye(4)
        t[0, 3] = baseline
        return cls(k, t)

    @property
    def baseline(self) -> float:
        """Distance between the two optical centres."""
        return float(np.linalg.norm(self.T_left_right[:3, 3]))

    @property
    def fx_baseline(self) -> float:
        """``fx · b``: disparity (pixels) times depth (m)."""
        return float(self.intrinsics[0, 0] * self.baseline)

    def _right_from_left(self) -> tuple[np.ndarray, np.ndarray]:
        r = self.T_left_right[:3, :3].T
        return r, -r @ self.T_left_right[:3, 3]

    def points_in_right(self, p_cam: np.ndarray) -> np.ndarray:
        """Points expressed in the right camera frame."""
        r, t = self._right_from_left()
        return np.asarray(p_cam, dtype=float) @ r.T + t

    def project(self, p_cam: np.ndarray) -> np.ndarray:
        """``(..., 3) -> (..., 4)`` stereo measurement ``(u_l, v_l, u_r, v_r)``."""
        p_cam = np.asarray(p_cam, dtype=float)
        p_right = self.points_in_right(p_cam)
        k = self.intrinsics
        left = p_cam[..., :2] / p_cam[..., 2:3]
        right = p_right[..., :2] / p_right[..., 2:3]
        scale = np.array([k[0, 0], k[1, 1]])
        centre = np.array([k[0, 2], k[1, 2]])
        return np.concatenate([left * scale + centre, right * scale + centre], axis=-1)

    def project_jacobian(self, p_cam: np.ndarray) -> np.ndarray:
        """``∂ project / ∂ p_cam``, ``(..., 3) -> (..., 4, 3)``."""
        p_cam = np.asarray(p_cam, dtype=float)
        r, _ = self._right_from_left()
        p_right = self.points_in_right(p_cam)
        fx, fy = self.intrinsics[0, 0], self.intrinsics[1, 1]
        out = np.zeros((*p_cam.shape[:-1], 4, 3))
        out[..., 0:2, :] = _pinhole_jacobian(p_cam, fx, fy)
        out[..., 2:4, :] = _pinhole_jacobian(p_right, fx, fy) @ r
        return out

    def in_view(
        self,
        p_cam: np.ndarray,
        width: float,
        height: float,
        min_depth: float = 0.1,
        max_depth: float = np.inf,
    ) -> np.ndarray:
        """Boolean mask: depth within range in both cameras, both pixels inside the image,
        and positive disparity."""
        p_cam = np.asarray(p_cam, dtype=float)
        p_right = self.points_in_right(p_cam)
        ok = (
            (p_cam[..., 2] > min_depth)
            & (p_cam[..., 2] < max_depth)
            & (p_right[..., 2] > min_depth)
        )
        with np.errstate(divide="ignore", invalid="ignore"):
            z = self.project(np.where(ok[..., None], p_cam, 1.0))
        return ok & in_image(z, width, height) & (z[..., 0] - z[..., 2] > 0)


def check_stereo(intrinsics, T_left_right) -> tuple[np.ndarray, np.ndarray]:
    """The one check of a stereo camera, whatever file it came from: ``K`` 3×3 and
    ``T_left_right`` 4×4, every entry finite, focal lengths ``fx = K[0][0]`` and ``fy = K[1][1]``
    positive, the baseline (the length of ``T_left_right``'s translation) positive.

    Returns
    -------
    K, T_left_right
        As float arrays.

    Raises
    ------
    InputError
        Naming the entry that is wrong and what it holds.
    """
    k = np.asarray(intrinsics, dtype=float)
    t = np.asarray(T_left_right, dtype=float)
    if k.shape != (3, 3):
        raise InputError(f"K must be 3×3, got shape {k.shape}")
    if t.shape != (4, 4):
        raise InputError(f"T_left_right must be 4×4, got shape {t.shape}")
    for name, m in (("K", k), ("T_left_right", t)):
        if not np.all(np.isfinite(m)):
            r, c = np.argwhere(~np.isfinite(m))[0]
            raise InputError(f"{name}[{r}][{c}] must be finite, got {m[r, c]}")
    for name, (r, c) in (("fx", (0, 0)), ("fy", (1, 1))):
        if not k[r, c] > 0:
            raise InputError(f"focal length {name} = K[{r}][{c}] must be > 0, got {k[r, c]:g}")
    baseline = float(np.linalg.norm(t[:3, 3]))
    if not baseline > 0:
        raise InputError(
            f"stereo baseline must be > 0, got {baseline:g} (T_left_right translation "
            f"{t[:3, 3].tolist()}: the right camera sits on the left one)"
        )
    return k, t


def in_image(z: np.ndarray, width: float, height: float) -> np.ndarray:
    """Boolean mask: both pixels of each stereo measurement ``(u_l, v_l, u_r, v_r)`` inside a
    ``width × height`` image."""
    z = np.asarray(z, dtype=float)
    return (
        (z[..., 0] >= 0)
        & (z[..., 0] < width)
        & (z[..., 1] >= 0)
        & (z[..., 1] < height)
        & (z[..., 2] >= 0)
        & (z[..., 2] < width)
        & (z[..., 3] >= 0)
        & (z[..., 3] < height)
    )


def _pinhole_jacobian(p: np.ndarray, fx: float, fy: float) -> np.ndarray:
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    inv_z = 1.0 / z
    out = np.zeros((*p.shape[:-1], 2, 3))
    out[..., 0, 0] = fx * inv_z
    out[..., 0, 2] = -fx * x * inv_z**2
    out[..., 1, 1] = fy * inv_z
    out[..., 1, 2] = -fy * y * inv_z**2
    return out
