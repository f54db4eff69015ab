"""Run one multi-robot EKF over one planar run and score it against the truth.

Per step it records, for every robot, the pose NEES (eq. 25, normalised by the dimension 3),
the squared position error and the squared heading error, and over the features in the state
the mean per-feature NEES (each 2×2 block, normalised by 2) and the mean squared position error.
Robot 1 is anchored at step 0 (zero covariance), so step 0 is excluded from the robot NEES.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from teamslam.ekf2d.environments import PlanarEnvironment
from teamslam.ekf2d.filter import MultiRobotEKF
from teamslam.ekf2d.linearization import Policy
from teamslam.ekf2d.simulate import PlanarRun, PlanarTruth
from teamslam.ekf2d.start import gauss_newton_start
from teamslam.geometry.se2 import wrap_angle

__all__ = ["RunMetrics", "run_filter", "start_filter"]


@dataclass
class RunMetrics:
    """Per-step errors and NEES of one filter on one run.

    Attributes
    ----------
    pose_nees
        ``(K + 1, N)`` robot pose NEES / 3 (NaN at step 0).
    position_sq, heading_sq
        ``(K + 1, N)`` squared position (m²) and heading (rad²) errors.
    feature_nees
        ``(K + 1,)`` mean over the features in the state of each feature's NEES / 2.
    feature_sq
        ``(K + 1,)`` mean over the features in the state of the squared position error.
    pose_error, pose_sigma
        ``(K + 1, N, 3)`` signed pose errors (truth − estimate) and the filter's standard
        deviations, for 3σ-bound plots.
    """

    pose_nees: np.ndarray
    position_sq: np.ndarray
    heading_sq: np.ndarray
    feature_nees: np.ndarray
    feature_sq: np.ndarray
    pose_error: np.ndarray
    pose_sigma: np.ndarray


def start_filter(
    env: PlanarEnvironment, run: PlanarRun, policy: Policy, record_jacobians: bool = False
) -> MultiRobotEKF:
    """A filter started at step 0 by the Gauss–Newton start (robot 1 anchored at its truth)."""
    ekf = MultiRobotEKF(env.odometry_covs(), env.observation_covs(), policy, record_jacobians)
    obs0 = run.observations(0)
    start = gauss_newton_start(obs0, run.truth.poses[0, 0], env.observation_covs())
    ekf.start(start.poses, start.feature_ids, start.features, start.cov)
    rest = ~np.isin(obs0.feature, start.feature_ids)
    ekf.update(obs0.select(rest), run.truth.poses[0], run.truth.features)
    return ekf


class _Recorder:
    """Per-step estimates and the covariance blocks the metrics need, scored after the run."""

    def __init__(self, steps: int, n_robots: int) -> None:
        self.poses = np.empty((steps + 1, n_robots, 3))
        self.pose_covs = np.empty((steps + 1, n_robots, 3, 3))
        self.features: list[np.ndarray] = []
        self.feature_covs: list[np.ndarray] = []

    def record(self, ekf: MultiRobotEKF, k: int) -> None:
        self.poses[k] = ekf.poses
        self.pose_covs[k] = ekf.pose_covs()
        self.features.append(ekf.features.copy())
        self.feature_covs.append(ekf.feature_covs())

    def score(self, truth: PlanarTruth, feature_ids: list[int]) -> RunMetrics:
        steps = self.poses.shape[0] - 1
        n = self.poses.shape[1]
        err = truth.poses[: steps + 1] - self.poses
        err[..., 2] = wrap_angle(err[..., 2])
        covs = self.pose_covs
        pose_nees = np.full((steps + 1, n), np.nan)
        if steps:
            solved = np.linalg.solve(covs[1:], err[1:, ..., None])[..., 0]
            pose_nees[1:] = np.einsum("kni,kni->kn", err[1:], solved) / 3.0
        sigma = np.sqrt(np.maximum(np.diagonal(covs, axis1=2, axis2=3), 0.0))
        # features: the state at step k holds the first f_k features of the final order
        counts = np.array([f.shape[0] for f in self.features])
        feature_nees = np.full(steps + 1, np.nan)
        feature_sq = np.full(steps + 1, np.nan)
        if counts.sum():
            offsets = np.cumsum(counts) - counts
            slot = np.arange(counts.sum()) - np.repeat(offsets, counts)
            fe = truth.features[np.asarray(feature_ids)[slot]] - np.concatenate(self.features)
            fc = np.concatenate(self.feature_covs)
            cxx, cxy, cyy = fc[:, 0, 0], fc[:, 0, 1], fc[:, 1, 1]
            det = cxx * cyy - cxy * cxy
            quad = (cyy * fe[:, 0] ** 2 - 2 * cxy * fe[:, 0] * fe[:, 1] + cxx * fe[:, 1] ** 2) / det
            have = counts > 0
            start = offsets[have]
            feature_nees[have] = np.add.reduceat(quad, start) / counts[have] / 2.0
            feature_sq[have] = np.add.reduceat(np.sum(fe**2, axis=1), start) / counts[have]
        return RunMetrics(
            pose_nees,
            np.sum(err[..., :2] ** 2, axis=-1),
            err[..., 2] ** 2,
            feature_nees,
            feature_sq,
            err,
            sigma,
        )


def run_filter(env: PlanarEnvironment, run: PlanarRun, policy: Policy) -> RunMetrics:
    """Start, then step through the whole run, scoring every step."""
    steps = run.truth.steps
    recorder = _Recorder(steps, env.n_robots)
    ekf = start_filter(env, run, policy)
    truth_features = run.truth.features if policy.needs_truth else None
    recorder.record(ekf, 0)
    for k in range(steps):
        ekf.step(
            run.odometry[k],
            run.observations(k + 1),
            run.truth.poses[k],
            run.truth.poses[k + 1],
            truth_features,
        )
        recorder.record(ekf, k + 1)
    return recorder.score(run.truth, ekf.feature_ids)
