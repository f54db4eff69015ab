"""The compiled per-message passes of consensus give the numbers of the numpy expressions
they replace, bit for bit (or, for a sum, to rounding), and the same verdicts."""

from __future__ import annotations

import numpy as np

from teamslam.msckf.consensus_kernels import (
    FINITE,
    NON_FINITE,
    NOT_SYMMETRIC,
    checked_symmetric_part,
)


def _spd(rng, d):
    a = rng.normal(size=(d, d))
    return a @ a.T + d * np.eye(d)


def test_checked_symmetric_part_is_the_numpy_symmetric_part():
    rng = np.random.default_rng(0)
    for d in (3, 12, 45):
        matrix = _spd(rng, d)
        # asymmetric within the tolerance: the symmetric part is not the matrix itself
        matrix += 1e-11 * np.abs(matrix).max() * np.triu(rng.normal(size=(d, d)), 1)
        mean = rng.normal(size=d)
        status, sym = checked_symmetric_part(mean, matrix)
        assert status == FINITE
        assert np.array_equal(sym, 0.5 * (matrix + matrix.T))
        assert not np.array_equal(sym, matrix)


def test_checked_symmetric_part_verdicts():
    rng = np.random.default_rng(1)
    matrix, mean = _spd(rng, 9), rng.normal(size=9)
    skewed = matrix.copy()
    skewed[2, 7] += 1e-6 * np.abs(matrix).max()
    assert checked_symmetric_part(mean, skewed)[0] == NOT_SYMMETRIC
    for where in ((0, 0), (3, 8), (8, 3)):
        bad = matrix.copy()
        bad[where] = np.nan
        assert checked_symmetric_part(mean, bad)[0] == NON_FINITE
    bad_mean = mean.copy()
    bad_mean[4] = np.inf
    assert checked_symmetric_part(bad_mean, matrix)[0] == NON_FINITE
    # a non-finite entry is named as such even where the matrix is also asymmetric
    skewed[5, 5] = -np.inf
    assert checked_symmetric_part(mean, skewed)[0] == NON_FINITE
