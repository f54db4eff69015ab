"""The planar rigid-motion group SE(2), batched over leading axes.

Poses are homogeneous matrices ``(..., 3, 3)``; tangent vectors ``xi = (ρx, ρy, θ)``
(translation first, as in :mod:`teamslam.geometry.se3`). With ``V(θ) = sin θ/θ I +
(1 - cos θ)/θ J`` (``J`` the 90° rotation):

* ``exp(xi) = [[R(θ), V(θ) ρ], [0, 1]]``;
* ``Ad(T) = [[R, -J t], [0, 1]]``;
* ``J_l(xi) = [[V(θ), (c I - d J) ρ], [0, 1]]`` and ``J_r(xi) = [[V(-θ), (c I + d J) ρ], [0, 1]]``
  with ``c = (θ - sin θ)/θ²``, ``d = (1 - cos θ)/θ²``.

Planar filters usually carry poses as ``(x, y, φ)`` vectors: :func:`from_xytheta` and
:func:`to_xytheta` convert.
"""

from __future__ import annotations

import numpy as np

from teamslam.errors import InputError
from teamslam.geometry import _series

__all__ = [
    "adjoint",
    "compose",
    "exp",
    "from_xytheta",
    "hat",
    "inverse",
    "left_jacobian",
    "left_jacobian_inverse",
    "log",
    "right_jacobian",
    "right_jacobian_inverse",
    "rotation",
    "to_xytheta",
    "vee",
    "wrap_angle",
]

_J = np.array([[0.0, -1.0], [1.0, 0.0]])


def wrap_angle(angle: np.ndarray) -> np.ndarray:
    """Wrap angles to ``[-π, π)``."""
    return (np.asarray(angle, dtype=float) + np.pi) % (2.0 * np.pi) - np.pi


def _check_tangent(xi: np.ndarray, name: str) -> np.ndarray:
    xi = np.asarray(xi, dtype=float)
    if xi.shape[-1] != 3:
        raise InputError(f"se2.{name} expects a trailing axis of size 3, got shape {xi.shape}")
    return xi


def _check_pose(pose: np.ndarray, name: str) -> np.ndarray:
    pose = np.asarray(pose, dtype=float)
    if pose.shape[-2:] != (3, 3):
        raise InputError(f"se2.{name} expects (..., 3, 3), got shape {pose.shape}")
    return pose


def rotation(theta: np.ndarray) -> np.ndarray:
    """Planar rotation matrices ``R(θ)``, ``(...) -> (..., 2, 2)``."""
    theta = np.asarray(theta, dtype=float)
    c, s = np.cos(theta), np.sin(theta)
    out = np.empty((*theta.shape, 2, 2))
    out[..., 0, 0] = c
    out[..., 0, 1] = -s
    out[..., 1, 0] = s
    out[..., 1, 1] = c
    return out


def from_xytheta(pose: np.ndarray) -> np.ndarray:
    """Homogeneous matrix of ``(x, y, φ)``."""
    pose = _check_tangent(pose, "from_xytheta")
    out = np.zeros((*pose.shape[:-1], 3, 3))
    out[..., :2, :2] = rotation(pose[..., 2])
    out[..., :2, 2] = pose[..., :2]
    out[..., 2, 2] = 1.0
    return out


def to_xytheta(pose: np.ndarray) -> np.ndarray:
    """``(x, y, φ)`` of a homogeneous matrix, φ in ``[-π, π]``."""
    pose = _check_pose(pose, "to_xytheta")
    phi = np.arctan2(pose[..., 1, 0], pose[..., 0, 0])
    return np.concatenate([pose[..., :2, 2], phi[..., None]], axis=-1)


def hat(xi: np.ndarray) -> np.ndarray:
    """``xi^ = [[θ J, ρ], [0, 0]]``."""
    xi = _check_tangent(xi, "hat")
    out = np.zeros((*xi.shape[:-1], 3, 3))
    out[..., :2, :2] = xi[..., 2, None, None] * _J
    out[..., :2, 2] = xi[..., :2]
    return out


def vee(xi_hat: np.ndarray) -> np.ndarray:
    """Inverse of :func:`hat`."""
    xi_hat = _check_pose(xi_hat, "vee")
    theta = 0.5 * (xi_hat[..., 1, 0] - xi_hat[..., 0, 1])
    return np.concatenate([xi_hat[..., :2, 2], theta[..., None]], axis=-1)


def _v_matrix(theta: np.ndarray) -> np.ndarray:
    a = _series.sinc(np.abs(theta))[..., None, None]
    b = (theta * _series.one_minus_cos_over_sq(np.abs(theta)))[..., None, None]
    return a * np.eye(2) + b * _J


