"""Stereo observation of world points from a body pose, with Jacobians (distributed MSCKF, §V-D).

``z = project(T_cam_body · Rᵀ (p_world − t)) = (u_l, v_l, u_r, v_r)`` for a body pose
``T_world_body = (R, t)``; Jacobians in the right-perturbation convention of
:mod:`teamslam.geometry`, batched over observations. See the concept page *The filter*
(``docs/concepts/filter.md``).
"""

from __future__ import annotations

import numpy as np

from teamslam.gaussian import chi2_quantile
from teamslam.geometry import so3
from teamslam.geometry.camera import StereoCamera

__all__ = ["linearisation_reach", "observe", "observe_jacobians", "points_in_camera"]


def points_in_camera(
    T_world_body: np.ndarray, p_world: np.ndarray, T_cam_body: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``(p_body, p_cam)`` of points ``(..., 3)`` seen from poses ``(..., 4, 4)``."""
    rot = T_world_body[..., :3, :3]
    p_body = np.einsum("...ji,...j->...i", rot, p_world - T_world_body[..., :3, 3])
    p_cam = p_body @ T_cam_body[:3, :3].T + T_cam_body[:3, 3]
    return p_body, p_cam


def observe(
    camera: StereoCamera, T_cam_body: np.ndarray, T_world_body: np.ndarray, p_world: np.ndarray
) -> np.ndarray:
    """Predicted stereo measurements ``(..., 4)``."""
    _, p_cam = points_in_camera(T_world_body, p_world, T_cam_body)
    return camera.project(p_cam)


def observe_jacobians(
    camera: StereoCamera, T_cam_body: np.ndarray, T_world_body: np.ndarray, p_world: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Prediction ``(..., 4)``, Jacobians w.r.t. pose ``(..., 4, 6)`` and point ``(..., 4, 3)``."""
    p_body, p_cam = points_in_camera(T_world_body, p_world, T_cam_body)
    d_proj = camera.project_jacobian(p_cam) @ T_cam_body[:3, :3]  # ∂z/∂p_body
    d_pose = np.concatenate(
        [-d_proj, d_proj @ so3.hat(p_body)], axis=-1
    )  # ∂p_body/∂ρ = −I, ∂p_body/∂φ = p_body^
    d_point = d_proj @ np.swapaxes(T_world_body[..., :3, :3], -1, -2)
    return camera.project(p_cam), d_pose, d_point


def linearisation_reach(
    camera: StereoCamera,
    T_cam_body: np.ndarray,
    T_world_body: np.ndarray,
    point: np.ndarray,
    cov: np.ndarray,
    std: np.ndarray,
    probability: float,
) -> float:
    """How far a point's stereo rows are from linear over its confidence region, in standard
    deviations of the estimate they give.

    The rows ``h`` of the ``n`` observations from poses ``T_world_body`` are linearised at
    ``point``. At the six points ``point ± √q Lₖ`` of the region ``δpᵀ cov⁻¹ δp ≤ q``
    (``cov = L Lᵀ``, ``q`` the χ²(3) quantile of ``probability``) their linearisation error
    ``ε = h(p) − h(point) − H (p − point)``, each coordinate whitened by its noise ``std``, is
    projected on the whitened columns of ``H``: how far the error moves the least-squares point
    of those rows (one Gauss–Newton step from ``point`` on noise-free data made at ``p``), in its
    own standard deviations. Above 1, a point the data still allow would be estimated more than
    one deviation off by rows linearised at ``point``.

    Parameters
    ----------
    camera, T_cam_body
        The stereo pair and the body-to-camera transform.
    T_world_body
        ``(n, 4, 4)`` poses of the observations.
    point
        ``(3,)`` the linearisation point.
    cov
        ``(3, 3)`` the point's covariance.
    std
        ``(n, 4)`` noise standard deviation of each measurement coordinate.
    probability
        Probability of the confidence region, in (0, 1).

    Returns
    -------
    The largest over the six points; ``inf`` when one lies behind a camera.
    """
    _, at_cam = points_in_camera(T_world_body, point[None], T_cam_body)
    at = camera.project(at_cam)
    _, _, d_point = observe_jacobians(camera, T_cam_body, T_world_body, point[None])
    chol = np.linalg.cholesky(0.5 * (cov + cov.T))
    steps = np.sqrt(chi2_quantile(probability, 3)) * np.concatenate([chol.T, -chol.T])  # (6, 3)
    _, cams = points_in_camera(T_world_body[None], point + steps[:, None, :], T_cam_body)
    right = camera.points_in_right(cams)
    if not (np.all(cams[..., 2] > 0) and np.all(right[..., 2] > 0)):
        return float("inf")
    error = (camera.project(cams) - at - np.einsum("nij,sj->sni", d_point, steps)) / std
    basis, _ = np.linalg.qr((d_point / std[..., None]).reshape(-1, 3))
    moved = error.reshape(steps.shape[0], -1) @ basis
    return float(np.sqrt((moved**2).sum(axis=1)).max())
