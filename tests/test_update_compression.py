"""QR compression of stacked measurement rows (MSCKF): the same update with fewer rows."""

from __future__ import annotations

import numpy as np
import pytest

from teamslam.msckf.update import MeasurementRows, compress


def _posterior(prior_cov, jacobian, residual, variance):
    """Kalman update of a zero prior mean: ``(δ, P⁺)``, written out densely."""
    s = jacobian @ prior_cov @ jacobian.T + np.diag(variance)
    gain = prior_cov @ jacobian.T @ np.linalg.inv(s)
    return gain @ residual, prior_cov - gain @ jacobian @ prior_cov


@pytest.mark.parametrize("seed", range(4))
def test_compressed_rows_give_the_same_update(seed):
    rng = np.random.default_rng(seed)
    dim, touched, rows = 40, 18, 90
    cols = np.sort(rng.choice(dim, touched, replace=False))
    jacobian = np.zeros((rows, dim))
    jacobian[:, cols] = rng.normal(size=(rows, touched))
    residual = rng.normal(size=rows)
    variance = rng.uniform(0.5, 2.0, rows)  # unequal noise: whitening matters
    root = rng.normal(size=(dim, dim))
    prior_cov = root @ root.T / dim + 0.1 * np.eye(dim)
    compressed = compress(MeasurementRows(jacobian, residual, variance))
    assert compressed.rows == touched
    assert not compressed.jacobian[:, np.setdiff1d(np.arange(dim), cols)].any()
    np.testing.assert_array_equal(compressed.variance, np.ones(touched))
    want = _posterior(prior_cov, jacobian, residual, variance)
    got = _posterior(prior_cov, compressed.jacobian, compressed.residual, compressed.variance)
    np.testing.assert_allclose(got[0], want[0], rtol=0, atol=1e-10)
    np.testing.assert_allclose(got[1], want[1], rtol=0, atol=1e-10)
    # the residual's whitened norm splits into the kept part and what the update cannot use
    assert np.sum(compressed.residual**2) <= np.sum(residual**2 / variance) + 1e-12


def test_fewer_rows_than_columns_are_left_as_they_are():
    rng = np.random.default_rng(7)
    rows = MeasurementRows(rng.normal(size=(5, 12)), rng.normal(size=5), np.full(5, 2.0))
    assert compress(rows) is rows
