"""Compiled inner loop of the MSCKF's Gauss–Newton triangulation (numba).

:func:`gauss_newton_points` runs the triangulation's iterations — stereo residuals and point
Jacobians of :func:`teamslam.msckf.filter.models.observe_jacobians`, normal equations
``(JᵀJ + 10⁻¹² I) δ = Jᵀ r`` solved by LU with partial pivoting — in one compiled call.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["gauss_newton_points"]


@numba.njit(cache=True, error_model="numpy")
def gauss_newton_points(
    points: np.ndarray,
    ok: np.ndarray,
    rot_cam_world: np.ndarray,
    t_cam_world: np.ndarray,
    rot_right_left: np.ndarray,
    t_right_left: np.ndarray,
    focal: np.ndarray,
    centre: np.ndarray,
    z: np.ndarray,
    iterations: int,
) -> np.ndarray:
    """Refine ``points`` ``(G, 3)`` in place; return the last normal matrices ``(G, 3, 3)``.

    Parameters
    ----------
    points
        Initial world points; only those with ``ok`` move.
    rot_cam_world, t_cam_world
        ``(G, n, 3, 3)`` and ``(G, n, 3)``: ``p_cam = R p_world + t`` of each observation.
    rot_right_left, t_right_left
        The right camera from the left one.
    focal, centre
        ``(fx, fy)`` and ``(cx, cy)``.
    z
        ``(G, n, 4)`` stereo measurements ``(u_l, v_l, u_r, v_r)``.
    """
    g_count, n = z.shape[0], z.shape[1]
    normals = np.empty((g_count, 3, 3))
    jac = np.empty((4, 3))
    cam_jac = np.empty((4, 3))
    err = np.empty(4)
    for g in range(g_count):
        p = points[g].copy()
        for _ in range(iterations):
            normal = np.zeros((3, 3))
            rhs = np.zeros(3)
            for k in range(n):
                rot = rot_cam_world[g, k]
                pc = rot @ p + t_cam_world[g, k]
                pr = rot_right_left @ pc + t_right_left
                # residuals: measurement − projection (left, then right)
                err[0] = z[g, k, 0] - (pc[0] / pc[2] * focal[0] + centre[0])
                err[1] = z[g, k, 1] - (pc[1] / pc[2] * focal[1] + centre[1])
                err[2] = z[g, k, 2] - (pr[0] / pr[2] * focal[0] + centre[0])
                err[3] = z[g, k, 3] - (pr[1] / pr[2] * focal[1] + centre[1])
                # ∂z/∂p_cam: pinhole Jacobians of both cameras (the right one through R_rl)
                left = np.zeros((2, 3))
                inv_z = 1.0 / pc[2]
                left[0, 0] = focal[0] * inv_z
                left[0, 2] = -focal[0] * pc[0] * inv_z**2
                left[1, 1] = focal[1] * inv_z
                left[1, 2] = -focal[1] * pc[1] * inv_z**2
                right = np.zeros((2, 3))
                inv_z = 1.0 / pr[2]
                right[0, 0] = focal[0] * inv_z
                right[0, 2] = -focal[0] * pr[0] * inv_z**2
                right[1, 1] = focal[1] * inv_z
                right[1, 2] = -focal[1] * pr[1] * inv_z**2
                cam_jac[0:2] = left
                cam_jac[2:4] = right @ rot_right_left
                jac[:, :] = cam_jac @ rot
                for a in range(3):
                    for b in range(3):
                        s = 0.0
                        for r in range(4):
                            s += jac[r, a] * jac[r, b]
                        normal[a, b] += s
                    s = 0.0
                    for r in range(4):
                        s += jac[r, a] * err[r]
                    rhs[a] += s
            for a in range(3):
                normal[a, a] += 1e-12
            normals[g] = normal
            if ok[g]:
                p += _solve3(normal, rhs)
        points[g] = p
    return normals


@numba.njit(cache=True, error_model="numpy")
def _solve3(matrix: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """``matrix⁻¹ rhs`` for a 3×3 system, LU with partial pivoting."""
    a = matrix.copy()
    b = rhs.copy()
    for col in range(3):
        pivot = col
        for row in range(col + 1, 3):
            if abs(a[row, col]) > abs(a[pivot, col]):
                pivot = row
        if pivot != col:
            for c in range(3):
                a[col, c], a[pivot, c] = a[pivot, c], a[col, c]
            b[col], b[pivot] = b[pivot], b[col]
        for row in range(col + 1, 3):
            factor = a[row, col] / a[col, col]
            for c in range(col, 3):
                a[row, c] -= factor * a[col, c]
            b[row] -= factor * b[col]
    x = np.empty(3)
    for row in range(2, -1, -1):
        s = b[row]
        for c in range(row + 1, 3):
            s -= a[row, c] * x[c]
        x[row] = s / a[row, row]
    return x
