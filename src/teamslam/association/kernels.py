"""Compiled inner loops of the association (numba).

The descriptor comparison and the pairwise consistency test are a few float32 operations per
element over arrays of ``n_a · n_b · k`` and ``m²`` elements; in numpy each operation makes a
temporary of that size, so the cost is memory traffic. These loops do the same float32
arithmetic element by element, without the temporaries.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["consistent_pairs", "descriptor_mismatch"]


@numba.njit(cache=True)
def descriptor_mismatch(
    dx: np.ndarray,
    vx: np.ndarray,
    dy: np.ndarray,
    vy: np.ndarray,
    quarter_rho2: np.float32,
) -> np.ndarray:
    """For every pair ``(x, y)`` and each neighbour distance of ``x``: the smallest normalised
    squared difference to any neighbour distance of ``y``, ``(n_x, n_y, k)`` float32.

    ``z = (dₓ − d_y)² / (vₓ + v_y + ρ²/4 · (dₓ + d_y)²)``.
    """
    nx, k = dx.shape
    ny, ky = dy.shape
    out = np.empty((nx, ny, k), dtype=np.float32)
    for x in range(nx):
        for y in range(ny):
            for i in range(k):
                a = dx[x, i]
                va = vx[x, i]
                best = np.float32(np.inf)
                for j in range(ky):
                    d = a - dy[y, j]
                    s = a + dy[y, j]
                    z = d * d / (va + vy[y, j] + quarter_rho2 * s * s)
                    if z < best:
                        best = z
                out[x, y, i] = best
    return out


@numba.njit(cache=True)
def consistent_pairs(
    ia: np.ndarray,
    ib: np.ndarray,
    dist_a: np.ndarray,
    var_a: np.ndarray,
    dist_b: np.ndarray,
    var_b: np.ndarray,
    quarter_rho2: np.float32,
    chi2: np.float32,
) -> np.ndarray:
    """``(m, m)`` boolean: candidates ``p = (ia[p], ib[p])`` and ``q`` name four different
    objects and ``(dₐ − d_b)² ≤ χ² · (σₐ² + σ_b² + ρ²/4 · (dₐ + d_b)²)`` (float32)."""
    m = ia.size
    out = np.zeros((m, m), dtype=np.bool_)
    for p in range(m):
        a, b = ia[p], ib[p]
        for q in range(p + 1, m):
            a2, b2 = ia[q], ib[q]
            if a == a2 or b == b2:
                continue
            d1 = dist_a[a, a2]
            d2 = dist_b[b, b2]
            s = d1 + d2
            var = var_a[a, a2] + var_b[b, b2]
            var += quarter_rho2 * (s * s)
            diff = d1 - d2
            if diff * diff <= chi2 * var:
                out[p, q] = True
                out[q, p] = True
    return out
