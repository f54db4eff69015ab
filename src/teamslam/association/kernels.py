"""Compiled inner loops of the association (numba).

The neighbourhood comparison of every pair of objects and the pairwise consistency test are a
few float32 operations per element over ``n_a · n_b · k²`` and ``m²`` elements; in numpy each
operation makes a temporary of that size, so the cost is memory traffic. These loops do the
float32 arithmetic element by element, without the temporaries.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["consistent_pairs", "gathered_objects", "shared_neighbourhood"]


@numba.njit(cache=True)
def _consistent(d1: float, v1: float, d2: float, v2: float, quarter_rho2, chi2) -> bool:
    """``(d₁ − d₂)² ≤ χ² · (v₁ + v₂ + ρ²/4 · (d₁ + d₂)²)`` (float32)."""
    diff = d1 - d2
    s = d1 + d2
    return diff * diff <= chi2 * (v1 + v2 + quarter_rho2 * (s * s))


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
            if _consistent(
                dist_a[a, a2], var_a[a, a2], dist_b[b, b2], var_b[b, b2], quarter_rho2, chi2
            ):
                out[p, q] = True
                out[q, p] = True
    return out


@numba.njit(cache=True)
def shared_neighbourhood(
    dx: np.ndarray,
    vx: np.ndarray,
    dxx: np.ndarray,
    vxx: np.ndarray,
    dy: np.ndarray,
    vy: np.ndarray,
    dyy: np.ndarray,
    vyy: np.ndarray,
    allowed: np.ndarray,
    quarter_rho2: np.float32,
    chi2: np.float32,
    members: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """For every pair ``(x, y)``: how many neighbours of ``x`` and of ``y`` can be the same
    objects, as a rigid whole.

    Neighbour pairs ``(x', y')`` whose distances to ``x`` and ``y`` agree (the ``χ²`` test of
    :func:`consistent_pairs`) are the matches; two matches fit each other when they name four
    different objects and their distances agree as well. The matches are taken in order of how
    many others they fit (ties: closer agreement to ``x`` and ``y``), each kept when it fits
    every match kept before — a greedy consistent set of the pair's neighbourhood (the
    heuristic of :mod:`teamslam.association.clique`), ``x`` and ``y`` its common anchor.
    Neighbours only one map holds find no partner and cost nothing; distances that agree by
    chance rarely agree with each other too.

    Parameters
    ----------
    dx, vx, dy, vy
        ``(n, k)`` float32 distances from each object to its ``k`` nearest neighbours in its own
        map, and their variances.
    dxx, vxx, dyy, vyy
        ``(n, k, k)`` float32 distances between those neighbours, and their variances.
    allowed
        ``(n_x, n_y)`` boolean: the pairs to score (others score 0).
    members
        ``(n_x, n_y, m)`` integer array, filled by the call where the set has two members or
        more: its ``c``-th member (``c < m``) as ``i · k_y + j`` for neighbour ``i`` of ``x``
        and ``j`` of ``y``; entries beyond the set are left as they were (pass ``-1`` s).

    Returns
    -------
    count, mismatch
        ``(n_x, n_y)`` int64 neighbours in the consistent set and float32 sum of their
        normalised squared distance differences.
    """
    nx, kx = dx.shape
    ny, ky = dy.shape
    count = np.zeros((nx, ny), dtype=np.int64)
    mismatch = np.zeros((nx, ny), dtype=np.float32)
    cap = kx * ky
    z = np.empty(cap, dtype=np.float32)
    li = np.empty(cap, dtype=np.int64)
    lj = np.empty(cap, dtype=np.int64)
    chosen = np.empty(cap, dtype=np.int64)
    degree = np.empty(cap, dtype=np.int64)
    order = np.empty(cap, dtype=np.int64)
    fits = np.zeros((cap, cap), dtype=np.bool_)
    for x in range(nx):
        for y in range(ny):
            if not allowed[x, y]:
                continue
            n = 0
            for i in range(kx):
                da = dx[x, i]
                va = vx[x, i]
                for j in range(ky):
                    db = dy[y, j]
                    d = da - db
                    s = da + db
                    zz = d * d / (va + vy[y, j] + quarter_rho2 * (s * s))
                    if zz <= chi2:
                        # insertion in order of agreement (ties: earlier neighbours first)
                        p = n
                        while p > 0 and z[p - 1] > zz:
                            z[p] = z[p - 1]
                            li[p] = li[p - 1]
                            lj[p] = lj[p - 1]
                            p -= 1
                        z[p] = zz
                        li[p] = i
                        lj[p] = j
                        n += 1
            if n <= 1:  # nothing to test against each other
                count[x, y] = n
                mismatch[x, y] = z[0] if n else np.float32(0.0)
                continue
            # the matches' mutual consistency (one to one, distances between neighbours)
            for p in range(n):
                degree[p] = 0
            for p in range(n):
                i, j = li[p], lj[p]
                for q in range(p + 1, n):
                    i2, j2 = li[q], lj[q]
                    ok = (
                        i != i2
                        and j != j2
                        and _consistent(
                            dxx[x, i, i2],
                            vxx[x, i, i2],
                            dyy[y, j, j2],
                            vyy[y, j, j2],
                            quarter_rho2,
                            chi2,
                        )
                    )
                    fits[p, q] = ok
                    fits[q, p] = ok
                    if ok:
                        degree[p] += 1
                        degree[q] += 1
            for r in range(n):  # stable insertion sort by degree, highest first
                p = r
                while p > 0 and degree[order[p - 1]] < degree[r]:
                    order[p] = order[p - 1]
                    p -= 1
                order[p] = r
            m = 0
            total = np.float32(0.0)
            for r in range(n):
                p = order[r]
                ok = True
                for c in range(m):
                    if not fits[p, chosen[c]]:
                        ok = False
                        break
                if ok:
                    chosen[m] = p
                    total += z[p]
                    if m < members.shape[2]:
                        members[x, y, m] = li[p] * ky + lj[p]
                    m += 1
            count[x, y] = m
            mismatch[x, y] = total
    return count, mismatch


@numba.njit(cache=True)
def gathered_objects(
    rotations: np.ndarray,
    translations: np.ndarray,
    means_first: np.ndarray,
    means_second: np.ndarray,
    spread_first: np.ndarray,
    spread_second: np.ndarray,
    chi2: float,
) -> np.ndarray:
    """For each transform ``(R, t)``: how many objects of the first map have an object of the
    second within reach, ``‖a − (R b + t)‖² ≤ χ² · (λₐ + λ_b)``.

    ``λ`` is an object's largest covariance eigenvalue, so the test is the bounding sphere of the
    Mahalanobis gate without drift allowance: a cheap upper bound on the pairs the transform's
    gate could gather, used to rank many transforms before the few best are tested properly.

    Parameters
    ----------
    rotations, translations
        ``(h, 3, 3)`` and ``(h, 3)``: transforms taking the second map into the first.
    means_first, means_second
        ``(n_a, 3)`` and ``(n_b, 3)`` object positions.
    spread_first, spread_second
        ``(n_a,)`` and ``(n_b,)`` largest covariance eigenvalues.

    Returns
    -------
    numpy.ndarray
        ``(h,)`` int64 counts.
    """
    out = np.zeros(rotations.shape[0], dtype=np.int64)
    moved = np.empty((means_second.shape[0], 3))
    for h in range(rotations.shape[0]):
        for j in range(means_second.shape[0]):
            for u in range(3):
                moved[j, u] = (
                    rotations[h, u, 0] * means_second[j, 0]
                    + rotations[h, u, 1] * means_second[j, 1]
                    + rotations[h, u, 2] * means_second[j, 2]
                    + translations[h, u]
                )
        n = 0
        for i in range(means_first.shape[0]):
            for j in range(means_second.shape[0]):
                d2 = 0.0
                for u in range(3):
                    v = moved[j, u] - means_first[i, u]
                    d2 += v * v
                if d2 <= chi2 * (spread_first[i] + spread_second[j]):
                    n += 1
                    break
        out[h] = n
    return out
