"""Stereo visual odometry: PnP + RANSAC on tracked stereo points, for teams without odometry.

The stereo observations of frame ``k`` are triangulated in the rectified left camera; the same
track ids in frame ``k + 1`` give 2D–3D pairs, and ``cv2.solvePnPRansac`` (refined on the
inliers) gives the camera motion. It is turned into body odometry
``T_body_k⁻¹ · T_body_{k+1}`` through ``T_cam_body``.
"""

from __future__ import annotations

import numpy as np

from teamslam.frontend._cv import require_cv2
from teamslam.geometry.camera import StereoCamera

__all__ = ["stereo_motion", "triangulate"]


def triangulate(camera: StereoCamera, z: np.ndarray) -> np.ndarray:
    """``(N, 4)`` rectified stereo observations → ``(N, 3)`` points in the left camera."""
    z = np.asarray(z, dtype=float).reshape(-1, 4)
    K = camera.intrinsics
    disparity = z[:, 0] - z[:, 2]
    depth = camera.fx_baseline / disparity
    x = (z[:, 0] - K[0, 2]) / K[0, 0] * depth
    y = (z[:, 1] - K[1, 2]) / K[1, 1] * depth
    return np.column_stack([x, y, depth])


def stereo_motion(
    camera: StereoCamera,
    T_cam_body: np.ndarray,
    ids_a: np.ndarray,
    z_a: np.ndarray,
    ids_b: np.ndarray,
    uv_b: np.ndarray,
    reprojection: float,
    min_inliers: int,
) -> np.ndarray | None:
    """Body motion from frame a to frame b, or ``None`` when too few inliers support one.

    Parameters
    ----------
    camera, T_cam_body
        Rectified camera and body → left-camera transform.
    ids_a, z_a
        Stereo observations of frame a.
    ids_b, uv_b
        Left-image positions of tracks in frame b.
    reprojection, min_inliers
        RANSAC threshold (pixels) and least inlier count.
    """
    cv2 = require_cv2()
    common, ia, ib = np.intersect1d(ids_a, ids_b, return_indices=True)
    if common.size < min_inliers:
        return None
    points = triangulate(camera, z_a[ia])
    ok, rvec, tvec, inliers = cv2.solvePnPRansac(
        points.astype(np.float64),
        np.asarray(uv_b[ib], dtype=np.float64),
        camera.intrinsics,
        None,
        reprojectionError=float(reprojection),
        iterationsCount=200,
        confidence=0.999,
        flags=cv2.SOLVEPNP_ITERATIVE,
    )
    if not ok or inliers is None or len(inliers) < min_inliers:
        return None
    inl = inliers.ravel()
    rvec, tvec = cv2.solvePnPRefineLM(
        points[inl],
        np.asarray(uv_b[ib][inl], dtype=np.float64),
        camera.intrinsics,
        None,
        rvec,
        tvec,
    )
    T_b_a = np.eye(4)  # camera b from camera a
    T_b_a[:3, :3] = cv2.Rodrigues(rvec)[0]
    T_b_a[:3, 3] = tvec.ravel()
    T_a_b = np.linalg.inv(T_b_a)
    return np.linalg.inv(T_cam_body) @ T_a_b @ T_cam_body
