"""Planar robot motion and point-feature observation models (FEJ multi-robot EKF paper, §2.2).

Motion (eq. 2) with its Jacobians ``Φ``, ``G`` (eqs. 5–6), observation (eq. 7) with ``H_r``,
``H_f`` (eqs. 10–11), and feature initialisation from one observation; batched over leading
axes. The linearisation point of each Jacobian is an argument, so the filter evaluates it where
its policy says. Equations: the concept page *Linearisation*
(``docs/concepts/linearization.md``).
"""

from __future__ import annotations

import numpy as np

from teamslam.geometry.se2 import rotation, wrap_angle

__all__ = [
    "J",
    "feature_from_observation",
    "feature_from_observation_jacobians",
    "motion",
    "motion_jacobians",
    "observation",
    "observation_jacobians",
]

J = np.array([[0.0, -1.0], [1.0, 0.0]])


def motion(pose: np.ndarray, odometry: np.ndarray) -> np.ndarray:
    """Propagate poses ``(..., 3)`` with odometry ``(u_x, u_y, v)`` ``(..., 3)`` (eq. 2)."""
    pose = np.asarray(pose, dtype=float)
    odometry = np.asarray(odometry, dtype=float)
    out = np.empty(np.broadcast_shapes(pose.shape, odometry.shape))
    out[..., :2] = pose[..., :2] + np.einsum(
        "...ij,...j->...i", rotation(pose[..., 2]), odometry[..., :2]
    )
    out[..., 2] = wrap_angle(pose[..., 2] + odometry[..., 2])
    return out


def motion_jacobians(
    position_from: np.ndarray, position_to: np.ndarray, heading: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``Φ`` (eq. 5) and ``G`` (eq. 6) at the given linearisation point.

    Parameters
    ----------
    position_from, position_to
        ``(..., 2)`` robot positions before and after the step (``J (x_p' - x_p)`` is the
        heading column of ``Φ``).
    heading
        ``(...)`` heading before the step (rotates the odometry noise in ``G``).
    """
    delta = np.asarray(position_to, dtype=float) - np.asarray(position_from, dtype=float)
    shape = delta.shape[:-1]
    phi = np.broadcast_to(np.eye(3), (*shape, 3, 3)).copy()
    phi[..., :2, 2] = delta @ J.T
    g = np.zeros((*shape, 3, 3))
    g[..., :2, :2] = rotation(heading)
    g[..., 2, 2] = 1.0
    return phi, g


def observation(pose: np.ndarray, feature: np.ndarray) -> np.ndarray:
    """Feature position in the robot frame, ``C(φ)ᵀ (x_f - x_p)``, ``(..., 2)`` (eq. 7)."""
    pose = np.asarray(pose, dtype=float)
    diff = np.asarray(feature, dtype=float) - pose[..., :2]
    return np.einsum("...ji,...j->...i", rotation(pose[..., 2]), diff)


def observation_jacobians(
    position: np.ndarray, heading: np.ndarray, feature: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``H_r`` ``(..., 2, 3)`` and ``H_f`` ``(..., 2, 2)`` at the given point (eqs. 10–11)."""
    h_f = np.swapaxes(rotation(heading), -1, -2)
    diff = np.asarray(feature, dtype=float) - np.asarray(position, dtype=float)
    h_r = np.empty((*h_f.shape[:-2], 2, 3))
    h_r[..., :, :2] = -h_f
    h_r[..., :, 2] = -np.einsum("...ij,...j->...i", h_f, diff @ J.T)
    return h_r, h_f


def feature_from_observation(pose: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Invert the observation: ``x_f = x_p + C(φ) z``."""
    pose = np.asarray(pose, dtype=float)
    return pose[..., :2] + np.einsum(
        "...ij,...j->...i", rotation(pose[..., 2]), np.asarray(z, float)
    )


def feature_from_observation_jacobians(
    pose: np.ndarray, z: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``∂x_f/∂x_r`` ``(..., 2, 3)`` and ``∂x_f/∂z`` ``(..., 2, 2)`` of feature initialisation."""
    pose = np.asarray(pose, dtype=float)
    c = rotation(pose[..., 2])
    d_pose = np.empty((*c.shape[:-2], 2, 3))
    d_pose[..., :, :2] = np.eye(2)
    d_pose[..., :, 2] = np.einsum("ij,...jk,...k->...i", J, c, np.asarray(z, float))
    return d_pose, c
