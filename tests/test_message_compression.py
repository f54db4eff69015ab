"""What makes consensus messages small: variable-length ids, and float32 only where it is safe."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from teamslam.msckf.consensus import FLOAT32_MAX_KL, rounding_divergence
from teamslam.msckf.consensus.messages import (
    HEADER_BYTES,
    CommonMarginalMessage,
    MapIdsMessage,
    decode_ids,
    encode_ids,
    encoded_ids_size,
)
from teamslam.runtime.wire import HEADER, WireError, decode, encode, team_id

TEAM = team_id("compression")
INT64 = (-(2**63), 2**63 - 1)


def test_header_size_is_the_one_messages_count():
    assert HEADER.size == HEADER_BYTES


@given(st.lists(st.integers(*INT64), max_size=60, unique=True))
@settings(max_examples=300, deadline=None)
def test_ids_round_trip_exactly_over_the_whole_int64_range(values):
    ids = np.array(sorted(values), dtype=np.int64)
    data = encode_ids(ids)
    assert len(data) == encoded_ids_size(ids)
    np.testing.assert_array_equal(decode_ids(data, ids.size), ids)


def test_dense_ids_take_one_byte_each():
    ids = np.arange(1000, 1100)
    assert len(encode_ids(ids)) == 2 + 99  # the first id (zigzag 2000) in two bytes
    msg = MapIdsMessage(0, 1, 3, ids, np.zeros(100, dtype=bool))
    data = encode(msg, TEAM)
    assert len(data) == msg.nbytes() == HEADER_BYTES + 101 + 13
    back = decode(data, TEAM, 2)
    np.testing.assert_array_equal(back.ids, ids)


@pytest.mark.parametrize(
    ("data", "count", "reason"),
    [
        (bytes([0x80]), 1, "complete ids"),  # the varint never ends
        (bytes([0x02, 0x00]), 2, "not strictly increasing"),  # a zero difference
        (bytes([0xFF] * 9 + [0x7F]), 1, "longer than 64 bits"),
        (bytes([0xFF] * 11), 1, "complete ids"),
        (bytes([0x02, 0x04]), 1, "complete ids"),  # more ids than the header says
        (bytes([0xFE] + [0xFF] * 8 + [0x01, 0x02]), 2, "64-bit range"),  # 2^63-1, then past it
    ],
)
def test_bad_id_bytes_are_named(data, count, reason):
    with pytest.raises(ValueError, match=reason):
        decode_ids(data, count)


def test_the_wire_refuses_ids_that_are_not_increasing():
    unsorted = MapIdsMessage(0, 1, 3, np.array([5, 2, 9]))
    with pytest.raises(WireError, match="strictly increasing"):
        encode(unsorted, TEAM)
    good = bytearray(encode(MapIdsMessage(0, 1, 3, np.array([2, 5, 9])), TEAM))
    good[HEADER_BYTES + 1] = 0  # a zero difference: a repeated id
    with pytest.raises(WireError, match="bad ids"):
        decode(bytes(good), TEAM, 2)


def _kl(mean_1, cov_1, mean_0, cov_0):
    info = np.linalg.inv(cov_0)
    diff = mean_1 - mean_0
    _, logdet_0 = np.linalg.slogdet(cov_0)
    _, logdet_1 = np.linalg.slogdet(cov_1)
    return 0.5 * (np.trace(info @ cov_1) - mean_1.size + diff @ info @ diff + logdet_0 - logdet_1)


@pytest.mark.parametrize("scale", [1e-3, 1e-5])
def test_rounding_divergence_is_the_kl_divergence(scale):
    rng = np.random.default_rng(3)
    a = rng.normal(size=(9, 9))
    cov = a @ a.T + 0.2 * np.eye(9)
    mean = 50 * rng.normal(size=9)
    d_cov = scale * rng.normal(size=(9, 9))
    d_cov = d_cov + d_cov.T
    d_mean = scale * rng.normal(size=9)
    got = rounding_divergence(mean, cov, mean + d_mean, cov + d_cov)
    assert got == pytest.approx(_kl(mean + d_mean, cov + d_cov, mean, cov), rel=1e-2)
    blocks = np.stack([cov[:3, :3], cov[3:6, 3:6], cov[6:, 6:]])
    d_blocks = np.stack([d_cov[:3, :3], d_cov[3:6, 3:6], d_cov[6:, 6:]])
    exact = sum(
        _kl(mean[s] + d_mean[s], blocks[i] + d_blocks[i], mean[s], blocks[i])
        for i, s in enumerate((slice(0, 3), slice(3, 6), slice(6, 9)))
    )
    assert rounding_divergence(mean, blocks, mean + d_mean, blocks + d_blocks) == pytest.approx(
        exact, rel=1e-2
    )


class _State:
    """Just what :func:`common_marginal_message` reads from a state."""

    def __init__(self, objects, cov):
        self.objects = objects
        self.cov = cov
        self.object_ids = np.arange(len(objects)) * 3
        self.n_poses = 0

    def object_slots(self, ids):
        return np.where(np.isin(ids, self.object_ids), np.asarray(ids) // 3, -1)

    def object(self, slots):
        return SimpleNamespace(columns=3 * np.asarray(slots)[..., None] + np.arange(3))

    def covariance(self, columns):
        columns = np.asarray(columns)
        return self.cov[columns[..., :, None], columns[..., None, :]]


def test_float32_only_where_rounding_is_harmless():
    from teamslam.msckf.consensus import common_marginal_message

    rng = np.random.default_rng(5)
    objects = 20 * rng.normal(size=(4, 3))
    a = rng.normal(size=(12, 12))
    well = 0.01 * (a @ a.T + 12 * np.eye(12))
    msg = common_marginal_message(_State(objects, well), 0, 1, 2, [9, 0, 3], float32=True)
    assert msg.single_precision
    np.testing.assert_array_equal(msg.ids, [0, 3, 9])  # increasing, as the wire carries them
    exact = common_marginal_message(_State(objects, well), 0, 1, 2, [0, 3, 9])
    assert rounding_divergence(exact.mean, exact.cov, msg.mean, msg.cov) <= FLOAT32_MAX_KL
    # nearly singular (two objects almost rigidly tied): float32 would change it a lot
    u = rng.normal(size=(12, 2))
    tight = u @ u.T + 1e-9 * np.eye(12)
    msg = common_marginal_message(_State(objects, tight), 0, 1, 2, [0, 3, 9], float32=True)
    assert not msg.single_precision
    rounded = msg.cov.astype(np.float32).astype(float)
    assert rounding_divergence(msg.mean, msg.cov, msg.mean, rounded) > FLOAT32_MAX_KL
    back = decode(encode(msg, TEAM), TEAM, 2)
    assert isinstance(back, CommonMarginalMessage)
    np.testing.assert_array_equal(back.cov, msg.cov)


def test_the_joint_bound_is_above_the_divergence_and_close_to_it():
    from teamslam.msckf.consensus import rounding_divergence_bound

    rng = np.random.default_rng(8)
    for d in (6, 30, 90):
        a = rng.normal(size=(d, d))
        cov = a @ a.T / d + np.diag(rng.uniform(1e-4, 1.0, d))
        mean = 30 * rng.normal(size=d)
        cov32 = cov.astype(np.float32).astype(float)
        mean32 = mean.astype(np.float32).astype(float)
        exact = rounding_divergence(mean, cov, mean32, cov32)
        bound = rounding_divergence_bound(mean, cov, mean32, cov32)
        assert exact <= bound <= 1e4 * exact
    not_pd = -np.eye(3)
    assert rounding_divergence_bound(np.zeros(3), not_pd, np.zeros(3), not_pd) == np.inf


def test_the_information_form_bound_is_above_the_divergence():
    """Rounding a marginal's information matrix and mean to float32: the O(d²) bound is never
    below the divergence (second order, ``¼‖Lᵀ ΔΩ L‖²_F + ½ Δμᵀ Ω Δμ`` with ``Σ = L Lᵀ``) and
    not wildly above it; a marginal too ill-conditioned for float32 is caught."""
    from teamslam.msckf.consensus import information_rounding_bound

    rng = np.random.default_rng(9)
    for d, spread in ((6, 0.0), (30, 0.0), (90, 0.0), (30, 3.0), (90, 3.0)):
        a = rng.normal(size=(d, d))
        cov = a @ a.T / d + np.diag(rng.uniform(1e-4, 1.0, d))
        # objects known very differently well (standard deviations over e^±spread): the bound
        # scales by the standard deviations first, so it stays close
        scale = np.exp(rng.uniform(-spread, spread, d))
        cov = cov * np.outer(scale, scale)
        info = np.linalg.inv(cov)
        info = 0.5 * (info + info.T)
        mean = 30 * rng.normal(size=d)
        info32 = info.astype(np.float32).astype(float)
        mean32 = mean.astype(np.float32).astype(float)
        lower = np.linalg.cholesky(cov)
        whitened = lower.T @ (info32 - info) @ lower
        exact = 0.25 * np.sum(whitened**2) + 0.5 * (mean32 - mean) @ info @ (mean32 - mean)
        # the same divergence through the moment form (the rounded information inverted)
        cov32 = np.linalg.inv(info32)
        assert rounding_divergence(mean, cov, mean32, 0.5 * (cov32 + cov32.T)) == pytest.approx(
            exact, rel=0.05
        )
        bound = information_rounding_bound(mean, cov, info, mean32, info32)
        assert exact <= bound <= 1e2 * exact
    u = rng.normal(size=(12, 2))
    tight = u @ u.T + 1e-9 * np.eye(12)
    info = np.linalg.inv(tight)
    rounded = info.astype(np.float32).astype(float)
    assert information_rounding_bound(np.zeros(12), tight, info, np.zeros(12), rounded) > (
        FLOAT32_MAX_KL
    )
