"""Planar multi-robot EKF: Jacobians, linearisation policies, step-0 start, observability, NEES."""

from __future__ import annotations

import json

import numpy as np
import pytest

from teamslam.ekf2d import environments as E
from teamslam.ekf2d import models, observability
from teamslam.ekf2d import run as R
from teamslam.ekf2d import simulate as S
from teamslam.ekf2d.filter import MultiRobotEKF, StepObservations
from teamslam.ekf2d.linearization import policy
from teamslam.ekf2d.start import StartError, gauss_newton_start
from teamslam.eval.montecarlo import chi2_band
from teamslam.testing import numerical_jacobian


def test_motion_jacobians_match_finite_differences():
    rng = np.random.default_rng(0)
    for _ in range(10):
        pose = np.array([*rng.normal(size=2) * 5, rng.uniform(-3, 3)])
        odo = np.array([*rng.normal(size=2), rng.normal() * 0.2])
        nxt = models.motion(pose, odo)
        phi, g = models.motion_jacobians(pose[:2], nxt[:2], pose[2])
        wrap = lambda a, b: np.array([*(a[:2] - b[:2]), np.angle(np.exp(1j * (a[2] - b[2])))])  # noqa: E731
        num_phi = numerical_jacobian(lambda p: models.motion(p, odo), pose, 3, minus=wrap)
        num_g = numerical_jacobian(lambda u: models.motion(pose, u), odo, 3, minus=wrap)
        np.testing.assert_allclose(phi, num_phi, atol=1e-7)
        np.testing.assert_allclose(g, num_g, atol=1e-7)


def test_observation_jacobians_match_finite_differences():
    rng = np.random.default_rng(1)
    for _ in range(10):
        pose = np.array([*rng.normal(size=2) * 5, rng.uniform(-3, 3)])
        feat = rng.normal(size=2) * 10
        h_r, h_f = models.observation_jacobians(pose[:2], pose[2], feat)
        np.testing.assert_allclose(
            h_r, numerical_jacobian(lambda p: models.observation(p, feat), pose, 3), atol=1e-7
        )
        np.testing.assert_allclose(
            h_f, numerical_jacobian(lambda f: models.observation(pose, f), feat, 2), atol=1e-7
        )
        z = models.observation(pose, feat)
        np.testing.assert_allclose(models.feature_from_observation(pose, z), feat, atol=1e-12)
        d_pose, d_z = models.feature_from_observation_jacobians(pose, z)
        np.testing.assert_allclose(
            d_pose,
            numerical_jacobian(lambda p: models.feature_from_observation(p, z), pose, 3),
            atol=1e-7,
        )
        np.testing.assert_allclose(
            d_z,
            numerical_jacobian(lambda q: models.feature_from_observation(pose, q), z, 2),
            atol=1e-7,
        )


def _two_filter_states(name: str):
    """Two filters with the same first estimates but different current feature estimates."""
    covs_q = np.array([np.diag([0.1, 0.1, 0.01])] * 2)
    covs_r = np.array([0.25 * np.eye(2)] * 2)
    out = []
    for shift in (0.0, 0.7):
        ekf = MultiRobotEKF(covs_q, covs_r, policy(name), record_jacobians=True)
        feats = np.array([[5.0, 2.0], [-3.0, 4.0]])
        ekf.start(np.array([[0, 0, 0.1], [1, 1, -0.2]]), [10, 11], feats, np.eye(10) * 0.5)
        ekf.features[:] += shift  # move the current estimate, not the first estimate
        obs = StepObservations([0, 1], [10, 11], [[4.0, 1.0], [-4.0, 3.0]])
        ekf.update(obs)
        out.append(ekf.record.h[-1])
    return out


def test_fej_feature_jacobians_ignore_the_current_estimate():
    h_a, h_b = _two_filter_states("fej")
    np.testing.assert_array_equal(h_a, h_b)
    h_a, h_b = _two_filter_states("std")
    assert np.abs(h_a - h_b).max() > 0.1  # the standard filter does move with the estimate


