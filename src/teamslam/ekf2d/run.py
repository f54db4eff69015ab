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
from teamslam.ekf2d.simulate import PlanarRun
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
    truth_features = dict(enumerate(run.truth.features))
    ekf.update(obs0.select(rest), run.truth.poses[0], truth_features)
    return ekf


def _score(ekf: MultiRobotEKF, run: PlanarRun, k: int, out: RunMetrics) -> None:
    truth = run.truth
    err = truth.poses[k] - ekf.poses
    err[:, 2] = wrap_angle(err[:, 2])
    out.position_sq[k] = np.sum(err[:, :2] ** 2, axis=1)
    out.heading_sq[k] = err[:, 2] ** 2
    covs = np.stack([ekf.pose_cov(i) for i in range(ekf.n_robots)])
    out.pose_error[k] = err
    out.pose_sigma[k] = np.sqrt(np.maximum(np.diagonal(covs, axis1=1, axis2=2), 0.0))
    if k > 0:
        solved = np.linalg.solve(covs, err[..., None])[..., 0]
        out.pose_nees[k] = np.einsum("ni,ni->n", err, solved) / 3.0
    f = ekf.n_features
    if f:
        ids = np.asarray(ekf.feature_ids)
        fe = truth.features[ids] - ekf.features
        nr = 3 * ekf.n_robots
        x = nr + 2 * np.arange(f)  # each feature's 2×2 diagonal block, read element-wise
        p = ekf.cov
        cxx, cxy, cyy = p[x, x], p[x, x + 1], p[x + 1, x + 1]
        det = cxx * cyy - cxy * cxy
        quad = (cyy * fe[:, 0] ** 2 - 2 * cxy * fe[:, 0] * fe[:, 1] + cxx * fe[:, 1] ** 2) / det
        out.feature_nees[k] = np.mean(quad) / 2.0
        out.feature_sq[k] = np.mean(np.sum(fe**2, axis=1))


def run_filter(env: PlanarEnvironment, run: PlanarRun, policy: Policy) -> RunMetrics:
    """Start, then step through the whole run, scoring every step."""
    steps, n = run.truth.steps, env.n_robots
    out = RunMetrics(
        np.full((steps + 1, n), np.nan),
        np.zeros((steps + 1, n)),
        np.zeros((steps + 1, n)),
        np.full(steps + 1, np.nan),
        np.full(steps + 1, np.nan),
        np.zeros((steps + 1, n, 3)),
        np.zeros((steps + 1, n, 3)),
    )
    ekf = start_filter(env, run, policy)
    truth_features = dict(enumerate(run.truth.features)) if policy.needs_truth else None
    _score(ekf, run, 0, out)
    for k in range(steps):
        ekf.step(
            run.odometry[k],
            run.observations(k + 1),
            run.truth.poses[k],
            run.truth.poses[k + 1],
            truth_features,
        )
        _score(ekf, run, k + 1, out)
    return out
