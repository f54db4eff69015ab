"""The compiled per-message passes of consensus give the numbers of the numpy expressions
they replace, bit for bit (or, for a sum, to rounding), and the same verdicts."""

from __future__ import annotations

import numpy as np

from teamslam._gaussian_kernels import (
    add_weighted_difference_at,
    rebuilt_joint,
)
from teamslam.gaussian import add_weighted_difference, spd_inverse, symmetrize
from teamslam.msckf.consensus.kernels import (
    FINITE,
    NON_FINITE,
    NOT_SYMMETRIC,
    all_single,
    checked_symmetric_part,
    encoded_ids_bytes,
    merged_record,
    single_rounding,
    symmetric_block,
)
from teamslam.msckf.consensus.messages import encode_ids


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


def _numpy_rounding_bound(mean, cov, info, mean32, info32):
    """The estimate of ``information_rounding_bound`` written out in numpy."""
    std = np.sqrt(np.diagonal(cov))
    scale = np.outer(std, std)
    correlation_norm = (np.abs(cov) / scale).sum(axis=0).max()
    scaled_info_norm = (np.abs(info) * scale).sum(axis=0).max()
    d_info = np.sum(((info32 - info) * scale) ** 2)
    d_mean = np.sum(((mean32 - mean) / std) ** 2)
    return 0.25 * correlation_norm**2 * d_info + 0.5 * scaled_info_norm * d_mean


def test_single_rounding_is_the_float32_rounding_and_its_bound():
    rng = np.random.default_rng(2)
    for d in (3, 30, 90):
        # objects known to very different precisions, as in a team's joint marginal
        scales = np.exp(rng.uniform(-4, 4, size=d))
        cov = _spd(rng, d) * np.outer(scales, scales)
        info = np.linalg.inv(cov)
        mean = rng.normal(size=d) * 100
        mean32, info32, bound = single_rounding(mean, cov, info)
        assert np.array_equal(mean32, mean.astype(np.float32).astype(float))
        assert np.array_equal(info32, info.astype(np.float32).astype(float))
        assert bound > 0
        assert np.isclose(bound, _numpy_rounding_bound(mean, cov, info, mean32, info32), rtol=1e-12)


def test_add_weighted_difference_at_is_the_numpy_scatter_add():
    rng = np.random.default_rng(3)
    d = 60
    info, eta = _spd(rng, d), rng.normal(size=d)
    sub = np.sort(rng.choice(d, size=24, replace=False))
    their, own = _spd(rng, 24), _spd(rng, 24)
    their_eta, own_eta = rng.normal(size=24), rng.normal(size=24)
    want_info, want_eta = info.copy(), eta.copy()
    add_weighted_difference(
        want_info, want_eta, np.ix_(sub, sub), sub, 0.3, (their, their_eta), (own, own_eta)
    )
    add_weighted_difference_at(info, eta, sub, 0.3, their, their_eta, own, own_eta)
    assert np.array_equal(info, want_info) and np.array_equal(eta, want_eta)


def test_encoded_ids_bytes_is_the_length_of_the_written_varints():
    rng = np.random.default_rng(4)
    extremes = np.array([-(2**63), -1, 0, 1, 2**63 - 1], dtype=np.int64)
    for trial in range(300):
        low = (-(2**63), -1000, 0, 2**40)[trial % 4]
        high = 2**63 - 1 if trial % 3 else low + 10**6
        ids = np.unique(rng.integers(low, high, size=rng.integers(0, 40), dtype=np.int64))
        assert encoded_ids_bytes(ids) == len(encode_ids(ids))
    assert encoded_ids_bytes(extremes) == len(encode_ids(extremes))
    assert encoded_ids_bytes(np.array([4, 4], dtype=np.int64)) == -1
    assert encoded_ids_bytes(np.array([5, 2], dtype=np.int64)) == -1


def test_all_single_is_exact_float32_equality():
    rng = np.random.default_rng(5)
    single = rng.normal(size=(20, 20)).astype(np.float32).astype(float)
    assert all_single(single)
    for value in (1.0 + 2.0**-40, np.nan, 1e300):
        changed = single.copy()
        changed[7, 3] = value
        assert not all_single(changed)
        with np.errstate(over="ignore"):  # 1e300 is no float32: it rounds to inf
            assert not np.array_equal(changed.astype(np.float32), changed)
    changed = single.copy()
    changed[0, 0] = np.inf  # inf is a float32
    assert all_single(changed)


def test_symmetric_block_is_the_gathered_symmetric_part_and_inverts_alike():
    rng = np.random.default_rng(6)
    matrix = _spd(rng, 50)
    matrix += 1e-12 * rng.normal(size=(50, 50))  # not exactly symmetric
    index = rng.permutation(50)[:21]
    block = symmetric_block(matrix, index)
    want = symmetrize(matrix[np.ix_(index, index)])
    assert np.array_equal(block, want)
    assert np.array_equal(spd_inverse(block, symmetric=True), spd_inverse(want))


def test_rebuilt_joint_is_the_assembled_and_permuted_joint():
    rng = np.random.default_rng(8)
    n = 40
    cov = _spd(rng, n)
    iy = rng.permutation(n)[:25]
    ix = np.setdiff1d(np.arange(n), iy)
    correction = rng.normal(size=(ix.size, ix.size))
    new_xy, new_y = rng.normal(size=(ix.size, iy.size)), _spd(rng, iy.size)
    # numpy: [x, y] blocks in order, then every row and column put back
    ordered = np.block([[symmetrize(cov[np.ix_(ix, ix)] + correction), new_xy], [new_xy.T, new_y]])
    back = np.empty(n, dtype=np.intp)
    back[np.concatenate([ix, iy])] = np.arange(n)
    want = ordered[np.ix_(back, back)]
    assert np.array_equal(rebuilt_joint(cov, ix, iy, correction, new_xy, new_y), want)


def _numpy_record(old, ids, means, covs, exchanged, step):
    """The record of a link after an exchange, the numpy way: concatenate and sort."""
    take = np.isin(ids, exchanged)
    now = np.full(int(take.sum()), step, dtype=np.int64)
    keep = np.isin(old[0], ids) & ~np.isin(old[0], exchanged)
    new = [
        np.concatenate([kept[keep], fresh])
        for kept, fresh in zip(old, (ids[take], means[take], covs[take], now), strict=True)
    ]
    order = np.argsort(new[0])
    return tuple(a[order] for a in new)


def test_merged_record_keeps_the_untouched_objects_and_renews_the_exchanged_ones():
    rng = np.random.default_rng(7)
    empty = (np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros(0, np.int64))
    old, ages = empty, 0
    for step in range(12):
        ids = np.sort(rng.choice(60, size=rng.integers(30, 55), replace=False)).astype(np.int64)
        means, covs = rng.normal(size=(ids.size, 3)), rng.normal(size=(ids.size, 3, 3))
        exchanged = np.sort(rng.choice(60, size=rng.integers(0, 30), replace=False))
        exchanged = exchanged.astype(np.int64)
        got = merged_record(*old, ids, means, covs, exchanged, step)
        want = _numpy_record(old, ids, means, covs, exchanged, step)
        for a, b in zip(got, want, strict=True):
            assert np.array_equal(a, b)
        assert np.all(np.diff(got[0]) > 0)
        ages = max(ages, np.unique(got[3]).size)
        old = got
    assert ages > 1  # records of earlier steps were kept beside the new ones
