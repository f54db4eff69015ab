"""Stereo observation of world points from a body pose, with Jacobians (distributed MSCKF, §V-D).

``z = project(T_cam_body · Rᵀ (p_world − t)) = (u_l, v_l, u_r, v_r)`` for a body pose
``T_world_body = (R, t)``; Jacobians in the right-perturbation convention of
:mod:`teamslam.geometry`, batched over observations. See the concept page *The filter*
(``docs/concepts/filter.md``).
"""

from __future__ import annotations

import numpy as np

from teamslam.geometry import so3
from teamslam.geometry.camera import StereoCamera

__all__ = ["observe", "observe_jacobians", "points_in_camera"]


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
