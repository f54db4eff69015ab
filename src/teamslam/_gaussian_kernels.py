"""Compiled in-place passes of :mod:`teamslam.gaussian` (numba), imported on first use.

:func:`add_weighted_difference_at` is one neighbour's term of the information-form average
(eq. 42) added straight into the rows and columns of its objects: the same floating-point
operations entry by entry as the numpy expression
``info[np.ix_(c, c)] += w * (M − Ω_C)``, without the gathered temporaries.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["add_weighted_difference_at"]


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