def test_gauss_newton_start_recovers_truth_on_noise_free_data():
    env = E.environment(1, 20)
    truth = S.truth_of(env)
    obs0 = StepObservations(
        truth.obs_robot[: truth.obs_offsets[1]],
        truth.obs_feature[: truth.obs_offsets[1]],
        truth.obs_z[: truth.obs_offsets[1]],
    )
    sol = gauss_newton_start(obs0, truth.poses[0, 0], env.observation_covs())
    np.testing.assert_allclose(sol.poses, truth.poses[0], atol=1e-9)
    np.testing.assert_allclose(sol.features, truth.features[sol.feature_ids], atol=1e-9)
    assert sol.feature_ids.size >= 2
    np.testing.assert_array_equal(sol.cov[:3, :3], 0.0)  # robot 1 anchored
    assert np.all(np.linalg.eigvalsh(sol.cov[3:, 3:]) > 0)


def test_start_needs_two_shared_features():
    obs = StepObservations([0, 0, 1, 1], [1, 2, 2, 3], np.ones((4, 2)))
    with pytest.raises(StartError, match="at least 2"):
        gauss_newton_start(obs, np.zeros(3), np.array([np.eye(2)] * 2))


def _lemma1_env():
    wp1 = np.array([[0, 0], [2, 0.3], [4, 1], [6, 2.2], [8, 3.5], [10, 5]], float)
    wp2 = np.array([[0, 5], [1, 3], [3, 2], [5, 1.5], [7, 1], [9, 0.8]], float)
    return E.PlanarEnvironment(
        "lemma1", [wp1, wp2], np.array([[3.0, 6.0], [7.0, -2.0]]), loops=1, sensor_range=1e3
    )


@pytest.mark.parametrize(("name", "expected"), [("std", 8), ("fej", 7), ("ideal", 7)])
def test_observability_rank_lemma_1(name, expected):
    env = _lemma1_env()
    truth = S.truth_of(env)
    run = S.simulate(env, truth, np.random.default_rng(3))
    ekf = R.start_filter(env, run, policy(name), record_jacobians=True)
    tf = dict(enumerate(truth.features))
    for k in range(truth.steps):
        ekf.step(run.odometry[k], run.observations(k + 1), truth.poses[k], truth.poses[k + 1], tf)
    m = observability.observability_matrix(ekf.record, 1, 4)
    assert m.shape == (40, 10)
    assert observability.rank(m) == expected
    null = observability.nullspace(m)
    assert null.shape[1] == 10 - expected
    if name != "std":
        # global translation is unobservable: moving every robot and feature by (1, 0)
        shift = np.zeros(10)
        shift[[0, 3, 6, 8]] = 1.0
        np.testing.assert_allclose(m @ shift, 0.0, atol=1e-9)


def test_ideal_ekf_nees_is_consistent():
    """Ideal-EKF NEES over 200 seeded runs of a short (20-step) run lies in the 95% χ² band.

    The per-step NEES of both robots is averaged over steps 1–20; the band is that of a single
    robot at a single step (χ²(3 · runs)), which averaging over steps and robots only narrows,
    so the check is conservative but still fails for a filter that is off by 15% or more.
    """
    env = E.environment(1, 20)
    env.loops = 1
    truth = S.truth_of(env)
    runs, steps = 200, 20
    nees = []
    for seed in range(runs):
        m = R.run_filter(env, S.simulate(env, truth, np.random.default_rng(seed)), policy("ideal"))
        nees.append(m.pose_nees[1 : steps + 1])
    avg = float(np.mean(nees))
    lo, hi = chi2_band(3, runs)
    assert lo <= avg <= hi, (lo, avg, hi)


def test_fej_beats_std_in_monte_carlo_on_published_environment(shared_data):
    from teamslam.ekf2d.experiments import monte_carlo

    files = [
        shared_data / "fej-environments" / f
        for f in ("RobotsWaypoints_1.mat", "CheckedTrueState_20features_1.mat")
    ]
    env = E.load_matlab_environment(
        files, odometry_std=[(0.3, np.pi / 90)] * 2, observation_std=[0.5, 0.5]
    )
    result = monte_carlo(env, runs=24, seed=1, workers=2, progress=False)
    std, fej = result.table["std"], result.table["fej"]
    assert std["r1_pose_nees"] > 1.4  # the standard filter is overconfident
    assert 0.8 < fej["r1_pose_nees"] < 1.2
    assert fej["r1_position_rmse"] < std["r1_position_rmse"]
    assert fej["feature_rmse"] < std["feature_rmse"]