def _v_matrix_inverse(theta: np.ndarray) -> np.ndarray:
    a = _series.sinc(np.abs(theta))[..., None, None]
    b = (theta * _series.one_minus_cos_over_sq(np.abs(theta)))[..., None, None]
    return (a * np.eye(2) - b * _J) / (a * a + b * b)


def exp(xi: np.ndarray) -> np.ndarray:
    """Pose ``exp(xi^)``."""
    xi = _check_tangent(xi, "exp")
    out = np.zeros((*xi.shape[:-1], 3, 3))
    out[..., :2, :2] = rotation(xi[..., 2])
    out[..., :2, 2] = np.einsum("...ij,...j->...i", _v_matrix(xi[..., 2]), xi[..., :2])
    out[..., 2, 2] = 1.0
    return out


def log(pose: np.ndarray) -> np.ndarray:
    """Tangent vector of a pose, θ in ``[-π, π]``."""
    pose = _check_pose(pose, "log")
    theta = np.arctan2(pose[..., 1, 0], pose[..., 0, 0])
    rho = np.einsum("...ij,...j->...i", _v_matrix_inverse(theta), pose[..., :2, 2])
    return np.concatenate([rho, theta[..., None]], axis=-1)


def compose(t_a: np.ndarray, t_b: np.ndarray) -> np.ndarray:
    """``T_a · T_b``."""
    return _check_pose(t_a, "compose") @ _check_pose(t_b, "compose")


def inverse(pose: np.ndarray) -> np.ndarray:
    """``T⁻¹ = [[Rᵀ, -Rᵀ t], [0, 1]]``."""
    pose = _check_pose(pose, "inverse")
    r_t = np.swapaxes(pose[..., :2, :2], -1, -2)
    out = np.zeros_like(pose)
    out[..., :2, :2] = r_t
    out[..., :2, 2] = -np.einsum("...ij,...j->...i", r_t, pose[..., :2, 2])
    out[..., 2, 2] = 1.0
    return out


def adjoint(pose: np.ndarray) -> np.ndarray:
    """``Ad(T) = [[R, -J t], [0, 1]]``."""
    pose = _check_pose(pose, "adjoint")
    out = np.zeros((*pose.shape[:-2], 3, 3))
    out[..., :2, :2] = pose[..., :2, :2]
    out[..., :2, 2] = -np.einsum("ij,...j->...i", _J, pose[..., :2, 2])
    out[..., 2, 2] = 1.0
    return out


def _jacobian(xi: np.ndarray, sign: float) -> np.ndarray:
    theta = xi[..., 2]
    abs_theta = np.abs(theta)
    c = (theta * _series.theta_minus_sin_over_cube(abs_theta))[..., None, None]
    d = _series.one_minus_cos_over_sq(abs_theta)[..., None, None]
    out = np.zeros((*xi.shape[:-1], 3, 3))
    out[..., :2, :2] = _v_matrix(sign * theta)
    out[..., :2, 2] = np.einsum("...ij,...j->...i", c * np.eye(2) - sign * d * _J, xi[..., :2])
    out[..., 2, 2] = 1.0
    return out


def _jacobian_inverse(xi: np.ndarray, sign: float) -> np.ndarray:
    jac = _jacobian(xi, sign)
    v_inv = _v_matrix_inverse(sign * xi[..., 2])
    out = np.zeros_like(jac)
    out[..., :2, :2] = v_inv
    out[..., :2, 2] = -np.einsum("...ij,...j->...i", v_inv, jac[..., :2, 2])
    out[..., 2, 2] = 1.0
    return out


def left_jacobian(xi: np.ndarray) -> np.ndarray:
    """``exp(xi + δ) ≈ exp(J_l δ) exp(xi)``."""
    return _jacobian(_check_tangent(xi, "left_jacobian"), 1.0)


def right_jacobian(xi: np.ndarray) -> np.ndarray:
    """``exp(xi + δ) ≈ exp(xi) exp(J_r δ)``."""
    return _jacobian(_check_tangent(xi, "right_jacobian"), -1.0)


def left_jacobian_inverse(xi: np.ndarray) -> np.ndarray:
    """Closed-form inverse of :func:`left_jacobian`."""
    return _jacobian_inverse(_check_tangent(xi, "left_jacobian_inverse"), 1.0)


def right_jacobian_inverse(xi: np.ndarray) -> np.ndarray:
    """Closed-form inverse of :func:`right_jacobian`."""
    return _jacobian_inverse(_check_tangent(xi, "right_jacobian_inverse"), -1.0)
