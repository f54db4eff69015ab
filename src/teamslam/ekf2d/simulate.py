"""Monte Carlo data for a planar environment: fixed ground truth, fresh noise every run.

The robots follow their waypoints exactly (step ``k`` at waypoint ``k mod K``), heading along
the path (towards the next waypoint). Odometry is the true motion in the robot frame plus
plain Gaussian noise, ``u = C(φ_k)ᵀ (p_{k+1} − p_k) + w``, ``v = φ_{k+1} − φ_k + ν``; every feature
within the sensing range is observed, ``z = C(φ)ᵀ (x_f − x_p) + e``. (The published generator's
truncated-noise helper truncated only one element and halved the y-noise; here noise is exactly
the configured Gaussian.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from teamslam.ekf2d import models
from teamslam.ekf2d.environments import PlanarEnvironment
from teamslam.ekf2d.filter import StepObservations
from teamslam.geometry.se2 import rotation, wrap_angle

__all__ = ["PlanarRun", "PlanarTruth", "simulate", "truth_of"]


@dataclass
class PlanarTruth:
    """Noise-free trajectories and observations of an environment.

    Attributes
    ----------
    poses
        ``(K + 1, N, 3)`` true poses.
    odometry
        ``(K, N, 3)`` true odometry.
    features
        ``(F, 2)`` true feature positions (id = row).
    obs_offsets, obs_robot, obs_feature, obs_z
        Flattened per-step observations: step ``k`` holds rows
        ``obs_offsets[k]:obs_offsets[k+1]``; ``obs_z`` is noise-free.
    """

    poses: np.ndarray
    odometry: np.ndarray
    features: np.ndarray
    obs_offsets: np.ndarray
    obs_robot: np.ndarray
    obs_feature: np.ndarray
    obs_z: np.ndarray

    @property
    def steps(self) -> int:
        """Number of motion steps ``K``."""
        return self.odometry.shape[0]


@dataclass
class PlanarRun:
    """One Monte Carlo run: the truth plus noisy odometry and observations."""

    truth: PlanarTruth
    odometry: np.ndarray
    obs_z: np.ndarray

    def __post_init__(self) -> None:
        # every step's observations are slices of these, checked once here
        t = self.truth
        self._all = StepObservations(t.obs_robot, t.obs_feature, self.obs_z)

    def observations(self, k: int) -> StepObservations:
        """Observations of step ``k``."""
        a, b = self.truth.obs_offsets[k], self.truth.obs_offsets[k + 1]
        obs = self._all
        return StepObservations.checked_rows(obs.robot[a:b], obs.feature[a:b], obs.z[a:b])


def truth_of(env: PlanarEnvironment) -> PlanarTruth:
    """The noise-free trajectories and observations of ``env`` for ``env.loops`` loops."""
    steps = env.steps
    n = env.n_robots
    poses = np.zeros((steps + 1, n, 3))
    k = np.arange(steps + 2)
    for i, wp in enumerate(env.waypoints):
        pos = wp[k % len(wp)]
        heading = np.arctan2(*(pos[1:] - pos[:-1]).T[::-1])
        poses[:, i, :2] = pos[:-1]
        poses[:, i, 2] = heading
    delta = poses[1:, :, :2] - poses[:-1, :, :2]
    odometry = np.zeros((steps, n, 3))
    odometry[..., :2] = np.einsum("knji,knj->kni", rotation(poses[:-1, :, 2]), delta)
    odometry[..., 2] = wrap_angle(poses[1:, :, 2] - poses[:-1, :, 2])
    dist = np.linalg.norm(poses[:, :, None, :2] - env.features[None, None], axis=-1)
    step_i, robot_i, feat_i = np.nonzero(dist < env.sensor_range)
    z = models.observation(poses[step_i, robot_i], env.features[feat_i])
    offsets = np.searchsorted(step_i, np.arange(steps + 2))
    return PlanarTruth(poses, odometry, env.features.copy(), offsets, robot_i, feat_i, z)


def simulate(
    env: PlanarEnvironment,
    truth: PlanarTruth,
    rng: np.random.Generator,
    observation_noise_scale: tuple[float, float] = (1.0, 1.0),
) -> PlanarRun:
    """Draw one run's odometry and observation noise.

    ``observation_noise_scale`` scales the drawn observation noise per axis (x, y) while the
    filters keep assuming ``env.observation_std``: ``(1, 0.5)`` draws data like the published
    generator, whose truncated noise leaves about half the y-noise, to measure what that bias
    does to NEES.
    """
    odo_std = np.array([[su, su, sp] for su, sp in env.odometry_std])
    odometry = truth.odometry + rng.standard_normal(truth.odometry.shape) * odo_std[None]
    obs_std = np.asarray(env.observation_std)[truth.obs_robot][:, None]
    if observation_noise_scale != (1.0, 1.0):
        obs_std = obs_std * np.asarray(observation_noise_scale, dtype=float)[None]
    obs_z = truth.obs_z + rng.standard_normal(truth.obs_z.shape) * obs_std
    return PlanarRun(truth, odometry, obs_z)
