"""The MSCKF Kalman update against the textbook formula, and QR compression of its rows."""

from __future__ import annotations

import numpy as np
import pytest

from teamslam.geometry import se3
from teamslam.msckf.state import MsckfState
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


@pytest.mark.parametrize("seed", range(3))
def test_state_update_is_the_kalman_update_and_exactly_symmetric(seed):
    """``MsckfState.update`` (syrk downdate through the Cholesky factor of ``S``) equals
    ``P − P Hᵀ S⁻¹ H P`` and the mean shift ``P Hᵀ S⁻¹ r``, and leaves ``P`` exactly symmetric."""
    rng = np.random.default_rng(20 + seed)
    poses, objects = 4, 5
    dim = 6 * poses + 3 * objects
    T = se3.exp(0.3 * rng.normal(size=(poses, 6)))
    means = rng.normal(size=(objects, 3))
    root = rng.normal(size=(dim, dim))
    cov = root @ root.T / dim + 0.05 * np.eye(dim)
    state = MsckfState.from_arrays(T, np.arange(poses), np.arange(objects), means, cov)
    prior_cov, prior_objects = state.cov.copy(), state.objects.copy()
    rows = 7
    jacobian = np.zeros((rows, dim))
    touched = rng.choice(dim, 12, replace=False)  # the update works on these columns only
    jacobian[:, touched] = rng.normal(size=(rows, 12))
    residual = rng.normal(size=rows)
    noise = np.diag(rng.uniform(0.1, 1.0, rows))
    delta = state.update(jacobian, residual, noise)
    s = jacobian @ prior_cov @ jacobian.T + noise
    gain = prior_cov @ jacobian.T @ np.linalg.inv(s)
    np.testing.assert_allclose(delta, gain @ residual, rtol=0, atol=1e-12)
    want = prior_cov - gain @ jacobian @ prior_cov
    np.testing.assert_allclose(state.cov, want, rtol=0, atol=1e-12)
    assert np.array_equal(state.cov, state.cov.T)
    np.testing.assert_allclose(state.objects, prior_objects + delta[6 * poses :].reshape(-1, 3))
