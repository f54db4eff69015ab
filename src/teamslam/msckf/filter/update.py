"""Batched measurement work of the MSCKF: triangulation, null-space projection, gating.

Geometric features are grouped by track length; per group: Gauss–Newton triangulation, the
left null space of each point Jacobian by batched Householder QR (eq. 24) and rows for a χ²
gate with the residual's own degrees of freedom; stacked rows taller than the columns they
touch are QR-compressed. Rows are compact over the columns they may touch
(:class:`MeasurementRows`). See the concept page *The filter* (``docs/concepts/filter.md``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from teamslam.errors import EstimationError, InternalError
from teamslam.geometry.camera import StereoCamera
from teamslam.msckf.filter.kernels import gauss_newton_points
from teamslam.msckf.filter.models import points_in_camera

__all__ = [
    "MeasurementRows",
    "compress",
    "householder_project",
    "null_space_rows",
    "stereo_point",
    "triangulate",
]


@dataclass
class MeasurementRows:
    """Stacked residuals and Jacobians with per-row noise variance, built compact.

    ``jacobian`` holds only the error-state ``columns`` the rows may touch (increasing; OpenVINS'
    ``H_order``): ``jacobian[:, j]`` is the derivative with respect to error-state column
    ``columns[j]``, every other column of the full Jacobian is zero. ``columns=None`` means the
    Jacobian is full width (every column of the state, in order).
    """

    jacobian: np.ndarray
    residual: np.ndarray
    variance: np.ndarray
    columns: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.columns is None:
            return
        columns = np.asarray(self.columns, dtype=np.int64).ravel()
        if columns.size != self.jacobian.shape[1]:
            raise InternalError(
                f"{self.jacobian.shape[1]} Jacobian columns for {columns.size} state columns"
            )
        if np.any(columns[1:] <= columns[:-1]):  # put the columns in increasing order
            order = np.argsort(columns, kind="stable")
            columns = columns[order]
            if np.any(columns[1:] == columns[:-1]):
                raise InternalError("a state column appears twice in a Jacobian")
            self.jacobian = self.jacobian[:, order]
        self.columns = columns

    @classmethod
    def empty(cls, dim: int | None = None) -> MeasurementRows:
        """No rows (compact: no columns; ``dim`` is accepted for the full-width form)."""
        return cls(np.zeros((0, 0)), np.zeros(0), np.zeros(0), np.zeros(0, dtype=np.int64))

    @property
    def rows(self) -> int:
        """Number of rows."""
        return self.residual.size

    def state_columns(self) -> np.ndarray:
        """The error-state columns of ``jacobian``'s columns."""
        if self.columns is None:
            return np.arange(self.jacobian.shape[1])
        return self.columns

    def full(self, dim: int) -> np.ndarray:
        """The full-width ``(rows, dim)`` Jacobian (for checks, and for ``H δ`` of the iterated
        update; the Kalman update itself works on the compact columns)."""
        out = np.zeros((self.rows, dim))
        out[:, self.state_columns()] = self.jacobian
        return out

    def extend(self, other: MeasurementRows) -> MeasurementRows:
        """Both sets of rows, over the union of their columns."""
        if self.columns is None and other.columns is None:
            return MeasurementRows(
                np.vstack([self.jacobian, other.jacobian]),
                np.concatenate([self.residual, other.residual]),
                np.concatenate([self.variance, other.variance]),
            )
        mine, theirs = self.state_columns(), other.state_columns()
        columns = np.union1d(mine, theirs)
        jacobian = np.zeros((self.rows + other.rows, columns.size))
        jacobian[: self.rows, np.searchsorted(columns, mine)] = self.jacobian
        jacobian[self.rows :, np.searchsorted(columns, theirs)] = other.jacobian
        return MeasurementRows(
            jacobian,
            np.concatenate([self.residual, other.residual]),
            np.concatenate([self.variance, other.variance]),
            columns,
        )


