"""The rotation group SO(3), batched over leading axes.

Rotation vectors ``phi`` have shape ``(..., 3)``, rotation matrices ``(..., 3, 3)``.
Conventions (Barfoot, *State Estimation for Robotics*, ch. 7):

* ``exp(phi) = I + sin θ/θ · φ^ + (1 - cos θ)/θ² · φ^²`` with θ = |φ|;
* left Jacobian ``J_l(φ)``: ``exp(φ + δ) ≈ exp(J_l(φ) δ) · exp(φ)``;
* right Jacobian ``J_r(φ) = J_l(-φ)``: ``exp(φ + δ) ≈ exp(φ) · exp(J_r(φ) δ)``.
"""

from __future__ import annotations

import numpy as np

from teamslam.errors import InputError
from teamslam.geometry import _series

__all__ = [
    "adjoint",
    "compose",
    "exp",
    "hat",
    "inverse",
    "left_jacobian",
    "left_jacobian_inverse",
    "log",
    "right_jacobian",
    "right_jacobian_inverse",
    "vee",
]


def hat(phi: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix ``φ^`` with ``φ^ v = φ × v``; shape ``(..., 3) -> (..., 3, 3)``."""
    phi = np.asarray(phi, dtype=float)
    if phi.shape[-1] != 3:
        raise InputError(f"so3.hat expects a trailing axis of size 3, got shape {phi.shape}")
    out = np.zeros((*phi.shape[:-1], 3, 3))
    x, y, z = phi[..., 0], phi[..., 1], phi[..., 2]
    out[..., 0, 1] = -z
    out[..., 0, 2] = y
    out[..., 1, 0] = z
    out[..., 1, 2] = -x
    out[..., 2, 0] = -y
    out[..., 2, 1] = x
    return out


def vee(omega: np.ndarray) -> np.ndarray:
    """Inverse of :func:`hat` (uses the antisymmetric part); ``(..., 3, 3) -> (..., 3)``."""
    omega = np.asarray(omega, dtype=float)
    if omega.shape[-2:] != (3, 3):
        raise InputError(f"so3.vee expects (..., 3, 3), got shape {omega.shape}")
    return 0.5 * np.stack(
        [
            omega[..., 2, 1] - omega[..., 1, 2],
            omega[..., 0, 2] - omega[..., 2, 0],
            omega[..., 1, 0] - omega[..., 0, 1],
        ],
        axis=-1,
    )


def _angle(phi: np.ndarray) -> np.ndarray:
    return np.sqrt(np.einsum("...i,...i->...", phi, phi))


def _hat_squared(phi: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """``φ^ φ^ = φ φᵀ - θ² I`` without a matrix product."""
    return phi[..., :, None] * phi[..., None, :] - (theta * theta)[..., None, None] * np.eye(3)


def _eye_like(phi: np.ndarray) -> np.ndarray:
    return np.broadcast_to(np.eye(3), (*phi.shape[:-1], 3, 3))


def exp(phi: np.ndarray) -> np.ndarray:
    """Rotation matrix of the rotation vector ``phi`` (Rodrigues' formula)."""
    phi = np.asarray(phi, dtype=float)
    angle = _angle(phi)
    theta = angle[..., None, None]
    return (
        _eye_like(phi)
        + _series.sinc(theta) * hat(phi)
        + _series.one_minus_cos_over_sq(theta) * _hat_squared(phi, angle)
    )


def log(rotation: np.ndarray) -> np.ndarray:
    """Rotation vector of a rotation matrix, angle in ``[0, π]``.

    Accurate near θ = 0 (series) and near θ = π, where the axis is taken from the symmetric
    part ``(R + Rᵀ)/2 = cos θ I + (1 - cos θ) a aᵀ`` and its sign from the antisymmetric part.
    """
    rotation = np.asarray(rotation, dtype=float)
    if rotation.shape[-2:] != (3, 3):
        raise InputError(f"so3.log expects (..., 3, 3), got shape {rotation.shape}")
    batch_shape = rotation.shape[:-2]
    rotation = rotation.reshape(-1, 3, 3)
    trace = np.trace(rotation, axis1=-2, axis2=-1)
    cos_theta = np.clip(0.5 * (trace - 1.0), -1.0, 1.0)
    sin_axis = vee(rotation)  # = sin θ · a
    sin_theta = np.linalg.norm(sin_axis, axis=-1)
    theta = np.arctan2(sin_theta, cos_theta)
    phi = sin_axis / _series.sinc(theta)[..., None]

    near_pi = cos_theta < -0.7
    if np.any(near_pi):
        rot = rotation[near_pi]
        c = cos_theta[near_pi]
        sym = 0.5 * (rot + np.swapaxes(rot, -1, -2)) - c[:, None, None] * np.eye(3)
        outer = sym / (1.0 - c)[:, None, None]  # a aᵀ
        diag = np.diagonal(outer, axis1=-2, axis2=-1)
        k = np.argmax(diag, axis=-1)
        rows = np.arange(len(k))
        axis = outer[rows, :, k] / np.sqrt(diag[rows, k])[:, None]
        sign = np.where(np.einsum("ni,ni->n", axis, sin_axis[near_pi]) < 0.0, -1.0, 1.0)
        phi[near_pi] = (sign * theta[near_pi])[:, None] * axis
    return phi.reshape(*batch_shape, 3)


def compose(r_a: np.ndarray, r_b: np.ndarray) -> np.ndarray:
    """``R_a · R_b`` (broadcast over leading axes)."""
    return np.asarray(r_a, dtype=float) @ np.asarray(r_b, dtype=float)


def inverse(rotation: np.ndarray) -> np.ndarray:
    """``Rᵀ``."""
    return np.swapaxes(np.asarray(rotation, dtype=float), -1, -2)


def adjoint(rotation: np.ndarray) -> np.ndarray:
    """Adjoint of SO(3): the rotation matrix itself (``R exp(φ) Rᵀ = exp(R φ)``)."""
    return np.array(rotation, dtype=float)


def left_jacobian(phi: np.ndarray) -> np.ndarray:
    """``J_l(φ) = I + (1 - cos θ)/θ² φ^ + (θ - sin θ)/θ³ φ^²``."""
    phi = np.asarray(phi, dtype=float)
    angle = _angle(phi)
    theta = angle[..., None, None]
    return (
        _eye_like(phi)
        + _series.one_minus_cos_over_sq(theta) * hat(phi)
        + _series.theta_minus_sin_over_cube(theta) * _hat_squared(phi, angle)
    )


def left_jacobian_inverse(phi: np.ndarray) -> np.ndarray:
    """``J_l(φ)⁻¹ = I - φ^/2 + (1 - θ sin θ / (2(1 - cos θ)))/θ² φ^²`` (singular at θ = 2π)."""
    phi = np.asarray(phi, dtype=float)
    angle = _angle(phi)
    theta = angle[..., None, None]
    return (
        _eye_like(phi)
        - 0.5 * hat(phi)
        + _series.inverse_jacobian_coefficient(theta) * _hat_squared(phi, angle)
    )


def right_jacobian(phi: np.ndarray) -> np.ndarray:
    """``J_r(φ) = J_l(-φ)``."""
    return left_jacobian(-np.asarray(phi, dtype=float))


def right_jacobian_inverse(phi: np.ndarray) -> np.ndarray:
    """``J_r(φ)⁻¹ = J_l(-φ)⁻¹``."""
    return left_jacobian_inverse(-np.asarray(phi, dtype=float))
