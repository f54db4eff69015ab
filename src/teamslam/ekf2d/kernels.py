"""Compiled inner loop of the multi-robot EKF update for small states (numba).

:func:`update_full` does the batch update of :meth:`MultiRobotEKF._batch_update` — eqs. 8–11
with ``H`` evaluated where the policy says and the innovation at the current estimate — in one
compiled call on the fully stored symmetric ``P``; larger states keep the numpy/BLAS path.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["motion", "propagate_full", "update_full"]


@numba.njit(cache=True)
def update_full(
    p: np.ndarray,
    mean: np.ndarray,
    n_robots: int,
    robot: np.ndarray,
    slots: np.ndarray,
    z: np.ndarray,
    covs: np.ndarray,
    lin_pose: np.ndarray,
    lin_feature: np.ndarray,
    pose: np.ndarray,
    feature: np.ndarray,
) -> bool:
    """One batch update of ``mean`` and the full symmetric ``P`` (both in place).

    Parameters
    ----------
    p
        ``(n, n)`` covariance, both triangles stored.
    mean
        ``(n,)`` state mean.
    robot, slots, z, covs
        Per observation: robot index, feature slot, ``z`` ``(m, 2)``, noise ``(m, 2, 2)``.
    lin_pose, lin_feature
        ``(m, 3)`` and ``(m, 2)``: where ``H`` is evaluated for each observation.
    pose, feature
        ``(m, 3)`` and ``(m, 2)``: the current estimates (predicted observation).

    Returns
    -------
    bool
        False (nothing changed) when the innovation covariance is not positive definite.
    """
    n = p.shape[0]
    r = 3 * n_robots
    m = robot.size
    k2 = 2 * m
    h = np.empty((m, 2, 5))
    cols = np.empty((m, 5), np.int64)
    ext = np.zeros((k2, n + 1))  # rows: (H P)[a, :] then the innovation in column n
    for i in range(m):
        # H = C(φ)ᵀ [−I, −J d, I] over [x_ri, x_fi] (eqs. 10–11), d = x_f − x_p
        c, s = math.cos(lin_pose[i, 2]), math.sin(lin_pose[i, 2])
        dx, dy = lin_feature[i, 0] - lin_pose[i, 0], lin_feature[i, 1] - lin_pose[i, 1]
        h[i, 0, 0], h[i, 0, 1], h[i, 0, 2], h[i, 0, 3], h[i, 0, 4] = -c, -s, c * dy - s * dx, c, s
        h[i, 1, 0], h[i, 1, 1], h[i, 1, 2], h[i, 1, 3], h[i, 1, 4] = (
            s,
            -c,
            -(s * dy + c * dx),
            -s,
            c,
        )
        for k in range(3):
            cols[i, k] = 3 * robot[i] + k
        cols[i, 3] = r + 2 * slots[i]
        cols[i, 4] = r + 2 * slots[i] + 1
        # innovation z − C(φ)ᵀ (x_f − x_p) at the current estimate (eq. 7)
        c, s = math.cos(pose[i, 2]), math.sin(pose[i, 2])
        ex, ey = feature[i, 0] - pose[i, 0], feature[i, 1] - pose[i, 1]
        ext[2 * i, n] = z[i, 0] - (c * ex + s * ey)
        ext[2 * i + 1, n] = z[i, 1] - (c * ey - s * ex)
    for i in range(m):  # H P: rows of P (symmetric) at the five columns of each observation
        for k in range(5):
            row = p[cols[i, k]]
            for a in range(2):
                hv = h[i, a, k]
                out = ext[2 * i + a]
                for j in range(n):
                    out[j] += hv * row[j]
    s_mat = np.zeros((k2, k2))  # S = H P Hᵀ + R
    for x in range(k2):
        for i in range(m):
            for a in range(2):
                acc = 0.0
                for k in range(5):
                    acc += h[i, a, k] * ext[x, cols[i, k]]
                s_mat[2 * i + a, x] = acc
    for i in range(m):
        for a in range(2):
            for b in range(2):
                s_mat[2 * i + a, 2 * i + b] += covs[i, a, b]
    low = np.zeros((k2, k2))  # S = L Lᵀ from the lower triangle
    for j in range(k2):
        acc = s_mat[j, j]
        for k in range(j):
            acc -= low[j, k] * low[j, k]
        if not acc > 0.0:
            return False
        low[j, j] = math.sqrt(acc)
        for i in range(j + 1, k2):
            acc = s_mat[i, j]
            for k in range(j):
                acc -= low[i, k] * low[j, k]
            low[i, j] = acc / low[j, j]
    for a in range(k2):  # [W | v] = L⁻¹ [H P | r], row by row
        out = ext[a]
        for b in range(a):
            lv = low[a, b]
            prev = ext[b]
            for j in range(n + 1):
                out[j] -= lv * prev[j]
        inv = 1.0 / low[a, a]
        for j in range(n + 1):
            out[j] *= inv
    for a in range(k2):  # mean += Wᵀ v; P −= Wᵀ W (rank-1 per row of W: stays symmetric)
        w = ext[a]
        v = w[n]
        for j in range(n):
            mean[j] += w[j] * v
        for i in range(n):
            wi = w[i]
            if wi != 0.0:
                row = p[i]
                for j in range(n):
                    row[j] -= wi * w[j]
    for i in range(n_robots):
        mean[3 * i + 2] = (mean[3 * i + 2] + math.pi) % (2.0 * math.pi) - math.pi
    return True


@numba.njit(cache=True)
def motion(pose: np.ndarray, odometry: np.ndarray) -> np.ndarray:
    """``(N, 3)`` poses moved by their odometry (eq. 2): ``x_p + C(φ) u``, ``wrap(φ + v)``."""
    out = np.empty_like(pose)
    for i in range(pose.shape[0]):
        c, s = math.cos(pose[i, 2]), math.sin(pose[i, 2])
        ux, uy = odometry[i, 0], odometry[i, 1]
        out[i, 0] = pose[i, 0] + (c * ux - s * uy)
        out[i, 1] = pose[i, 1] + (s * ux + c * uy)
        out[i, 2] = (pose[i, 2] + odometry[i, 2] + math.pi) % (2.0 * math.pi) - math.pi
    return out


@numba.njit(cache=True)
def propagate_full(p: np.ndarray, delta: np.ndarray, heading: np.ndarray, q: np.ndarray) -> None:
    """``P ← Φ P Φᵀ + G Q Gᵀ`` on the full symmetric ``P``, in place (eqs. 4–6).

    ``Φ`` is the identity but each robot's heading column ``J Δ`` (``delta`` ``(N, 2)``), ``G``
    rotates robot ``i``'s odometry noise ``q[i]`` by ``heading[i]``.
    """
    n = p.shape[0]
    n_robots = delta.shape[0]
    for i in range(n_robots):
        a = 3 * i
        cx, cy = -delta[i, 1], delta[i, 0]
        for j in range(n):  # rows: Φ P
            p[a, j] += cx * p[a + 2, j]
            p[a + 1, j] += cy * p[a + 2, j]
        for j in range(n):  # columns: (Φ P) Φᵀ
            p[j, a] += cx * p[j, a + 2]
            p[j, a + 1] += cy * p[j, a + 2]
    g = np.zeros((3, 3))
    g[2, 2] = 1.0
    for i in range(n_robots):
        c, s = math.cos(heading[i]), math.sin(heading[i])
        g[0, 0], g[0, 1], g[1, 0], g[1, 1] = c, -s, s, c
        a = 3 * i
        for x in range(3):
            for y in range(3):
                acc = 0.0
                for k in range(3):
                    for b in range(3):
                        acc += g[x, k] * q[i, k, b] * g[y, b]
                p[a + x, a + y] += acc
    r = 3 * n_robots
    for x in range(r):  # the robot block, made exactly symmetric again
        for y in range(x):
            v = 0.5 * (p[x, y] + p[y, x])
            p[x, y] = v
            p[y, x] = v
