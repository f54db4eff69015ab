"""The MSCKF Kalman update against the textbook formula, and QR compression of its rows."""

from __future__ import annotations

import numpy as np
import pytest

from teamslam.geometry import se3
from teamslam.msckf.filter.state import MsckfState
from teamslam.msckf.filter.update import MeasurementRows, compress


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
    # compact over exactly the touched columns (OpenVINS' H_order)
    np.testing.assert_array_equal(compressed.columns, cols)
    assert compressed.jacobian.shape == (touched, touched)
    np.testing.assert_array_equal(compressed.variance, np.ones(touched))
    want = _posterior(prior_cov, jacobian, residual, variance)
    full = compressed.full(dim)
    got = _posterior(prior_cov, full, compressed.residual, compressed.variance)
    np.testing.assert_allclose(got[0], want[0], rtol=0, atol=1e-10)
    np.testing.assert_allclose(got[1], want[1], rtol=0, atol=1e-10)
    # the same rows given compact (columns listed, in any order) compress to the same rows
    shuffled = rng.permutation(touched)
    compact = MeasurementRows(jacobian[:, cols[shuffled]], residual, variance, cols[shuffled])
    again = compress(compact)
    np.testing.assert_array_equal(again.columns, compressed.columns)
    np.testing.assert_array_equal(again.jacobian, compressed.jacobian)
    np.testing.assert_array_equal(again.residual, compressed.residual)
    # the residual's whitened norm splits into the kept part and what the update cannot use
    assert np.sum(compressed.residual**2) <= np.sum(residual**2 / variance) + 1e-12


def test_fewer_rows_than_columns_are_left_as_they_are():
    rng = np.random.default_rng(7)
    rows = MeasurementRows(rng.normal(size=(5, 12)), rng.normal(size=5), np.full(5, 2.0))
    assert compress(rows) is rows


def test_compact_rows_extend_over_the_union_of_their_columns():
    rng = np.random.default_rng(9)
    h_a = rng.normal(size=(3, 2))
    a = MeasurementRows(h_a.copy(), rng.normal(size=3), np.ones(3), [7, 2])
    b = MeasurementRows(rng.normal(size=(2, 3)), rng.normal(size=2), np.ones(2), [4, 7, 9])
    both = a.extend(b)
    np.testing.assert_array_equal(both.columns, [2, 4, 7, 9])
    np.testing.assert_array_equal(both.full(12), np.vstack([a.full(12), b.full(12)]))
    np.testing.assert_array_equal(a.full(12)[:, [7, 2]], h_a)  # columns kept paired


def test_a_compact_update_is_the_full_width_update_bit_for_bit():
    rng = np.random.default_rng(11)
    dim = 6 * 4 + 3 * 5
    root = rng.normal(size=(dim, dim))
    cov = root @ root.T / dim + 0.05 * np.eye(dim)
    T = se3.exp(0.3 * rng.normal(size=(4, 6)))

    def state():
        return MsckfState.from_arrays(T, np.arange(4), np.arange(5), np.zeros((5, 3)), cov)

    cols = np.array([3, 4, 5, 25, 26, 27, 31])
    h = rng.normal(size=(5, cols.size))
    r, noise = rng.normal(size=5), np.diag(rng.uniform(0.1, 1.0, 5))
    compact, full = state(), state()
    delta = compact.update(h, r, noise, columns=cols)
    wide = np.zeros((5, dim))
    wide[:, cols] = h
    np.testing.assert_array_equal(delta, full.update(wide, r, noise))
    np.testing.assert_array_equal(compact.cov, full.cov)
    with pytest.raises(ValueError, match="read-only"):
        compact.cov[0, 0] = 1.0  # the covariance leaves the state read-only


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
