"""Compiled per-message passes of consensus (numba).

A robot of a team of ``n`` sends and receives up to ``n − 1`` joint marginals per step; in
numpy each check or rounding of one is a dozen whole-matrix passes with their temporaries, so
at a few dozen objects the cost is the passes, not the arithmetic. Each function here is one
compiled pass over a message's arrays that gives the same numbers as the numpy expressions it
replaces (element by element the same floating-point operations, no reassociation):

* :func:`checked_symmetric_part` — the receiver's finiteness and symmetry checks of a joint
  marginal and its symmetric part (:func:`~teamslam.msckf.consensus_checks.receive_marginal`).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["FINITE", "NON_FINITE", "NOT_SYMMETRIC", "checked_symmetric_part"]

FINITE, NON_FINITE, NOT_SYMMETRIC = 0, 1, 2
"""What :func:`checked_symmetric_part` found."""


@numba.njit(cache=True)
def checked_symmetric_part(mean: np.ndarray, matrix: np.ndarray) -> tuple[int, np.ndarray]:
    """``(status, (M + Mᵀ) / 2)`` of a received mean and ``(d, d)`` matrix ``M``.

    ``status`` is :data:`NON_FINITE` when an entry of either is NaN or infinite,
    :data:`NOT_SYMMETRIC` when ``max |M − Mᵀ| > 10⁻⁹ max |M| + 10⁻¹²``, else :data:`FINITE`
    (the symmetric part is then the second value; otherwise it is not filled in).
    """
    d = matrix.shape[0]
    out = np.empty((d, d))
    finite = True
    for i in range(mean.size):
        finite &= np.isfinite(mean[i])
    largest = 0.0
    asymmetry = 0.0
    for i in range(d):
        value = matrix[i, i]
        finite &= np.isfinite(value)
        largest = max(largest, abs(value))
        out[i, i] = 0.5 * (value + value)
        for j in range(i + 1, d):
            upper, lower = matrix[i, j], matrix[j, i]
            finite &= np.isfinite(upper) & np.isfinite(lower)
            largest = max(largest, abs(upper), abs(lower))
            asymmetry = max(asymmetry, abs(upper - lower))
            value = 0.5 * (upper + lower)
            out[i, j] = value
            out[j, i] = value
    if not finite:
        return NON_FINITE, out
    if asymmetry > 1e-9 * largest + 1e-12:
        return NOT_SYMMETRIC, out
    return FINITE, out
