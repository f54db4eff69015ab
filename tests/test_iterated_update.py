"""Iterated EKF object updates: Gauss–Newton on the prior and the stereo measurement."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import cho_factor, cho_solve
from scipy.optimize import least_squares

from teamslam.errors import InputError
from teamslam.geometry import se3
from teamslam.msckf import MsckfConfig, config_for, run_team
from teamslam.msckf.filter.models import observe, observe_jacobians
from teamslam.msckf.filter.state import MsckfState
from teamslam.sim import lissajous_team


def _scene():
    """One pose and one object 12 m ahead whose prior depth σ is 3 m, and its measurement from
    a second viewpoint 4 m to the side (the object's depth is what that view measures)."""
    team = lissajous_team(robots=1, steps=5, seed=0)
    camera, T_cam_body = team.calibration.camera, team.calibration.T_cam_body
    T_world_body = np.eye(4)
    T_world_body[:3, 3] = [0.0, 4.0, 0.0]
    state = MsckfState(T_world_body, 0, np.eye(6) * 0.05**2)
    p_cam_true = np.array([0.3, -0.2, 12.0])
    T_world_cam = T_world_body @ T_cam_body
    # the object's prior: along the first view's ray, 2.5 m short, σ 3 m along the ray
    ray = T_world_cam[:3, :3] @ (p_cam_true / np.linalg.norm(p_cam_true))
    truth = T_world_cam[:3, :3] @ p_cam_true + T_world_cam[:3, 3] - np.array([0.0, 4.0, 0.0])
    prior = truth - 2.5 * ray
    cov_pp = 3.0**2 * np.outer(ray, ray) + 0.05**2 * np.eye(3)
    cross = np.zeros((3, 6))
    cross[:, :3] = 0.01**2 * np.eye(3)
    state.add_object(7, prior, cov_pp, cross)
    noise = 1.0
    z = observe(camera, T_cam_body, T_world_body, truth[None])[0] + np.array([0.4, -0.3, 0.2, 0.5])
    return state, camera, T_cam_body, z, noise


def _rows_at(state, camera, T_cam_body, z):
    def rows_at():
        pred = observe(camera, T_cam_body, state.current_pose, state.objects)[0]
        _, d_pose, d_point = observe_jacobians(
            camera, T_cam_body, state.current_pose, state.objects
        )
        h = np.zeros((4, state.dim))
        h[:, :6] = d_pose[0]
        h[:, 6:] = d_point[0]
        return h, z - pred, np.full(4, 1.0)

    return rows_at


def _map_estimate(state, camera, T_cam_body, z, noise):
    """The maximum a posteriori error state, by scipy: ``‖δ‖²_P⁻¹ + ‖z − h(x₀ ⊞ δ)‖²/σ²``."""
    whiten = np.linalg.inv(np.linalg.cholesky(state.cov))
    pose0, object0 = state.current_pose.copy(), state.objects[0].copy()

    def residual(delta):
        pose = pose0 @ se3.exp(delta[:6])
        point = object0 + delta[6:]
        return np.concatenate(
            [whiten @ delta, (z - observe(camera, T_cam_body, pose, point[None])[0]) / noise]
        )

    return least_squares(residual, np.zeros(9), xtol=1e-15, ftol=1e-15, gtol=1e-15).x


def test_iterated_update_converges_to_the_map_estimate():
    state, camera, T_cam_body, z, noise = _scene()
    expected = _map_estimate(state, camera, T_cam_body, z, noise)
    ekf, _, _, _, _ = _scene()
    ekf_delta, used = ekf.iterated_update(_rows_at(ekf, camera, T_cam_body, z), 1)
    assert used == 1
    delta, used = state.iterated_update(_rows_at(state, camera, T_cam_body, z), 30, 1e-6)
    assert 3 <= used < 10  # Gauss–Newton: a few linearisations
    # the EKF step is far from the MAP estimate: the test can tell them apart
    assert np.linalg.norm(ekf_delta[6:] - expected[6:]) > 0.05
    # iterated: at the MAP estimate (the iterate's pose Jacobians are taken in its own tangent
    # space, which differs from the chart at the prior by a second-order term)
    np.testing.assert_allclose(delta, expected, atol=1e-7)
    # covariance: the Laplace posterior at the last linearisation, (P⁻¹ + Hᵀ R⁻¹ H)⁻¹
    prior, _, _, _, _ = _scene()
    h, _, _ = _rows_at(state, camera, T_cam_body, z)()
    laplace = np.linalg.inv(np.linalg.inv(prior.cov) + h.T @ h / noise**2)
    np.testing.assert_allclose(state.cov, laplace, rtol=2e-3, atol=1e-9)


def test_one_linearization_is_the_ekf_update():
    state, camera, T_cam_body, z, _ = _scene()
    reference, _, _, _, _ = _scene()
    rows = _rows_at(reference, camera, T_cam_body, z)()
    expected = reference.update(rows[0], rows[1], np.diag(rows[2]))
    delta, used = state.iterated_update(_rows_at(state, camera, T_cam_body, z), 1)
    assert used == 1
    np.testing.assert_array_equal(delta, expected)
    np.testing.assert_array_equal(state.cov, reference.cov)


def test_iteration_count_is_validated():
    with pytest.raises(InputError, match=r"objects\.update_iterations"):
        MsckfConfig.from_settings({"objects.update_iterations": 0})


@pytest.mark.parametrize("linearization", ["std", "fej"])
def test_agent_iterated_update_lowers_the_posterior_cost_every_frame(linearization, monkeypatch):
    """In a running team, every frame's iterated object update lands at a lower value of the
    cost it minimises (prior + object rows, relinearised where it is evaluated) than the EKF
    step from the same prior: the agent relinearises the same rows at the iterate."""
    original = MsckfState.iterated_update
    costs = []

    def cost(state, rows_at, delta, factor, poses, objects):
        state.poses, state.objects = poses, objects
        state.correct(delta)
        rows = rows_at()
        residual, variance = rows.residual, rows.variance
        state.poses, state.objects = poses, objects
        return float(delta @ cho_solve(factor, delta) + np.sum(residual**2 / variance))

    def checked(state, rows_at, iterations, tolerance=1e-2):
        poses, objects, before = state.poses, state.objects, state.snapshot()
        factor = cho_factor(state.cov)
        steps = {}
        for n in (1, iterations):
            ekf_delta, _ = original(state, rows_at, n, 0.0)
            steps[n] = cost(state, rows_at, ekf_delta, factor, poses, objects)
            state.restore(before)
        costs.append((steps[1], steps[iterations]))
        return original(state, rows_at, iterations, tolerance)

    monkeypatch.setattr(MsckfState, "iterated_update", checked)
    team = lissajous_team(robots=1, steps=30, seed=1)
    cfg = config_for(
        team,
        {"filter.window": 6, "filter.linearization": linearization, "objects.update_iterations": 4},
    )
    result = run_team(team, cfg, consensus=False, progress=False)
    costs = np.array(costs)
    assert len(costs) > 20 and result.counters[0]["object_linearizations"] > len(costs)
    assert np.all(costs[:, 1] <= costs[:, 0] + 1e-9)
    assert np.mean(costs[:, 1] < costs[:, 0] - 1e-6) > 0.9
