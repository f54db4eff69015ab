"""The rigid-motion group SE(3), batched over leading axes.

Poses are homogeneous matrices ``(..., 4, 4)``; tangent vectors ``xi = (ρ, φ)`` of shape
``(..., 6)`` put **translation first, rotation second** (Barfoot's ordering, used by the
distributed-MSCKF paper). With this ordering

* ``xi^ = [[φ^, ρ], [0, 0]]`` and ``exp(xi) = [[exp(φ), J_l(φ) ρ], [0, 1]]``;
* ``Ad(T) = [[R, t^ R], [0, R]]`` so that ``T exp(xi) T⁻¹ = exp(Ad(T) xi)`` — the ``t^ R``
  block sits in the *upper right*, a placement easy to get wrong when copying formulas
  written for the (rotation, translation) ordering;
* the left Jacobian is ``[[J_l(φ), Q(ρ, φ)], [0, J_l(φ)]]`` (Barfoot eq. 7.86) and
  ``J_r(xi) = J_l(-xi)``.
"""

from __future__ import annotations

import numpy as np

from teamslam.errors import InputError
from teamslam.geometry import _series, so3

__all__ = [
    "adjoint",
    "compose",
    "exp",
    "from_rotation_translation",
    "hat",
    "inverse",
    "left_jacobian",
    "left_jacobian_inverse",
    "log",
    "right_jacobian",
    "right_jacobian_inverse",
    "vee",
]


def _check_tangent(xi: np.ndarray, name: str) -> np.ndarray:
    xi = np.asarray(xi, dtype=float)
    if xi.shape[-1] != 6:
        raise InputError(f"se3.{name} expects a trailing axis of size 6, got shape {xi.shape}")
    return xi


def _check_pose(pose: np.ndarray, name: str) -> np.ndarray:
    pose = np.asarray(pose, dtype=float)
    if pose.shape[-2:] != (4, 4):
        raise InputError(f"se3.{name} expects (..., 4, 4), got shape {pose.shape}")
    return pose