def test_environment_files(tmp_path, shared_data):
    env = E.environment(2, 60)
    E.save_environment(env, tmp_path / "env.json")
    back = E.load_environment(tmp_path / "env.json")
    np.testing.assert_array_equal(back.features, env.features)
    assert len(back.waypoints) == 2 and back.odometry_std == [tuple(s) for s in env.odometry_std]
    assert E.environment(1, 100).features[:20].tolist() == E.environment(1, 20).features.tolist()
    (tmp_path / "bad.json").write_text(
        json.dumps(
            {
                "format": "teamslam-planar-environment",
                "version": 1,
                "waypoints": [[[0, 0], [1, 0], [1, 1]]],
                "features": [],
            }
        )
    )
    with pytest.raises(E.PlanarEnvironmentError, match="at least 2 robots"):
        E.load_environment(tmp_path / "bad.json")
    (tmp_path / "junk.json").write_text("{not json")
    with pytest.raises(E.PlanarEnvironmentError, match="cannot read"):
        E.load_environment(tmp_path / "junk.json")
    with pytest.raises(E.PlanarEnvironmentError, match="'lm'"):
        E.load_matlab_environment([shared_data / "fej-environments" / "RobotsWaypoints_1.mat"])
    pub = E.load_matlab_environment(
        [
            shared_data / "fej-environments" / "RobotsWaypoints_1.mat",
            shared_data / "fej-environments" / "CheckedTrueState_20features_1.mat",
        ]
    )
    assert pub.features.shape == (20, 2) and pub.waypoints[0].shape == (63, 2)
    assert pub.steps == 315


def test_victoria_park_split_and_filters(shared_data):
    import scipy.io

    from teamslam.datasets.victoria_park import load_victoria_park
    from teamslam.ekf2d.victoria_park import run_victoria_park

    directory = shared_data / "victoria-park"
    split = load_victoria_park(directory)
    fed = scipy.io.loadmat(directory / "VicP_Measurements.mat")
    for i, robot in enumerate(split.robots):
        odo = fed[f"R{i + 1}OdoSet"]
        np.testing.assert_allclose(robot.odometry, odo[:, 2].reshape(-1, 3))
        obs = fed[f"R{i + 1}ObsSet"]
        np.testing.assert_allclose(robot.obs_z, obs[:, 2].reshape(-1, 2))
        np.testing.assert_array_equal(robot.obs_step, obs[0::2, 0])
        assert robot.steps == 2545
    assert np.unique(np.concatenate([r.obs_feature for r in split.robots])).size == 287
    fej = run_victoria_park(split, "fej")
    assert fej.position_rmse[0] < 0.3  # published FEJ: 0.16 m
    assert fej.position_rmse[1] < 2.0  # published FEJ: 0.83 m
    assert fej.feature_ids.size == 287


def test_bad_inputs_to_the_filter():
    ekf = MultiRobotEKF(np.array([np.eye(3)] * 2), np.array([np.eye(2)] * 2), policy("std"))
    with pytest.raises(ValueError, match="NaN"):
        StepObservations([0], [1], [[np.nan, 0.0]])
    with pytest.raises(ValueError, match="NaN"):
        ekf.propagate(np.array([[np.nan, 0, 0], [0, 0, 0]]))
    with pytest.raises(ValueError, match="outside"):
        ekf.update(StepObservations([5], [1], [[1.0, 0.0]]))
    with pytest.raises(ValueError, match="ground truth"):
        MultiRobotEKF(np.array([np.eye(3)] * 2), np.array([np.eye(2)] * 2), policy("ideal")).update(
            StepObservations([0], [1], [[1.0, 0.0]])
        )
    with pytest.raises(ValueError, match="unknown linearisation"):
        policy("best")
