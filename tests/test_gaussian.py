"""Gaussian core: marginals, conditionals, replace-a-marginal (Prop. 2), averaging (eq. 15)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from teamslam.gaussian import (
    Gaussian,
    InformationGaussian,
    NotPositiveDefiniteError,
    geometric_average,
    geometric_average_arrays,
    replace_marginal,
    spd_inverse,
)


def random_gaussian(rng: np.random.Generator, dim: int) -> Gaussian:
    a = rng.normal(size=(dim, dim))
    return Gaussian(rng.normal(size=dim), a @ a.T + 0.5 * np.eye(dim))


def random_index(rng: np.random.Generator, dim: int, size: int) -> np.ndarray:
    return rng.permutation(dim)[:size]


@given(st.integers(0, 10_000), st.integers(2, 9), st.data())
@settings(max_examples=60, deadline=None)
def test_replace_marginal_keeps_conditional(seed, dim, data):
    rng = np.random.default_rng(seed)
    size = data.draw(st.integers(1, dim - 1))
    joint = random_gaussian(rng, dim)
    iy = random_index(rng, dim, size)
    new = random_gaussian(rng, size)
    out = replace_marginal(joint, iy, new)
    # the y marginal is the new one
    np.testing.assert_allclose(out.marginal(iy).mean, new.mean, atol=1e-10)
    np.testing.assert_allclose(out.marginal(iy).cov, new.cov, atol=1e-10)
    # p(x | y) is unchanged at any y
    y = rng.normal(size=size)
    before, after = joint.conditional(iy, y), out.conditional(iy, y)
    np.testing.assert_allclose(after.mean, before.mean, atol=1e-8)
    np.testing.assert_allclose(after.cov, before.cov, atol=1e-8)
    # and the result is a valid covariance
    assert np.all(np.linalg.eigvalsh(out.cov) > 0)


def test_replace_marginal_matches_equation_14():
    rng = np.random.default_rng(1)
    joint = random_gaussian(rng, 5)
    ix, iy = np.array([0, 1, 2]), np.array([3, 4])
    new = random_gaussian(rng, 2)
    sx, sxy, sy = joint.cov[:3, :3], joint.cov[:3, 3:], joint.cov[3:, 3:]
    a = sxy @ np.linalg.inv(sy)
    b = joint.mean[ix] - a @ joint.mean[iy]
    p = sx - a @ sxy.T
    out = joint.replace_marginal(iy, new)
    np.testing.assert_allclose(out.mean[ix], a @ new.mean + b, atol=1e-12)
    np.testing.assert_allclose(out.cov[:3, :3], a @ new.cov @ a.T + p, atol=1e-12)
    np.testing.assert_allclose(out.cov[:3, 3:], a @ new.cov, atol=1e-12)


def test_replacing_with_own_marginal_is_identity():
    rng = np.random.default_rng(2)
    joint = random_gaussian(rng, 6)
    iy = [4, 1]
    out = joint.replace_marginal(iy, joint.marginal(iy))
    np.testing.assert_allclose(out.mean, joint.mean, atol=1e-12)
    np.testing.assert_allclose(out.cov, joint.cov, atol=1e-12)


def test_averaging_identical_marginals_is_a_no_op():
    rng = np.random.default_rng(3)
    g = random_gaussian(rng, 4)
    avg = geometric_average([g, g, g], [0.2, 0.5, 0.3])
    np.testing.assert_allclose(avg.mean, g.mean, atol=1e-12)
    np.testing.assert_allclose(avg.cov, g.cov, atol=1e-12)


def test_average_information_is_the_weighted_sum():
    rng = np.random.default_rng(4)
    parts = [random_gaussian(rng, 3) for _ in range(4)]
    w = np.array([0.1, 0.4, 0.3, 0.2])
    avg = geometric_average(parts, w)
    info = sum(wi * np.linalg.inv(p.cov) for wi, p in zip(w, parts, strict=True))
    vec = sum(wi * np.linalg.inv(p.cov) @ p.mean for wi, p in zip(w, parts, strict=True))
    np.testing.assert_allclose(np.linalg.inv(avg.cov), info, rtol=1e-10)
    np.testing.assert_allclose(np.linalg.inv(avg.cov) @ avg.mean, vec, rtol=1e-10, atol=1e-12)


def test_average_of_scalars_by_hand():
    # N(0, 1) and N(2, 4) with equal weights: info 0.5·1 + 0.5·0.25 = 0.625
    mean, cov = geometric_average_arrays(
        np.array([[0.0], [2.0]]), np.array([[[1.0]], [[4.0]]]), np.array([0.5, 0.5])
    )
    assert cov[0, 0] == pytest.approx(1 / 0.625)
    assert mean[0] == pytest.approx((0.5 * 0.25 * 2.0) / 0.625)


def test_information_form_round_trip_marginal_and_conditional():
    rng = np.random.default_rng(5)
    g = random_gaussian(rng, 6)
    info = g.information()
    back = info.moment()
    np.testing.assert_allclose(back.mean, g.mean, atol=1e-10)
    np.testing.assert_allclose(back.cov, g.cov, atol=1e-10)
    idx = [5, 0, 2]
    m_info = info.marginal(idx).moment()
    np.testing.assert_allclose(m_info.mean, g.marginal(idx).mean, atol=1e-10)
    np.testing.assert_allclose(m_info.cov, g.marginal(idx).cov, atol=1e-10)
    y = rng.normal(size=3)
    c_info = info.conditional(idx, y).moment()
    c_mom = g.conditional(idx, y)
    np.testing.assert_allclose(c_info.mean, c_mom.mean, atol=1e-10)
    np.testing.assert_allclose(c_info.cov, c_mom.cov, atol=1e-10)


def test_bad_inputs_are_named():
    with pytest.raises(ValueError, match="NaN"):
        Gaussian(np.array([0.0, np.nan]), np.eye(2))
    with pytest.raises(ValueError, match="does not match"):
        Gaussian(np.zeros(2), np.eye(3))
    with pytest.raises(NotPositiveDefiniteError, match="not positive definite"):
        spd_inverse(np.array([[1.0, 2.0], [2.0, 1.0]]))
    with pytest.raises(ValueError, match="sum to 1"):
        geometric_average([Gaussian(np.zeros(1), np.eye(1))] * 2, [0.5, 0.6])
    with pytest.raises(IndexError, match="repeated"):
        Gaussian(np.zeros(3), np.eye(3)).marginal([1, 1])
    with pytest.raises(ValueError, match="size"):
        Gaussian(np.zeros(3), np.eye(3)).replace_marginal([0], Gaussian(np.zeros(2), np.eye(2)))
    with pytest.raises(NotPositiveDefiniteError):
        InformationGaussian(np.zeros(2), -np.eye(2)).moment()


def test_sample_statistics():
    rng = np.random.default_rng(6)
    g = random_gaussian(rng, 3)
    x = g.sample(rng, 200_000)
    np.testing.assert_allclose(x.mean(0), g.mean, atol=0.03)
    np.testing.assert_allclose(np.cov(x.T), g.cov, rtol=0.03, atol=0.03)