def from_rotation_translation(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """Homogeneous matrix from ``R (..., 3, 3)`` and ``t (..., 3)``."""
    rotation = np.asarray(rotation, dtype=float)
    translation = np.asarray(translation, dtype=float)
    shape = np.broadcast_shapes(rotation.shape[:-2], translation.shape[:-1])
    out = np.zeros((*shape, 4, 4))
    out[..., :3, :3] = rotation
    out[..., :3, 3] = translation
    out[..., 3, 3] = 1.0
    return out


def hat(xi: np.ndarray) -> np.ndarray:
    """``xi^ = [[φ^, ρ], [0, 0]]``, ``(..., 6) -> (..., 4, 4)``."""
    xi = _check_tangent(xi, "hat")
    out = np.zeros((*xi.shape[:-1], 4, 4))
    out[..., :3, :3] = so3.hat(xi[..., 3:])
    out[..., :3, 3] = xi[..., :3]
    return out


def vee(xi_hat: np.ndarray) -> np.ndarray:
    """Inverse of :func:`hat`."""
    xi_hat = _check_pose(xi_hat, "vee")
    return np.concatenate([xi_hat[..., :3, 3], so3.vee(xi_hat[..., :3, :3])], axis=-1)


def exp(xi: np.ndarray) -> np.ndarray:
    """Pose ``exp(xi^)``."""
    xi = _check_tangent(xi, "exp")
    rho, phi = xi[..., :3], xi[..., 3:]
    t = np.einsum("...ij,...j->...i", so3.left_jacobian(phi), rho)
    return from_rotation_translation(so3.exp(phi), t)


def log(pose: np.ndarray) -> np.ndarray:
    """Tangent vector ``(ρ, φ)`` of a pose, rotation angle in ``[0, π]``."""
    pose = _check_pose(pose, "log")
    phi = so3.log(pose[..., :3, :3])
    rho = np.einsum("...ij,...j->...i", so3.left_jacobian_inverse(phi), pose[..., :3, 3])
    return np.concatenate([rho, phi], axis=-1)


def compose(t_a: np.ndarray, t_b: np.ndarray) -> np.ndarray:
    """``T_a · T_b``."""
    return _check_pose(t_a, "compose") @ _check_pose(t_b, "compose")


def inverse(pose: np.ndarray) -> np.ndarray:
    """``T⁻¹ = [[Rᵀ, -Rᵀ t], [0, 1]]`` (exact, no general matrix inverse)."""
    pose = _check_pose(pose, "inverse")
    r_t = np.swapaxes(pose[..., :3, :3], -1, -2)
    return from_rotation_translation(r_t, -np.einsum("...ij,...j->...i", r_t, pose[..., :3, 3]))


def adjoint(pose: np.ndarray) -> np.ndarray:
    """``Ad(T) = [[R, t^ R], [0, R]]`` (6×6, translation-first ordering)."""
    pose = _check_pose(pose, "adjoint")
    rotation = pose[..., :3, :3]
    out = np.zeros((*pose.shape[:-2], 6, 6))
    out[..., :3, :3] = rotation
    out[..., 3:, 3:] = rotation
    out[..., :3, 3:] = so3.hat(pose[..., :3, 3]) @ rotation
    return out


def _q_matrix(xi: np.ndarray) -> np.ndarray:
    """Barfoot's ``Q(ρ, φ)``, the upper-right block of the SE(3) left Jacobian."""
    rho_hat = so3.hat(xi[..., :3])
    phi_hat = so3.hat(xi[..., 3:])
    theta = np.linalg.norm(xi[..., 3:], axis=-1)[..., None, None]
    pr = phi_hat @ rho_hat
    rp = rho_hat @ phi_hat
    prp = pr @ phi_hat
    pp = phi_hat @ phi_hat
    return (
        0.5 * rho_hat
        + _series.theta_minus_sin_over_cube(theta) * (pr + rp + prp)
        + _series.se3_q_c2(theta) * (pp @ rho_hat + rho_hat @ pp - 3.0 * prp)
        + _series.se3_q_c3(theta) * (prp @ phi_hat + pp @ rp)
    )


def left_jacobian(xi: np.ndarray) -> np.ndarray:
    """``J_l(xi) = [[J_l(φ), Q], [0, J_l(φ)]]``: ``exp(xi + δ) ≈ exp(J_l δ) exp(xi)``."""
    xi = _check_tangent(xi, "left_jacobian")
    j = so3.left_jacobian(xi[..., 3:])
    out = np.zeros((*xi.shape[:-1], 6, 6))
    out[..., :3, :3] = j
    out[..., 3:, 3:] = j
    out[..., :3, 3:] = _q_matrix(xi)
    return out


def left_jacobian_inverse(xi: np.ndarray) -> np.ndarray:
    """``J_l(xi)⁻¹ = [[J⁻¹, -J⁻¹ Q J⁻¹], [0, J⁻¹]]``."""
    xi = _check_tangent(xi, "left_jacobian_inverse")
    j_inv = so3.left_jacobian_inverse(xi[..., 3:])
    out = np.zeros((*xi.shape[:-1], 6, 6))
    out[..., :3, :3] = j_inv
    out[..., 3:, 3:] = j_inv
    out[..., :3, 3:] = -j_inv @ _q_matrix(xi) @ j_inv
    return out


def right_jacobian(xi: np.ndarray) -> np.ndarray:
    """``J_r(xi) = J_l(-xi)``: ``exp(xi + δ) ≈ exp(xi) exp(J_r δ)``."""
    return left_jacobian(-_check_tangent(xi, "right_jacobian"))


def right_jacobian_inverse(xi: np.ndarray) -> np.ndarray:
    """``J_r(xi)⁻¹ = J_l(-xi)⁻¹``."""
    return left_jacobian_inverse(-_check_tangent(xi, "right_jacobian_inverse"))
