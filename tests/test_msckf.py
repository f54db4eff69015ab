"""The distributed MSCKF: Jacobians, state edits, consensus, team runs."""

from __future__ import annotations

import numpy as np
import pytest

from teamslam.eval.metrics import team_metrics
from teamslam.gaussian import geometric_average_arrays
from teamslam.geometry import se3
from teamslam.graph import from_edges
from teamslam.msckf import MsckfState, config_for, run_team
from teamslam.msckf.consensus import consensus_average, validate_marginal
from teamslam.msckf.consensus.messages import CommonMarginalMessage
from teamslam.msckf.filter.models import observe, observe_jacobians
from teamslam.msckf.filter.update import householder_project, triangulate
from teamslam.sim import lissajous_team
from teamslam.sim.lissajous import T_CAM_BODY
from teamslam.testing import numerical_jacobian, se3_plus


@pytest.fixture(scope="module")
def camera():
    return lissajous_team(robots=1, steps=2, landmarks=5, objects=2).calibration.camera


def test_stereo_observation_jacobians_match_finite_differences(camera):
    rng = np.random.default_rng(0)
    for _ in range(10):
        pose = se3.exp(rng.normal(size=6) * np.array([3, 3, 1, 0.3, 0.3, 1.0]))
        # a point in front of the camera (body x forward)
        p_body = np.array([rng.uniform(4, 20), rng.uniform(-3, 3), rng.uniform(-2, 2)])
        p_world = pose[:3, :3] @ p_body + pose[:3, 3]
        _, d_pose, d_point = observe_jacobians(camera, T_CAM_BODY, pose, p_world)
        num_pose = numerical_jacobian(
            lambda t: observe(camera, T_CAM_BODY, t, p_world), pose, 6, plus=se3_plus
        )
        num_point = numerical_jacobian(lambda p: observe(camera, T_CAM_BODY, pose, p), p_world, 3)
        np.testing.assert_allclose(d_pose, num_pose, rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(d_point, num_point, rtol=1e-5, atol=1e-5)


def test_augment_uses_the_adjoint_of_the_inverse_step():
    """ε_new = Ad(δT⁻¹) ε_last: the propagated covariance equals finite differences."""
    rng = np.random.default_rng(1)
    last = se3.exp(rng.normal(size=6))
    step = se3.exp(np.array([1.0, 0.1, -0.05, 0.02, -0.03, 0.2]))
    cov = np.diag(rng.uniform(0.01, 0.1, 6))
    state = MsckfState(last, 0, cov, debug=True)
    state.augment(step, 1, np.zeros((6, 6)) + 1e-12 * np.eye(6))
    jac = numerical_jacobian(
        lambda t: t @ step, last, 6, plus=se3_plus, minus=lambda a, b: se3.log(se3.inverse(b) @ a)
    )
    np.testing.assert_allclose(state.cov[6:, 6:], jac @ cov @ jac.T, atol=1e-9)
    np.testing.assert_allclose(state.cov[6:, :6], jac @ cov, atol=1e-9)
    np.testing.assert_allclose(state.poses[1], last @ step)


def test_triangulation_and_null_space(camera):
    rng = np.random.default_rng(2)
    poses = np.stack([se3.exp(np.array([k * 1.0, 0, 0, 0, 0, 0.02 * k])) for k in range(5)])
    point = np.array([15.0, 2.0, 1.0])
    z = observe(camera, T_CAM_BODY, poses, point)
    est, ok, rms = triangulate(camera, T_CAM_BODY, poses[None], z[None] + 0.0)
    assert ok[0] and rms[0] < 1e-9
    np.testing.assert_allclose(est[0], point, atol=1e-8)
    # the projected rows are orthogonal to the point Jacobian
    h_f = rng.normal(size=(3, 12, 3))
    rest = rng.normal(size=(3, 12, 5))
    upper, projected = householder_project(h_f, np.concatenate([h_f, rest], axis=2))
    np.testing.assert_allclose(projected[:, 3:, :3], 0.0, atol=1e-12)  # Nᵀ H_f = 0
    q = np.linalg.qr(h_f, mode="complete")[0]
    # same subspace as a complete QR: ‖Nᵀ x‖ agrees for every column
    np.testing.assert_allclose(
        np.linalg.norm(projected[:, 3:, 3:], axis=1),
        np.linalg.norm(np.swapaxes(q[:, :, 3:], 1, 2) @ rest, axis=1),
        rtol=1e-10,
    )
    np.testing.assert_allclose(
        np.abs(np.diagonal(upper, axis1=1, axis2=2)),
        np.abs(np.diagonal(np.linalg.qr(h_f)[1], axis1=1, axis2=2)),
    )


@pytest.fixture(scope="module")
def exact_team():
    return lissajous_team(robots=3, steps=40, seed=1, noise_free=True, landmarks=800)


@pytest.mark.parametrize("consensus", [False, True])
def test_noise_free_team_recovers_ground_truth(exact_team, consensus):
    cfg = config_for(exact_team, {"filter.window": 8, "filter.debug": True})
    result = run_team(exact_team, cfg, consensus=consensus, progress=False)
    for est, robot in zip(result.poses, exact_team.robots, strict=True):
        np.testing.assert_allclose(est[:, :3, 3], robot.T_world_body[:, :3, 3], atol=1e-6)
        np.testing.assert_allclose(est[:, :3, :3], robot.T_world_body[:, :3, :3], atol=1e-6)
    for ids, pos in zip(result.object_ids, result.objects, strict=True):
        assert ids.size > 10
        np.testing.assert_allclose(pos, exact_team.object_position(ids), atol=1e-6)


# drifting_team and drifting_runs (separate and consensus): session fixtures in conftest.py


def test_agent_without_neighbours_is_exactly_separate(drifting_team, drifting_runs):
    cfg = config_for(drifting_team, {"filter.window": 10, "filter.use_geometric_features": False})
    lonely = run_team(drifting_team, cfg, graph=from_edges(3, []), consensus=True, progress=False)
    for a, b in zip(lonely.poses, drifting_runs["separate"].poses, strict=True):
        np.testing.assert_array_equal(a, b)


def test_consensus_reduces_disagreement_and_error(drifting_team, drifting_runs):
    sep = team_metrics(drifting_team, drifting_runs["separate"])
    con = team_metrics(drifting_team, drifting_runs["consensus"])
    assert con["trajectory_rmse_avg_m"] < sep["trajectory_rmse_avg_m"]
    assert con["object_disagreement_avg_m"] < 0.5 * sep["object_disagreement_avg_m"]
    assert con["trajectory_rmse_avg_m"] < sep["trajectory_rmse_avg_m"]
    assert con["object_error_avg_m"] < sep["object_error_avg_m"]
    # the filter beats dead reckoning
    assert con["trajectory_rmse_avg_m"] < 0.5 * con["odometry_rmse_avg_m"]
    # every robot took part in consensus
    assert all(c.get("objects_averaged", 0) > 0 for c in drifting_runs["consensus"].counters)


def _state_with_objects(rng, ids, positions, spread=0.5):
    state = MsckfState(np.eye(4), 0, np.eye(6) * 0.01)
    for oid, p in zip(ids, positions, strict=True):
        cross = rng.normal(size=(3, state.dim)) * 0.001
        state.add_object(oid, p, np.eye(3) * spread, cross)
    return state


def test_consensus_with_identical_marginals_changes_nothing():
    rng = np.random.default_rng(3)
    state = _state_with_objects(rng, [4, 9], rng.normal(size=(2, 3)))
    cols = state.object_columns(np.arange(2)).ravel()
    msg = CommonMarginalMessage(
        1,
        0,
        1,
        state.object_ids.copy(),
        state.objects.ravel().copy(),
        state.cov[np.ix_(cols, cols)].copy(),
    )
    before_cov, before_obj, before_pose = state.cov.copy(), state.objects.copy(), state.poses.copy()
    consensus_average(state, 0.5, [(0.5, msg)])
    np.testing.assert_allclose(state.cov, before_cov, atol=1e-12)
    np.testing.assert_allclose(state.objects, before_obj, atol=1e-12)
    np.testing.assert_allclose(state.poses, before_pose, atol=1e-12)


def test_two_agents_one_common_object_is_equation_19_by_hand():
    rng = np.random.default_rng(4)
    state = _state_with_objects(rng, [7, 8], rng.normal(size=(2, 3)))
    slot = state.object_slots(np.array([7]))[0]
    cols = state.object_columns(np.array([slot])).ravel()
    own_mean, own_cov = state.objects[slot].copy(), state.cov[np.ix_(cols, cols)].copy()
    other_mean = own_mean + np.array([1.0, -0.5, 0.2])
    a = rng.normal(size=(3, 3))
    other_cov = a @ a.T + 0.1 * np.eye(3)
    msg = CommonMarginalMessage(1, 0, 1, np.array([7]), other_mean, other_cov)
    consensus_average(state, 0.5, [(0.5, msg)])
    info = 0.5 * np.linalg.inv(own_cov) + 0.5 * np.linalg.inv(other_cov)
    want_cov = np.linalg.inv(info)
    want_mean = want_cov @ (
        0.5 * np.linalg.inv(own_cov) @ own_mean + 0.5 * np.linalg.inv(other_cov) @ other_mean
    )
    np.testing.assert_allclose(state.objects[slot], want_mean, atol=1e-10)
    np.testing.assert_allclose(state.cov[np.ix_(cols, cols)], want_cov, atol=1e-10)


def test_three_way_average_is_one_weighted_average_not_pairwise():
    rng = np.random.default_rng(5)
    state = _state_with_objects(rng, [1], [np.zeros(3)])
    cols = state.object_columns(np.array([0])).ravel()
    own = (state.objects[0].copy(), state.cov[np.ix_(cols, cols)].copy())
    others = [(rng.normal(size=3), np.eye(3) * s) for s in (0.2, 2.0)]
    msgs = [
        (0.3, CommonMarginalMessage(j + 1, 0, 1, np.array([1]), m, c))
        for j, (m, c) in enumerate(others)
    ]
    consensus_average(state, 0.4, msgs)
    want_mean, want_cov = geometric_average_arrays(
        np.stack([own[0], others[0][0], others[1][0]]),
        np.stack([own[1], others[0][1], others[1][1]]),
        np.array([0.4, 0.3, 0.3]),
    )
    np.testing.assert_allclose(state.objects[0], want_mean, atol=1e-10)
    np.testing.assert_allclose(state.cov[np.ix_(cols, cols)], want_cov, atol=1e-10)
    # sequential pairwise averaging gives something else
    m1, c1 = geometric_average_arrays(
        np.stack([own[0], others[0][0]]), np.stack([own[1], others[0][1]]), np.array([0.5, 0.5])
    )
    m2, _ = geometric_average_arrays(
        np.stack([m1, others[1][0]]), np.stack([c1, others[1][1]]), np.array([0.5, 0.5])
    )
    assert np.abs(m2 - want_mean).max() > 1e-3


def test_bad_neighbour_messages_are_named():
    rng = np.random.default_rng(6)
    state = _state_with_objects(rng, [3, 5], rng.normal(size=(2, 3)))
    good_cov = np.eye(6)
    cases = {
        "ids not in this robot's map": CommonMarginalMessage(
            1, 0, 1, np.array([3, 99]), np.zeros(6), good_cov
        ),
        "sizes do not match": CommonMarginalMessage(
            1, 0, 1, np.array([3, 5]), np.zeros(5), good_cov
        ),
        "not positive definite": CommonMarginalMessage(
            1, 0, 1, np.array([3, 5]), np.zeros(6), -good_cov
        ),
        "non-finite": CommonMarginalMessage(
            1, 0, 1, np.array([3, 5]), np.full(6, np.nan), good_cov
        ),
        "not symmetric": CommonMarginalMessage(
            1, 0, 1, np.array([3, 5]), np.zeros(6), good_cov + np.triu(np.ones((6, 6)), 1)
        ),
    }
    for reason, msg in cases.items():
        problem = validate_marginal(state, msg)
        assert problem is not None and reason in problem, (reason, problem)
    # the same checks for a marginal in information form, named as such
    ids = np.array([3, 5])
    for reason, info in {
        "information matrix is not positive definite": -good_cov,
        "information matrix is not symmetric": good_cov + np.triu(np.ones((6, 6)), 1),
        "non-finite mean or information matrix": np.full((6, 6), np.inf),
        "mean/information matrix sizes": np.eye(9),
    }.items():
        msg = CommonMarginalMessage(1, 0, 1, ids, np.zeros(6), None, info=info)
        problem = validate_marginal(state, msg)
        assert problem is not None and reason in problem, (reason, problem)
    assert (
        validate_marginal(
            state, CommonMarginalMessage(1, 0, 1, ids, np.zeros(6), None, info=good_cov)
        )
        is None
    )
    with pytest.raises(ValueError, match="either a covariance or an information matrix"):
        CommonMarginalMessage(1, 0, 1, ids, np.zeros(6), good_cov, info=good_cov)


def test_gate_rejects_about_its_false_alarm_rate():
    """A correct χ² gate (right quantile, right dof) rejects ≈ 5% of good features."""
    team = lissajous_team(robots=1, steps=80, seed=7)
    result = run_team(team, config_for(team, {"filter.window": 10}), progress=False)
    c = result.counters[0]
    rate = c["rejected_features_gate"] / c["features_used"]
    assert 0.02 < rate < 0.10, rate


def test_single_robot_nees_band():
    """Documented band: pose NEES / 6 of one robot over a short noisy run stays in [0.3, 3]."""
    team = lissajous_team(robots=1, steps=80, seed=8)
    result = run_team(team, config_for(team, {"filter.window": 10}), progress=False)
    nees = team_metrics(team, result)["nees_pose_avg"][0]
    assert 0.3 < nees < 3.0, nees


def test_bad_odometry_and_measurements_are_rejected_and_counted(exact_team):
    import copy

    team = copy.deepcopy(exact_team)
    team.robots[0].odometry[5, 0, 3] = np.nan
    team.robots[0].objects.measurements[3, 1] = np.inf
    cfg = config_for(team, {"filter.window": 8})
    result = run_team(team, cfg, consensus=False, progress=False)
    c = result.counters[0]
    assert c["rejected_odometry"] == 1
    assert c["rejected_object_measurements"] == 1
    assert np.all(np.isfinite(result.poses[0]))
    # the other robots are untouched
    np.testing.assert_allclose(
        result.poses[1][:, :3, 3], team.robots[1].T_world_body[:, :3, 3], atol=1e-6
    )


def test_kitti00_objects_only_beats_odometry_and_consensus_agrees(kitti00_dir):
    from teamslam.datasets import import_reference

    team = import_reference(kitti00_dir).head(1200)
    assert team.sensor_model is None  # nothing hand-set: the noise is calibrated from the data
    cfg = config_for(team)
    sep = team_metrics(team, run_team(team, cfg, consensus=False, progress=False))
    con = team_metrics(team, run_team(team, cfg, consensus=True, progress=False))
    assert sep["trajectory_rmse_avg_m"] < sep["odometry_rmse_avg_m"]
    assert con["trajectory_rmse_avg_m"] < con["odometry_rmse_avg_m"]
    assert con["trajectory_rmse_avg_m"] < sep["trajectory_rmse_avg_m"]
    assert con["object_disagreement_avg_m"] < 0.5 * sep["object_disagreement_avg_m"]


def test_partial_neighbour_marginals_equal_the_moment_form_construction():
    """A neighbour sharing only some common objects is completed with our own conditional:
    the information-form average equals Prop. 2 completion + weighted geometric average."""
    from teamslam.gaussian import replace_marginal_arrays

    rng = np.random.default_rng(9)
    state = _state_with_objects(rng, [1, 2, 3, 4], rng.normal(size=(4, 3)))
    y_ids = np.array([1, 2, 3, 4])
    cols = state.object_columns(state.object_slots(y_ids)).ravel()
    own_mean, own_cov = state.objects.ravel().copy(), state.cov[np.ix_(cols, cols)].copy()
    msgs, terms = [], []
    for sender, ids in ((1, [1, 2, 3]), (2, [4]), (3, [2, 4, 1, 3])):
        sub = (3 * (np.array(ids) - 1)[:, None] + np.arange(3)).ravel()
        a = rng.normal(size=(sub.size, sub.size))
        m, c = (
            own_mean[sub] + rng.normal(size=sub.size) * 0.3,
            a @ a.T / sub.size + np.eye(sub.size),
        )
        msgs.append((0.2, CommonMarginalMessage(sender, 0, 1, np.array(ids), m, c)))
        terms.append(replace_marginal_arrays(own_mean, own_cov, sub, m, c))
    consensus_average(state, 0.4, msgs)
    want_mean, want_cov = geometric_average_arrays(
        np.stack([own_mean] + [t[0] for t in terms]),
        np.stack([own_cov] + [t[1] for t in terms]),
        np.array([0.4, 0.2, 0.2, 0.2]),
    )
    np.testing.assert_allclose(state.objects.ravel(), want_mean, atol=1e-9)
    np.testing.assert_allclose(state.cov[np.ix_(cols, cols)], want_cov, atol=1e-9)
