"""Observability of the 3D team filter under each linearisation policy (eq. 13).

Builds the local observability matrix ``M = [H_0; H_1 Φ_0; …]`` from the filter's own
:class:`~teamslam.msckf.filter.linearization.LinearizationPolicy`, fed with values drawn like a
filter's (:func:`estimates_like_a_filter`). With ``ideal`` and ``fej`` its rank is ``dim − 6``,
with ``std`` larger; :func:`falsely_observable` gives the singular values on the true
unobservable directions. See the concept page *Linearisation*
(``docs/concepts/linearization.md``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from teamslam.geometry import se3
from teamslam.geometry.camera import StereoCamera
from teamslam.linalg import nullspace, rank
from teamslam.msckf.filter.linearization import LinearizationPolicy, unobservable_directions
from teamslam.msckf.filter.models import observe_jacobians

__all__ = [
    "FilterValues",
    "estimates_like_a_filter",
    "falsely_observable",
    "nullspace",
    "observability_matrix",
    "rank",
    "team_scenario",
    "unobservable_basis",
]


@dataclass(frozen=True)
class FilterValues:
    """The values a filter holds at each frame (``R`` robots, frames ``0 … K``, ``m`` objects).

    Attributes
    ----------
    true_poses
        ``(R, K + 1, 4, 4)``.
    true_objects
        ``(m, 3)``.
    prior_poses
        ``T̂_{k|k−1}`` ``(R, K + 1, 4, 4)`` (frame 0: the known start).
    posterior_poses
        ``T̂_{k|k}`` ``(R, K + 1, 4, 4)``.
    odometry
        Measured relative poses ``(R, K, 4, 4)``: ``T̂_{k+1|k} = T̂_{k|k} · odometry_k``.
    objects
        Object estimates used at frame ``k`` ``(K + 1, m, 3)``; frame 0's is the first estimate.
    """

    true_poses: np.ndarray
    true_objects: np.ndarray
    prior_poses: np.ndarray
    posterior_poses: np.ndarray
    odometry: np.ndarray
    objects: np.ndarray


def team_scenario(robots: int, frames: int, objects: int) -> tuple[np.ndarray, np.ndarray]:
    """True poses ``(R, frames, 4, 4)`` turning gently, and objects ahead of every robot."""
    k = np.arange(frames)
    poses = np.tile(np.eye(4), (robots, frames, 1, 1))
    for r in range(robots):
        xi = np.zeros((frames, 6))
        xi[:, 0] = k * 1.0
        xi[:, 1] = 3.0 * r
        xi[:, 5] = 0.05 * k * (1 + r) + 0.1 * r
        xi[:, 4] = 0.02 * k
        poses[r, :, :3, :3] = se3.exp(xi)[:, :3, :3]
        poses[r, :, :3, 3] = xi[:, :3]
    j = np.arange(objects)
    points = np.column_stack([18.0 + 2.0 * j, 4.0 * np.sin(1.3 * j + 0.4), np.cos(0.7 * j)])
    return poses, points


def estimates_like_a_filter(
    true_poses: np.ndarray,
    true_objects: np.ndarray,
    rng: np.random.Generator,
    pose_std: float = 0.03,
    object_std: float = 0.3,
) -> FilterValues:
    """Estimates with a filter's structure: priors, updates that move them, noisy odometry."""
    r, n = true_poses.shape[:2]
    perturb = rng.normal(size=(r, n, 6)) * pose_std
    posterior = true_poses @ se3.exp(perturb)
    odometry = se3.inverse(true_poses[:, :-1]) @ true_poses[:, 1:]
    odometry = odometry @ se3.exp(rng.normal(size=(r, n - 1, 6)) * pose_std)
    prior = posterior.copy()
    prior[:, 1:] = posterior[:, :-1] @ odometry
    objects = true_objects + rng.normal(size=(n, *true_objects.shape)) * object_std
    return FilterValues(true_poses, true_objects, prior, posterior, odometry, objects)


def observability_matrix(
    policy: LinearizationPolicy,
    values: FilterValues,
    camera: StereoCamera,
    T_cam_body: np.ndarray,
) -> np.ndarray:
    """Stack (13) over every frame, every robot observing every object."""
    r, n = values.true_poses.shape[:2]
    m = values.true_objects.shape[0]
    dim = 6 * r + 3 * m
    transition = np.eye(dim)
    blocks = []
    for k in range(n):
        if k > 0:
            phi = np.eye(dim)
            for i in range(r):
                true_step = se3.inverse(values.true_poses[i, k - 1]) @ values.true_poses[i, k]
                step = policy.propagation_step(
                    values.prior_poses[i, k - 1],
                    values.prior_poses[i, k],
                    values.odometry[i, k - 1],
                    true_step,
                )
                phi[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] = se3.adjoint(se3.inverse(step))
            transition = phi @ transition
        points = policy.objects(values.objects[k], values.objects[0], values.true_objects)
        for i in range(r):
            # pose k enters with its prior T̂_{k|k−1}: current and first estimate at frame k
            pose = policy.poses(
                values.prior_poses[i, k], values.prior_poses[i, k], values.true_poses[i, k]
            )
            _, d_pose, d_point = observe_jacobians(camera, T_cam_body, pose, points)
            d_pose, d_point = policy.constrain(
                d_pose, d_point, values.prior_poses[i, k], values.objects[0]
            )
            h = np.zeros((m, 4, dim))
            h[:, :, 6 * i : 6 * i + 6] = d_pose
            for j in range(m):
                h[j, :, 6 * r + 3 * j : 6 * r + 3 * j + 3] = d_point[j]
            blocks.append(h.reshape(4 * m, dim) @ transition)
    return np.vstack(blocks)


def unobservable_basis(poses: np.ndarray, objects: np.ndarray) -> np.ndarray:
    """``(6R + 3m, 6)``: a rigid motion ``ξ = (δt, δθ)`` of the world in the error state at
    poses ``(R, 4, 4)`` and objects ``(m, 3)``."""
    r, m = poses.shape[0], objects.shape[0]
    out = np.zeros((6 * r + 3 * m, 6))
    for i in range(r):
        out[6 * i : 6 * i + 6] = unobservable_directions(poses[i], objects[:1])[0, :6]
    for j in range(m):
        out[6 * r + 3 * j : 6 * r + 3 * j + 3] = unobservable_directions(
            poses[0], objects[j : j + 1]
        )[0, 6:]
    return out


def falsely_observable(matrix: np.ndarray, basis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Singular values ``(6,)`` of ``M`` on the unobservable directions, relative to ``‖M‖``,
    with the right singular vectors in ``ξ = (δt, δθ)`` coordinates as rows ``(6, 6)``:
    a value well above round-off is a direction the filter wrongly treats as observable."""
    q, r_factor = np.linalg.qr(basis)
    _, s, vt = np.linalg.svd(matrix @ q)
    directions = vt @ r_factor  # back to ξ coordinates (up to scale)
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return s / np.linalg.norm(matrix, 2), directions
