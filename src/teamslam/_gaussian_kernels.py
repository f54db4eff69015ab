"""Compiled in-place passes of :mod:`teamslam.gaussian` (numba), imported on first use.

* :func:`add_weighted_difference_at` is one neighbour's term of the information-form average
  (eq. 42) added straight into the rows and columns of its objects: the same floating-point
  operations entry by entry as the numpy expression ``info[np.ix_(c, c)] += w * (M − Ω_C)``,
  without the gathered temporaries;
* :func:`rebuilt_joint` assembles the joint covariance of Prop. 2 from its blocks in one pass,
  each entry where it belongs (the same numbers as assembling ``[x, y]`` and permuting back).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["add_weighted_difference_at", "rebuilt_joint"]


@numba.njit(cache=True)
def add_weighted_difference_at(
    info: np.ndarray,
    eta: np.ndarray,
    index: np.ndarray,
    weight: float,
    their_info: np.ndarray,
    their_eta: np.ndarray,
    own_info: np.ndarray,
    own_eta: np.ndarray,
) -> None:
    """:func:`~teamslam.gaussian.add_weighted_difference` at ``np.ix_(index, index)`` and
    ``index`` (no repeats), in place: ``their`` the neighbour's information matrix and vector
    of the block, ``own`` ours."""
    k = index.size
    for a in range(k):
        row = index[a]
        eta[row] += weight * (their_eta[a] - own_eta[a])
        for b in range(k):
            info[row, index[b]] += weight * (their_info[a, b] - own_info[a, b])


@numba.njit(cache=True)
def rebuilt_joint(
    cov: np.ndarray,
    index_x: np.ndarray,
    index_y: np.ndarray,
    correction_x: np.ndarray,
    new_xy: np.ndarray,
    new_y: np.ndarray,
) -> np.ndarray:
    """The joint covariance after Prop. 2, ``(n, n)``, from the old one ``cov`` and the blocks:
    ``Σ̄ˣ = sym(Σˣ + correction_x)`` (``sym(M) = (M + Mᵀ) / 2``), ``Σ̄ˣʸ = new_xy`` and
    ``Σ̄ʸ = new_y``, at the rows and columns ``index_x`` and ``index_y`` (which together are
    every index once)."""
    n = cov.shape[0]
    nx, ny = index_x.size, index_y.size
    out = np.empty((n, n))
    for a in range(nx):
        row = index_x[a]
        for b in range(nx):
            col = index_x[b]
            upper = cov[row, col] + correction_x[a, b]
            lower = cov[col, row] + correction_x[b, a]
            out[row, col] = 0.5 * (upper + lower)
        for b in range(ny):
            value = new_xy[a, b]
            out[row, index_y[b]] = value
            out[index_y[b], row] = value
    for a in range(ny):
        row = index_y[a]
        for b in range(ny):
            out[row, index_y[b]] = new_y[a, b]
    return out