def stereo_point(
    camera: StereoCamera, T_cam_body: np.ndarray, T_world_body: np.ndarray, z: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """World points from single stereo measurements (depth from disparity), and validity."""
    k = camera.intrinsics
    disparity = z[..., 0] - z[..., 2]
    ok = disparity > 1e-9 * k[0, 0]
    depth = camera.fx_baseline / np.where(ok, disparity, 1.0)
    p_cam = np.stack(
        [(z[..., 0] - k[0, 2]) / k[0, 0] * depth, (z[..., 1] - k[1, 2]) / k[1, 1] * depth, depth],
        axis=-1,
    )
    p_body = (p_cam - T_cam_body[:3, 3]) @ T_cam_body[:3, :3]
    p_world = (
        np.einsum("...ij,...j->...i", T_world_body[..., :3, :3], p_body) + T_world_body[..., :3, 3]
    )
    return p_world, ok


def triangulate(
    camera: StereoCamera,
    T_cam_body: np.ndarray,
    poses: np.ndarray,
    z: np.ndarray,
    iterations: int = 8,
    min_depth: float = 0.1,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss–Newton triangulation of many points, each from ``n`` stereo observations.

    Parameters
    ----------
    poses
        ``(G, n, 4, 4)`` body poses of the observations.
    z
        ``(G, n, 4)`` stereo measurements.

    Returns
    -------
    points, ok, rms
        ``(G, 3)`` world points, ``(G,)`` validity (finite, in front of every camera,
        well-conditioned) and ``(G,)`` RMS reprojection error.
    """
    points, ok = stereo_point(camera, T_cam_body, poses[:, -1], z[:, -1])
    points = np.where(ok[:, None], points, 0.0)
    # p_cam = R_cam_body Rᵀ (p_world − t) + t_cam_body of each observation, then the
    # iterations in one compiled call (same equations as observe_jacobians)
    rot_cam_world = T_cam_body[:3, :3] @ np.swapaxes(poses[..., :3, :3], -1, -2)
    t_cam_world = T_cam_body[:3, 3] - np.einsum(
        "...ij,...j->...i", rot_cam_world, poses[..., :3, 3]
    )
    rot_right_left = camera.T_left_right[:3, :3].T
    k = camera.intrinsics
    points = np.ascontiguousarray(points, dtype=float)
    normal = gauss_newton_points(
        points,
        ok,
        np.ascontiguousarray(rot_cam_world),
        np.ascontiguousarray(t_cam_world),
        np.ascontiguousarray(rot_right_left),
        -rot_right_left @ camera.T_left_right[:3, 3],
        np.array([k[0, 0], k[1, 1]]),
        np.array([k[0, 2], k[1, 2]]),
        np.ascontiguousarray(z, dtype=float),
        iterations,
    )
    _, p_cam = points_in_camera(poses, points[:, None, :], T_cam_body)
    pred = camera.project(p_cam)
    rms = np.sqrt(np.mean((z - pred) ** 2, axis=(1, 2)))
    ok &= np.all(np.isfinite(points), axis=1) & np.all(p_cam[..., 2] > min_depth, axis=1)
    cond = np.linalg.cond(normal)
    ok &= np.isfinite(cond) & (cond < 1e12)
    return points, ok, rms


def householder_project(h_f: np.ndarray, rest: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Apply ``Qᵀ`` of the complete QR of each ``h_f`` to ``rest`` without forming ``Q``.

    Parameters
    ----------
    h_f
        ``(G, m, p)`` with ``m > p`` (point Jacobians, ``p = 3``).
    rest
        ``(G, m, k)`` columns to transform alongside (residual, state Jacobian).

    Returns
    -------
    upper, transformed
        ``(G, p, p)`` the triangular factor ``R`` and ``(G, m, k)`` ``Qᵀ rest``: its first ``p``
        rows are ``Q₁ᵀ rest``, the others ``Nᵀ rest`` with ``N`` an orthonormal basis of the
        left null space of ``h_f`` (eq. 24). ``p`` batched Householder reflections, ``O(m k)``
        each, instead of a complete ``m × m`` ``Q``.
    """
    a = np.concatenate([h_f, rest], axis=2)
    p = h_f.shape[2]
    for j in range(p):
        x = a[:, j:, j]
        norm = np.linalg.norm(x, axis=1)
        alpha = -np.where(x[:, 0] >= 0, 1.0, -1.0) * norm
        v = x.copy()
        v[:, 0] -= alpha
        vnorm = np.linalg.norm(v, axis=1)
        v = np.where(vnorm[:, None] > 0, v / np.where(vnorm > 0, vnorm, 1.0)[:, None], 0.0)
        a[:, j:, :] -= 2.0 * v[:, :, None] * np.einsum("gm,gmk->gk", v, a[:, j:, :])[:, None, :]
    return a[:, :p, :p], a[:, :, p:]


def null_space_rows(
    state_cov: np.ndarray,
    pose_columns: np.ndarray,
    dim: int,
    pred: np.ndarray,
    d_pose: np.ndarray,
    d_point: np.ndarray,
    z: np.ndarray,
    variance: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Project a group of features onto their point Jacobians' left null spaces (eq. 24).

    Parameters
    ----------
    state_cov
        ``(dim, dim)`` covariance of the block the rows act on (the window poses).
    pose_columns
        ``(G, n, 6)`` columns of each observation's pose in that block.
    dim
        Size of that block; rows are returned over it.
    pred, d_pose, d_point, z
        ``(G, n, 4)``, ``(G, n, 4, 6)``, ``(G, n, 4, 3)``, ``(G, n, 4)``.
    variance
        Measurement noise variance (isotropic, so ``Nᵀ V N = σ² I``).

    Returns
    -------
    residual, jacobian, innovation_cov
        ``(G, 4n − 3)`` projected residuals, ``(G, 4n − 3, dim)`` projected Jacobians and
        ``(G, 4n − 3, 4n − 3)`` innovation covariances (for the χ² gate).
    """
    g, n = z.shape[:2]
    m = 4 * n
    h_x = np.zeros((g, n, 4, dim))
    gi = np.arange(g)[:, None, None, None]
    ni = np.arange(n)[None, :, None, None]
    ri = np.arange(4)[None, None, :, None]
    h_x[gi, ni, ri, pose_columns[:, :, None, :]] = d_pose
    h_x = h_x.reshape(g, m, dim)
    residual = (z - pred).reshape(g, m, 1)
    _, projected = householder_project(d_point.reshape(g, m, 3), np.concatenate([residual, h_x], 2))
    r0 = projected[:, 3:, 0]
    h0 = projected[:, 3:, 1:]
    s = h0 @ state_cov @ np.swapaxes(h0, 1, 2) + variance * np.eye(m - 3)
    return r0, h0, s


def compress(rows: MeasurementRows) -> MeasurementRows:
    """QR-compress when there are more rows than state columns the rows touch.

    Rows are whitened (``r/σ``, ``H/σ``); with ``H = Q₁ R`` the update with ``(Q₁ᵀ r, R)`` and unit
    noise equals the update with ``(r, H)``. Only the touched columns are factored (those of
    the compact Jacobian that are not exactly zero), so many feature rows (which touch only the
    window poses) shrink to at most ``6c`` rows; the result is compact over those columns.
    """
    touched = np.flatnonzero(np.any(rows.jacobian != 0.0, axis=0))
    if rows.rows <= touched.size:
        return rows
    scale = 1.0 / np.sqrt(rows.variance)
    # one Householder QR of [H r] (Q never formed): its first |cols| rows are [R  Q₁ᵀ r]
    augmented = np.column_stack([rows.jacobian[:, touched], rows.residual]) * scale[:, None]
    factored, _, _, info = scipy.linalg.lapack.dgeqrf(augmented, overwrite_a=True)
    if info != 0:
        raise EstimationError(f"QR of the stacked measurement rows failed (LAPACK info {info})")
    n = touched.size
    return MeasurementRows(
        np.triu(factored[:n, :n]),
        factored[:n, n].copy(),
        np.ones(n),
        rows.state_columns()[touched],
    )
