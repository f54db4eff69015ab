"""Step-0 start of the multi-robot EKF by Gauss–Newton (FEJ multi-robot EKF paper, §2.2, eq. 12).

Robot 1 is anchored; the other robots' step-0 poses and the features seen at step 0 by at least
two robots minimise eq. 12, from a closed-form guess (no prior pose guess needed). The filter
starts from ``P_0 = diag(0, (Jᵀ R⁻¹ J)⁻¹)``. Derivation: the concept page *Linearisation*
(``docs/concepts/linearization.md``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from teamslam.ekf2d import models
from teamslam.ekf2d.filter import StepObservations
from teamslam.errors import InputError
from teamslam.gaussian import spd_inverse
from teamslam.geometry.se2 import wrap_angle

__all__ = ["StartError", "StartSolution", "gauss_newton_start"]


class StartError(InputError):
    """The step-0 problem is not solvable (too few shared features)."""


@dataclass
class StartSolution:
    """The step-0 state: every robot pose, the shared features and their joint covariance.

    ``cov`` is over ``[x_r1, …, x_rN, x_f(shared)…]`` with robot 1's block zero.
    """

    poses: np.ndarray
    feature_ids: np.ndarray
    features: np.ndarray
    cov: np.ndarray
    iterations: int
    cost: float


def _procrustes(local: np.ndarray, world: np.ndarray) -> np.ndarray:
    """Pose ``(x, y, φ)`` with ``world ≈ x_p + C(φ) local`` (least squares, 2D)."""
    lc, wc = local.mean(axis=0), world.mean(axis=0)
    a, b = local - lc, world - wc
    phi = np.arctan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), np.sum(a * b))
    c, s = np.cos(phi), np.sin(phi)
    return np.array([*(wc - np.array([[c, -s], [s, c]]) @ lc), phi])


def gauss_newton_start(
    observations: StepObservations,
    anchor_pose: np.ndarray,
    observation_covs: np.ndarray,
    max_iterations: int = 50,
    tolerance: float = 1e-10,
) -> StartSolution:
    """Solve (12) for the other robots' step-0 poses and the shared features.

    Parameters
    ----------
    observations
        Every robot's step-0 observations.
    anchor_pose
        Robot 1's (index 0) known pose.
    observation_covs
        ``(N, 2, 2)`` observation noise of every robot (unless ``observations.cov`` gives
        each observation its own).

    Raises
    ------
    StartError
        When a robot other than robot 1 sees fewer than 2 features shared at step 0.
    """
    covs = np.asarray(observation_covs, dtype=float)
    n = covs.shape[0]
    obs = observations
    # features seen by ≥ 2 robots (distinct robots)
    pairs = np.unique(np.stack([obs.feature, obs.robot], axis=1), axis=0)
    fid, robots_per = np.unique(pairs[:, 0], return_counts=True)
    shared = fid[robots_per >= 2]
    for r in range(n):
        seen = np.intersect1d(obs.feature[obs.robot == r], shared).size
        if seen < 2:
            raise StartError(
                f"robot {r + 1} sees {seen} feature(s) shared with another robot at step 0; "
                "the step-0 Gauss–Newton start needs at least 2"
            )
    use = np.isin(obs.feature, shared)
    rob, feat, z = obs.robot[use], obs.feature[use], obs.z[use]
    obs_covs = obs.covariances(covs)[use]
    slot = np.searchsorted(shared, feat)

    # closed-form initial guess: features from robot 1, then the others by Procrustes
    poses = np.zeros((n, 3))
    poses[0] = anchor_pose
    features = np.full((shared.size, 2), np.nan)
    placed = rob == 0
    features[slot[placed]] = models.feature_from_observation(anchor_pose, z[placed])
    pending = list(range(1, n))
    while pending:
        progress = False
        for r in list(pending):
            mine = rob == r
            known = mine & ~np.isnan(features[slot, 0])
            if known.sum() >= 2:
                poses[r] = _procrustes(z[known], features[slot[known]])
                todo = mine & np.isnan(features[slot, 0])
                features[slot[todo]] = models.feature_from_observation(poses[r], z[todo])
                pending.remove(r)
                progress = True
        if not progress:
            raise StartError("robots' step-0 observations do not connect to robot 1")

    # Gauss–Newton on the unknowns [poses of robots 2..N, shared features]
    n_unknown = 3 * (n - 1) + 2 * shared.size
    # whitening W with Wᵀ W = R⁻¹ for every observation: W = L⁻¹ where R = L Lᵀ
    w = np.linalg.inv(np.linalg.cholesky(obs_covs))
    m = rob.size
    cost = np.inf
    iterations = 0
    for iterations in range(1, max_iterations + 1):  # noqa: B007
        predicted = models.observation(poses[rob], features[slot])
        residual = np.einsum("mij,mj->mi", w, z - predicted).ravel()
        h_r, h_f = models.observation_jacobians(poses[rob, :2], poses[rob, 2], features[slot])
        jac = np.zeros((2 * m, n_unknown))
        rows = np.arange(2 * m).reshape(m, 2)
        for k in range(m):
            if rob[k] > 0:
                c = 3 * (rob[k] - 1)
                jac[rows[k], c : c + 3] = w[k] @ h_r[k]
            c = 3 * (n - 1) + 2 * slot[k]
            jac[rows[k], c : c + 2] = w[k] @ h_f[k]
        step, *_ = np.linalg.lstsq(jac, residual, rcond=None)
        poses[1:] += step[: 3 * (n - 1)].reshape(-1, 3)
        poses[1:, 2] = wrap_angle(poses[1:, 2])
        features += step[3 * (n - 1) :].reshape(-1, 2)
        cost = float(residual @ residual)
        if np.max(np.abs(step)) < tolerance:
            break
    p_s = spd_inverse(jac.T @ jac, "step-0 Gauss–Newton information")
    dim = 3 * n + 2 * shared.size
    cov = np.zeros((dim, dim))
    cov[3:, 3:] = p_s
    return StartSolution(poses, shared, features, cov, iterations, cost)
