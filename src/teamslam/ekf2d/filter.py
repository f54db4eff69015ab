"""The multi-robot EKF over ``[robot poses, features]`` (FEJ multi-robot EKF paper, §2.2).

One class serves the standard, first-estimate and ideal filters: the only difference is the
:class:`~teamslam.ekf2d.linearization.Policy` that says where Jacobians are evaluated. The
state (eq. 1) is ``[x_r1, …, x_rN, x_f1, …, x_fF]`` with features appended in the order they
are first seen; the covariance is one dense matrix kept symmetric, stored with spare capacity
so appending a feature does not copy it every time.

Per step ``k → k + 1`` (:meth:`MultiRobotEKF.step`): propagate every robot (eqs. 4–6; only the
robot rows and columns of ``P`` change), initialise features seen for the first time from their
first observation (with full cross-covariances), then one batch update with every other
observation of the step (eqs. 8–11). ``H`` is assembled only over the columns it touches, so an
update costs ``O(n · m)`` for ``P Hᵀ`` plus the rank-``m`` downdate of ``P``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
import scipy.linalg.lapack

from teamslam.ekf2d import models
from teamslam.ekf2d.linearization import LinearizationPoints, Policy
from teamslam.errors import InputError
from teamslam.gaussian import NotPositiveDefiniteError
from teamslam.geometry.se2 import wrap_angle

__all__ = ["JacobianRecord", "MultiRobotEKF", "StepObservations"]


@dataclass
class StepObservations:
    """All observations of one step: robot index, feature id and ``z`` (robot frame) per row.

    ``cov`` optionally gives each observation its own ``(m, 2, 2)`` noise covariance (real
    data); without it every robot's constant covariance is used.
    """

    robot: np.ndarray
    feature: np.ndarray
    z: np.ndarray
    cov: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.robot = np.asarray(self.robot, dtype=np.int64).ravel()
        self.feature = np.asarray(self.feature, dtype=np.int64).ravel()
        self.z = np.asarray(self.z, dtype=float).reshape(-1, 2)
        if not (self.robot.size == self.feature.size == self.z.shape[0]):
            raise InputError("observations: robot, feature and z must have one row each")
        if not np.all(np.isfinite(self.z)):
            raise InputError("observations: z contains NaN or infinite values")
        if self.cov is not None:
            self.cov = np.asarray(self.cov, dtype=float).reshape(-1, 2, 2)
            if self.cov.shape[0] != self.robot.size or not np.all(np.isfinite(self.cov)):
                raise InputError("observations: cov must be (m, 2, 2) and finite")

    def select(self, mask: np.ndarray) -> StepObservations:
        """The rows where ``mask`` holds."""
        cov = None if self.cov is None else self.cov[mask]
        return StepObservations(self.robot[mask], self.feature[mask], self.z[mask], cov)

    def covariances(self, per_robot: np.ndarray) -> np.ndarray:
        """``(m, 2, 2)`` noise covariance of every row."""
        return per_robot[self.robot] if self.cov is None else self.cov


@dataclass
class JacobianRecord:
    """Jacobians a run used, for the observability analysis (13).

    ``phi[k]`` is the full-state ``Φ_k`` of the propagation ``k → k + 1`` and ``h[k]`` the
    stacked ``H`` of the update at step ``k`` (over the state of that step).
    """

    phi: list[np.ndarray] = field(default_factory=list)
    h: list[np.ndarray] = field(default_factory=list)


def _block_diagonal(blocks: np.ndarray) -> np.ndarray:
    """Block-diagonal matrix of ``(k, b, b)`` blocks."""
    k, b, _ = blocks.shape
    out = np.zeros((k, b, k, b))
    diag = np.arange(k)
    out[diag, :, diag, :] = blocks
    return out.reshape(k * b, k * b)


class MultiRobotEKF:
    """EKF for N robots observing point features, with a pluggable linearisation policy.

    Parameters
    ----------
    odometry_covs
        ``(N, 3, 3)`` covariance of each robot's odometry noise ``(u_x, u_y, v)``.
    observation_covs
        ``(N, 2, 2)`` covariance of each robot's observation noise.
    policy
        Where Jacobians are evaluated (standard, first estimate, ideal).
    record_jacobians
        Keep every ``Φ`` and ``H`` for :mod:`teamslam.ekf2d.observability`.
    """

    def __init__(
        self,
        odometry_covs: np.ndarray,
        observation_covs: np.ndarray,
        policy: Policy,
        record_jacobians: bool = False,
    ) -> None:
        self.odometry_covs = np.asarray(odometry_covs, dtype=float)
        self.observation_covs = np.asarray(observation_covs, dtype=float)
        n = self.odometry_covs.shape[0]
        if self.odometry_covs.shape != (n, 3, 3) or self.observation_covs.shape != (n, 2, 2):
            raise InputError("need (N, 3, 3) odometry and (N, 2, 2) observation covariances")
        self.n_robots = n
        self.policy = policy
        self.record = JacobianRecord() if record_jacobians else None
        self._capacity = 3 * n + 2 * 32
        self._mean = np.zeros(self._capacity)
        self._cov = np.zeros((self._capacity, self._capacity))
        self.dim = 3 * n
        self.feature_ids: list[int] = []
        self._slot: dict[int, int] = {}
        self._first = np.zeros((32, 2))
        self.prior_poses = np.zeros((n, 3))

    # ------------------------------------------------------------------ state access
    @property
    def mean(self) -> np.ndarray:
        """State mean (a view)."""
        return self._mean[: self.dim]

    @property
    def cov(self) -> np.ndarray:
        """State covariance (a view)."""
        return self._cov[: self.dim, : self.dim]

    @property
    def poses(self) -> np.ndarray:
        """``(N, 3)`` current robot poses."""
        return self._mean[: 3 * self.n_robots].reshape(self.n_robots, 3)

    @property
    def n_features(self) -> int:
        """Features in the state."""
        return len(self.feature_ids)

    @property
    def features(self) -> np.ndarray:
        """``(F, 2)`` current feature estimates in state order."""
        return self._mean[3 * self.n_robots : self.dim].reshape(-1, 2)

    @property
    def first_estimates(self) -> np.ndarray:
        """``(F, 2)`` each feature's first estimate (state order)."""
        return self._first[: self.n_features]

    def slots(self, ids: np.ndarray) -> np.ndarray:
        """State slots of feature ids (``-1`` where not in the state)."""
        return np.array([self._slot.get(int(i), -1) for i in np.ravel(ids)], dtype=np.int64)

    def pose_cov(self, robot: int) -> np.ndarray:
        """3×3 covariance of a robot's pose."""
        s = slice(3 * robot, 3 * robot + 3)
        return self._cov[s, s]

    def _grow(self, extra: int) -> None:
        need = self.dim + extra
        if need <= self._capacity:
            return
        cap = max(need, 2 * self._capacity)
        mean = np.zeros(cap)
        cov = np.zeros((cap, cap))
        mean[: self.dim] = self.mean
        cov[: self.dim, : self.dim] = self.cov
        self._mean, self._cov, self._capacity = mean, cov, cap
        first = np.zeros((cap, 2))
        first[: self.n_features] = self.first_estimates
        self._first = first

    # ------------------------------------------------------------------ start
    def start(
        self,
        poses: np.ndarray,
        feature_ids: np.ndarray,
        features: np.ndarray,
        cov: np.ndarray,
    ) -> None:
        """Set the step-0 state: poses ``(N, 3)``, features and the joint covariance."""
        poses = np.asarray(poses, dtype=float).reshape(self.n_robots, 3)
        features = np.asarray(features, dtype=float).reshape(-1, 2)
        feature_ids = np.asarray(feature_ids, dtype=np.int64).ravel()
        dim = 3 * self.n_robots + 2 * len(feature_ids)
        cov = np.asarray(cov, dtype=float)
        if cov.shape != (dim, dim):
            raise InputError(f"start covariance must be {dim}×{dim}, got {cov.shape}")
        self.dim = 3 * self.n_robots
        self.feature_ids, self._slot = [], {}
        self._grow(2 * len(feature_ids))
        self.dim = dim
        self._mean[: 3 * self.n_robots] = poses.ravel()
        self._mean[3 * self.n_robots : dim] = features.ravel()
        self._cov[:dim, :dim] = 0.5 * (cov + cov.T)
        for k, fid in enumerate(feature_ids):
            self._slot[int(fid)] = k
            self.feature_ids.append(int(fid))
        self._first[: len(feature_ids)] = features
        self.prior_poses = poses.copy()

    # ------------------------------------------------------------------ propagation
    def propagate(
        self,
        odometry: np.ndarray,
        true_from: np.ndarray | None = None,
        true_to: np.ndarray | None = None,
        odometry_covs: np.ndarray | None = None,
    ) -> None:
        """Propagate every robot with its odometry ``(N, 3)`` (eqs. 2–6).

        ``odometry_covs`` ``(N, 3, 3)`` overrides the constant odometry noise for this step.
        """
        odometry = np.asarray(odometry, dtype=float).reshape(self.n_robots, 3)
        if not np.all(np.isfinite(odometry)):
            raise InputError("odometry contains NaN or infinite values")
        posterior = self.poses.copy()
        propagated = models.motion(posterior, odometry)
        points = LinearizationPoints(posterior, self.prior_poses, propagated, true_from, true_to)
        pos_from, pos_to = self.policy.propagation_positions(points)
        phi, g = models.motion_jacobians(pos_from, pos_to, self.policy.propagation_heading(points))
        nr, n = self.n_robots, self.dim
        r = 3 * nr
        p = self._cov[:n, :n]
        # Φ is the identity except each robot's heading column c = J (x_p' − x_p) (eq. 5), so
        # Φ P Φᵀ is two rank-one updates per robot on its position rows and columns
        q = self.odometry_covs if odometry_covs is None else np.asarray(odometry_covs, float)
        noise = np.einsum("nij,njk,nlk->nil", g, q, g)
        for i in range(nr):
            a = 3 * i
            c = phi[i, :2, 2]
            p[a : a + 2, :] += np.outer(c, p[a + 2, :])
            p[:, a : a + 2] += np.outer(p[:, a + 2], c)
            p[a : a + 3, a : a + 3] += noise[i]
        self._mean[:r] = propagated.ravel()
        self.prior_poses = propagated.copy()
        if self.record is not None:
            full = np.eye(n)
            full[:r, :r] = _block_diagonal(phi)
            self.record.phi.append(full)

    # ------------------------------------------------------------------ update
    def update(
        self,
        observations: StepObservations,
        true_poses: np.ndarray | None = None,
        true_features: dict[int, np.ndarray] | None = None,
    ) -> None:
        """Initialise new features, then one batch update with the other observations."""
        obs = observations
        if obs.robot.size and (obs.robot.min() < 0 or obs.robot.max() >= self.n_robots):
            raise InputError("observations name a robot outside 0..N-1")
        lin_poses = self.policy.update_poses(self.poses.copy(), true_poses)
        if self.policy.needs_truth and (true_poses is None or true_features is None):
            raise InputError(f"the {self.policy.name} policy needs ground truth")
        slots = self.slots(obs.feature)
        new = slots < 0
        if np.any(new):
            # the first observation of each new feature initialises it
            ids_new = obs.feature[new]
            _, first_rows = np.unique(ids_new, return_index=True)
            rows = np.flatnonzero(new)[np.sort(first_rows)]
            self._initialise(obs.select(rows), lin_poses)
            init_mask = np.zeros(obs.robot.size, dtype=bool)
            init_mask[rows] = True
            obs = obs.select(~init_mask)
            slots = self.slots(obs.feature)
        if self.record is not None and obs.robot.size == 0:
            self.record.h.append(np.zeros((0, self.dim)))
        if obs.robot.size == 0:
            return
        truth_f = np.array([true_features[i] for i in self.feature_ids]) if true_features else None
        lin_features = self.policy.update_features(self.features, self.first_estimates, truth_f)
        self._batch_update(obs, slots, lin_poses, lin_features)

    def _initialise(self, obs: StepObservations, lin_poses: np.ndarray) -> None:
        k = obs.robot.size
        n = self.dim
        self._grow(2 * k)
        poses = self.poses
        estimate = models.feature_from_observation(poses[obs.robot], obs.z)
        d_pose, d_z = models.feature_from_observation_jacobians(lin_poses[obs.robot], obs.z)
        p = self._cov
        rows = 3 * obs.robot[:, None] + np.arange(3)  # (k, 3)
        # cross-covariance with everything already in the state: A P, A selects robot rows
        cross = np.einsum("kij,kjn->kin", d_pose, p[rows, :n]).reshape(2 * k, n)
        a_full = np.zeros((2 * k, n))
        for j in range(k):
            a_full[2 * j : 2 * j + 2, rows[j]] = d_pose[j]
        new_block = a_full @ cross.T
        r = obs.covariances(self.observation_covs)
        noise = np.einsum("kij,kjl,kml->kim", d_z, r, d_z)
        for j in range(k):
            new_block[2 * j : 2 * j + 2, 2 * j : 2 * j + 2] += noise[j]
        p[n : n + 2 * k, :n] = cross
        p[:n, n : n + 2 * k] = cross.T
        p[n : n + 2 * k, n : n + 2 * k] = 0.5 * (new_block + new_block.T)
        self._mean[n : n + 2 * k] = estimate.ravel()
        for j, fid in enumerate(obs.feature):
            self._slot[int(fid)] = self.n_features
            self._first[self.n_features] = estimate[j]
            self.feature_ids.append(int(fid))
        self.dim = n + 2 * k

    def _batch_update(
        self,
        obs: StepObservations,
        slots: np.ndarray,
        lin_poses: np.ndarray,
        lin_features: np.ndarray,
    ) -> None:
        n, m, nr = self.dim, obs.robot.size, 3 * self.n_robots
        h_r, h_f = models.observation_jacobians(
            lin_poses[obs.robot, :2], lin_poses[obs.robot, 2], lin_features[slots]
        )
        robot_cols = 3 * obs.robot[:, None] + np.arange(3)
        feat_cols = nr + 2 * slots[:, None] + np.arange(2)
        cols = np.unique(np.concatenate([robot_cols.ravel(), feat_cols.ravel()]))
        h = np.zeros((2 * m, cols.size))
        row = np.arange(2 * m).reshape(m, 2)
        rc = np.searchsorted(cols, robot_cols)
        fc = np.searchsorted(cols, feat_cols)
        h[row[:, :, None], rc[:, None, :]] = h_r
        h[row[:, :, None], fc[:, None, :]] = h_f
        predicted = models.observation(self.poses[obs.robot], self.features[slots])
        innovation = (obs.z - predicted).ravel()
        p = self._cov[:n, :n]
        pht = p[:, cols] @ h.T  # (n, 2m)
        s = h @ pht[cols] + _block_diagonal(obs.covariances(self.observation_covs))
        # LAPACK directly: this runs every step, the wrappers' checks cost more than the solve
        factor, info = scipy.linalg.lapack.dpotrf(0.5 * (s + s.T), lower=True)
        if info != 0:
            raise NotPositiveDefiniteError("innovation covariance is not positive definite")
        solved, _ = scipy.linalg.lapack.dpotrs(factor, pht.T, lower=True)
        gain = solved.T
        self._mean[:n] += gain @ innovation
        self._mean[2:nr:3] = wrap_angle(self._mean[2:nr:3])
        p -= gain @ pht.T
        p += p.T
        p *= 0.5
        if self.record is not None:
            full = np.zeros((2 * m, n))
            full[:, cols] = h
            self.record.h.append(full)

    # ------------------------------------------------------------------ one step
    def step(
        self,
        odometry: np.ndarray,
        observations: StepObservations,
        true_from: np.ndarray | None = None,
        true_to: np.ndarray | None = None,
        true_features: dict[int, np.ndarray] | None = None,
        odometry_covs: np.ndarray | None = None,
    ) -> None:
        """Propagate with ``odometry`` then update with ``observations`` of the new step."""
        self.propagate(odometry, true_from, true_to, odometry_covs)
        self.update(observations, true_to, true_features)
