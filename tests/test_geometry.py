"""Lie-group geometry: round trips, scipy agreement, Jacobians against finite differences."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from teamslam.geometry import se2, se3, so3
from teamslam.testing import numerical_jacobian

finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)


def rotation_vectors(max_angle: float = np.pi - 1e-6):
    """Rotation vectors with angle in [0, max_angle]."""
    return st.builds(
        lambda axis, angle: (
            angle * axis / max(np.linalg.norm(axis), 1e-300)
            if np.linalg.norm(axis) > 1e-6
            else np.zeros(3)
        ),
        arrays(np.float64, 3, elements=st.floats(-1, 1)),
        st.floats(0.0, max_angle),
    )


def twists():
    return st.builds(
        lambda rho, phi: np.concatenate([rho, phi]),
        arrays(np.float64, 3, elements=st.floats(-20, 20)),
        rotation_vectors(),
    )


# ---------------------------------------------------------------- SO(3)
@given(rotation_vectors())
@settings(max_examples=300, deadline=None)
def test_so3_exp_log_round_trip(phi):
    np.testing.assert_allclose(so3.log(so3.exp(phi)), phi, atol=1e-9)


@given(rotation_vectors())
@settings(max_examples=200, deadline=None)
def test_so3_exp_matches_scipy(phi):
    np.testing.assert_allclose(so3.exp(phi), Rotation.from_rotvec(phi).as_matrix(), atol=1e-12)


def test_so3_log_matches_scipy_on_random_rotations():
    rotations = Rotation.random(2000, random_state=1)
    ours = so3.log(rotations.as_matrix())
    theirs = rotations.as_rotvec()
    np.testing.assert_allclose(so3.exp(ours), rotations.as_matrix(), atol=1e-12)
    np.testing.assert_allclose(ours, theirs, atol=1e-9)


def test_so3_exp_is_a_rotation_and_batched():
    phi = np.random.default_rng(0).normal(size=(4, 5, 3))
    r = so3.exp(phi)
    assert r.shape == (4, 5, 3, 3)
    np.testing.assert_allclose(
        r @ np.swapaxes(r, -1, -2), np.broadcast_to(np.eye(3), r.shape), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)
    np.testing.assert_allclose(so3.exp(phi[1, 2]), r[1, 2])


@pytest.mark.parametrize("angle", [0.0, 1e-12, 1e-8, 1e-5, 1e-3, 0.0999, 0.1, 0.1001])
def test_so3_small_angles(angle):
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    phi = angle * axis
    np.testing.assert_allclose(so3.exp(phi), Rotation.from_rotvec(phi).as_matrix(), atol=1e-15)
    np.testing.assert_allclose(so3.log(so3.exp(phi)), phi, atol=1e-15)
    # the series branch and the direct branch agree across the threshold
    np.testing.assert_allclose(
        so3.left_jacobian(phi) @ so3.left_jacobian_inverse(phi), np.eye(3), atol=1e-14
    )


@pytest.mark.parametrize("gap", [0.0, 1e-12, 1e-9, 1e-6, 1e-3, 0.1])
def test_so3_near_pi(gap):
    rng = np.random.default_rng(3)
    for _ in range(20):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        phi = (np.pi - gap) * axis
        r = so3.exp(phi)
        back = so3.log(r)
        np.testing.assert_allclose(so3.exp(back), r, atol=1e-12)
        if gap > 0:
            np.testing.assert_allclose(back, phi, atol=1e-7)
        else:  # at exactly π, either sign of the axis is the same rotation
            assert np.isclose(np.linalg.norm(back), np.pi)


def test_so3_hat_vee():
    phi = np.array([1.0, -2.0, 3.0])
    v = np.array([0.5, 0.1, -0.7])
    np.testing.assert_allclose(so3.hat(phi) @ v, np.cross(phi, v))
    np.testing.assert_allclose(so3.vee(so3.hat(phi)), phi)


def _so3_plus(r, d):
    return r @ so3.exp(d)


@given(rotation_vectors(max_angle=3.0))
@settings(max_examples=60, deadline=None)
def test_so3_jacobians_match_finite_differences(phi):
    # exp(φ + δ) ≈ exp(J_l δ) exp(φ)  and  ≈ exp(φ) exp(J_r δ)
    left = numerical_jacobian(lambda p: so3.exp(p), phi, 3, minus=lambda a, b: so3.log(a @ b.T))
    right = numerical_jacobian(lambda p: so3.exp(p), phi, 3, minus=lambda a, b: so3.log(b.T @ a))
    np.testing.assert_allclose(so3.left_jacobian(phi), left, atol=1e-7)
    np.testing.assert_allclose(so3.right_jacobian(phi), right, atol=1e-7)
    np.testing.assert_allclose(so3.left_jacobian_inverse(phi) @ left, np.eye(3), atol=1e-6)
    np.testing.assert_allclose(so3.right_jacobian_inverse(phi) @ right, np.eye(3), atol=1e-6)
    # the adjoint: R exp(δ) Rᵀ = exp(R δ)
    r = so3.exp(phi)
    ad = numerical_jacobian(
        lambda d: r @ so3.exp(d) @ r.T, np.zeros(3), 3, minus=lambda a, b: so3.log(a @ b.T)
    )
    np.testing.assert_allclose(so3.adjoint(r), ad, atol=1e-8)


# ---------------------------------------------------------------- SE(3)
@given(twists())
@settings(max_examples=300, deadline=None)
def test_se3_exp_log_round_trip(xi):
    np.testing.assert_allclose(se3.log(se3.exp(xi)), xi, atol=1e-8)


@given(twists())
@settings(max_examples=100, deadline=None)
def test_se3_exp_matches_matrix_exponential(xi):
    from scipy.linalg import expm

    np.testing.assert_allclose(se3.exp(xi), expm(se3.hat(xi)), atol=1e-9)


def test_se3_inverse_compose_and_batching():
    rng = np.random.default_rng(5)
    xi = rng.normal(size=(7, 6))
    t = se3.exp(xi)
    eye = np.broadcast_to(np.eye(4), t.shape)
    np.testing.assert_allclose(se3.compose(t, se3.inverse(t)), eye, atol=1e-12)
    np.testing.assert_allclose(se3.inverse(t), np.linalg.inv(t), atol=1e-12)
    np.testing.assert_allclose(se3.vee(se3.hat(xi)), xi)
    assert se3.left_jacobian(xi.reshape(7, 1, 6)).shape == (7, 1, 6, 6)


@given(twists())
@settings(max_examples=60, deadline=None)
def test_se3_jacobians_match_finite_differences(xi):
    left = numerical_jacobian(se3.exp, xi, 6, minus=lambda a, b: se3.log(a @ se3.inverse(b)))
    right = numerical_jacobian(se3.exp, xi, 6, minus=lambda a, b: se3.log(se3.inverse(b) @ a))
    np.testing.assert_allclose(se3.left_jacobian(xi), left, atol=2e-6)
    np.testing.assert_allclose(se3.right_jacobian(xi), right, atol=2e-6)
    np.testing.assert_allclose(
        se3.left_jacobian_inverse(xi), np.linalg.inv(se3.left_jacobian(xi)), atol=1e-7
    )
    np.testing.assert_allclose(
        se3.right_jacobian_inverse(xi), np.linalg.inv(se3.right_jacobian(xi)), atol=1e-7
    )


def test_se3_adjoint_block_placement():
    """Translation-first ordering puts t^R in the upper-right block: T exp(ε) T⁻¹ = exp(Ad ε)."""
    t = se3.exp(np.array([1.0, -2.0, 0.5, 0.3, -0.2, 0.9]))
    eps = np.array([0.01, 0.02, -0.03, 0.004, -0.005, 0.006])
    lhs = t @ se3.exp(eps) @ se3.inverse(t)
    np.testing.assert_allclose(lhs, se3.exp(se3.adjoint(t) @ eps), atol=1e-12)
    ad = se3.adjoint(t)
    np.testing.assert_allclose(ad[3:, :3], 0.0)
    np.testing.assert_allclose(ad[:3, 3:], so3.hat(t[:3, 3]) @ t[:3, :3])
    numeric = numerical_jacobian(
        lambda e: t @ se3.exp(e) @ se3.inverse(t),
        np.zeros(6),
        6,
        minus=lambda a, b: se3.log(a @ se3.inverse(b)),
    )
    np.testing.assert_allclose(ad, numeric, atol=1e-8)


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-4, 0.05, 0.0999, 0.1001, np.pi - 1e-7])
def test_se3_jacobian_branches(angle):
    axis = np.array([0.6, 0.0, 0.8])
    xi = np.concatenate([[3.0, -1.0, 2.0], angle * axis])
    np.testing.assert_allclose(se3.log(se3.exp(xi)), xi, atol=1e-8)
    np.testing.assert_allclose(
        se3.left_jacobian(xi) @ se3.left_jacobian_inverse(xi), np.eye(6), atol=1e-9
    )
    right = numerical_jacobian(se3.exp, xi, 6, minus=lambda a, b: se3.log(se3.inverse(b) @ a))
    np.testing.assert_allclose(se3.right_jacobian(xi), right, atol=2e-6)


def test_shape_errors_are_clear():
    with pytest.raises(ValueError, match="size 6"):
        se3.exp(np.zeros(5))
    with pytest.raises(ValueError, match=r"\(\.\.\., 3, 3\)"):
        so3.log(np.eye(4))
    with pytest.raises(ValueError, match="size 3"):
        se2.exp(np.zeros(4))


# ---------------------------------------------------------------- SE(2)
planar = st.builds(
    lambda r, th: np.array([r[0], r[1], th]),
    arrays(np.float64, 2, elements=st.floats(-50, 50)),
    st.floats(-np.pi + 1e-6, np.pi - 1e-6),
)


@given(planar)
@settings(max_examples=300, deadline=None)
def test_se2_exp_log_round_trip(xi):
    np.testing.assert_allclose(se2.log(se2.exp(xi)), xi, atol=1e-8)


@given(planar)
@settings(max_examples=100, deadline=None)
def test_se2_matches_matrix_exponential_and_xytheta(xi):
    from scipy.linalg import expm

    np.testing.assert_allclose(se2.exp(xi), expm(se2.hat(xi)), atol=1e-9)
    pose = np.array([xi[0], xi[1], xi[2]])
    np.testing.assert_allclose(se2.to_xytheta(se2.from_xytheta(pose)), pose, atol=1e-12)


@given(planar)
@settings(max_examples=80, deadline=None)
def test_se2_jacobians_match_finite_differences(xi):
    left = numerical_jacobian(se2.exp, xi, 3, minus=lambda a, b: se2.log(a @ se2.inverse(b)))
    right = numerical_jacobian(se2.exp, xi, 3, minus=lambda a, b: se2.log(se2.inverse(b) @ a))
    np.testing.assert_allclose(se2.left_jacobian(xi), left, atol=1e-6)
    np.testing.assert_allclose(se2.right_jacobian(xi), right, atol=1e-6)
    np.testing.assert_allclose(
        se2.left_jacobian_inverse(xi) @ se2.left_jacobian(xi), np.eye(3), atol=1e-9
    )
    np.testing.assert_allclose(
        se2.right_jacobian_inverse(xi) @ se2.right_jacobian(xi), np.eye(3), atol=1e-9
    )
    t = se2.exp(xi)
    ad = numerical_jacobian(
        lambda e: t @ se2.exp(e) @ se2.inverse(t),
        np.zeros(3),
        3,
        minus=lambda a, b: se2.log(a @ se2.inverse(b)),
    )
    np.testing.assert_allclose(se2.adjoint(t), ad, atol=1e-7)


@pytest.mark.parametrize("theta", [0.0, 1e-10, 1e-5, -1e-5, 0.0999, -0.1001, np.pi - 1e-9])
def test_se2_small_and_large_angles(theta):
    xi = np.array([2.0, -3.0, theta])
    np.testing.assert_allclose(se2.log(se2.exp(xi)), xi, atol=1e-9)
    np.testing.assert_allclose(se2.wrap_angle(theta + 2 * np.pi), theta, atol=1e-9)
