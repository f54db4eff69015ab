"""The multi-robot EKF over ``[robot poses, features]`` (FEJ multi-robot EKF paper, §2.2).

One class, :class:`MultiRobotEKF`, serves the standard, first-estimate and ideal filters; only
its :class:`~teamslam.ekf2d.linearization.Policy` differs. Per step (:meth:`MultiRobotEKF.step`):
propagate every robot (eqs. 4–6), initialise new features from their first observation (with
full cross-covariances), then one batch update with the step's other observations
(eqs. 8–11). ``P`` is one contiguous array, kept whole up to ``FULL_STORAGE_MAX`` entries and
as its lower triangle above (symmetric by construction either way); each step touches only
the blocks that change, and small states run as one compiled call
(:mod:`teamslam.ekf2d.kernels`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg.blas
import scipy.linalg.lapack

from teamslam.ekf2d import models
from teamslam.ekf2d.linearization import LinearizationPoints, Policy
from teamslam.errors import InputError
from teamslam.gaussian import NotPositiveDefiniteError

__all__ = ["JacobianRecord", "MultiRobotEKF", "StepObservations"]

_TWO_PI = 2.0 * np.pi
FULL_STORAGE_MAX = 128  # state size up to which both triangles of P are kept
_J_T = np.array([[0.0, 1.0], [-1.0, 0.0]])  # Δ @ Jᵀ = J Δ per row
_MINUS_J_T = -_J_T


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

    @classmethod
    def checked_rows(
        cls,
        robot: np.ndarray,
        feature: np.ndarray,
        z: np.ndarray,
        cov: np.ndarray | None = None,
    ) -> StepObservations:
        """Rows of arrays that were already validated as a whole (no checks, no copies).

        ``robot`` and ``feature`` must be 1-D ``int64``, ``z`` ``(m, 2)`` float and ``cov``
        ``None`` or ``(m, 2, 2)`` float, all finite — e.g. slices of one run's observations
        checked once by :class:`StepObservations` itself.
        """
        out = object.__new__(cls)
        out.robot, out.feature, out.z, out.cov = robot, feature, z, cov
        return out

    def select(self, mask: np.ndarray) -> StepObservations:
        """The rows where ``mask`` holds."""
        cov = None if self.cov is None else self.cov[mask]
        return StepObservations.checked_rows(
            self.robot[mask], self.feature[mask], self.z[mask], cov
        )

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


def _kernels():
    """:mod:`teamslam.ekf2d.kernels`, imported (and compiled) on first use."""
    from teamslam.ekf2d import kernels

    return kernels


def _collapse_columns(h: np.ndarray, columns: np.ndarray, n: int) -> np.ndarray:
    """``(rows, n)`` matrix with ``h``'s columns added into ``columns`` (which may repeat)."""
    full = np.zeros((h.shape[0], n))
    np.add.at(full.T, columns, h.T)
    return full


def _features_at(truth: Mapping[int, np.ndarray] | np.ndarray, ids: np.ndarray) -> np.ndarray:
    """Ground-truth positions ``(m, 2)`` of feature ids, from a mapping or an id-indexed array."""
    if isinstance(truth, np.ndarray):
        return truth[ids]
    return np.array([truth[i] for i in ids.tolist()], dtype=float).reshape(-1, 2)


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
        r = 3 * n
        self._capacity = r + 2 * 32
        self._mean = np.zeros(self._capacity)
        self._lower = np.zeros((r, r))  # P: its lower triangle (both while _full)
        self.dim = r
        self.feature_ids: list[int] = []
        self._slot: dict[int, int] = {}
        self._first = np.zeros((32, 2))
        self.prior_poses = np.zeros((n, 3))
        # propagation: [Φ_r | G] (r × 2r) and diag(P_rr, Q) (2r × 2r), so that
        # Φ_r P_rr Φ_rᵀ + G Q Gᵀ is one product; only their per-step entries are rewritten
        self._phi_g = np.hstack([np.eye(r), np.eye(r)])
        a = 3 * np.arange(n)[:, None]
        width = 2 * r
        self._phi_index = np.hstack(
            [
                a * width + a + 2,  # Φ[a, a+2] = −Δy
                (a + 1) * width + a + 2,  # Φ[a+1, a+2] = Δx
            ]
        )
        self._g_index = np.hstack(
            [
                a * width + r + a,  # G[a, a] = cos
                a * width + r + a + 1,  # G[a, a+1] = −sin
                (a + 1) * width + r + a,  # G[a+1, a] = sin
                (a + 1) * width + r + a + 1,  # G[a+1, a+1] = cos
            ]
        )
        self._phi_g_values = np.zeros((n, 6))
        self._blocks = np.zeros((width, width))
        self._blocks[r:, r:] = _block_diagonal(self.odometry_covs)
        self._template = np.zeros((2, 5))  # [−I, −J d, I]: column 2 filled per observation
        self._template[:, :2] = -np.eye(2)
        self._template[:, 3:] = np.eye(2)
        self._robot_cols = np.arange(r)
        self._feature_cols = r + 2 * np.arange(32)[:, None] + np.arange(2)
        self._shapes: dict[int, tuple[np.ndarray, ...]] = {}
        self._index_dim = -1
        self._full = True
        self._update_indices()

    # ------------------------------------------------------------------ state access
    @property
    def mean(self) -> np.ndarray:
        """State mean (a view)."""
        return self._mean[: self.dim]

    @property
    def cov(self) -> np.ndarray:
        """State covariance (a symmetric copy)."""
        lower = np.tril(self._lower)
        return lower + np.tril(lower, -1).T

    @property
    def poses(self) -> np.ndarray:
        """``(N, 3)`` current robot poses (a view)."""
        return self._mean[: 3 * self.n_robots].reshape(self.n_robots, 3)

    @property
    def n_features(self) -> int:
        """Features in the state."""
        return len(self.feature_ids)

    @property
    def features(self) -> np.ndarray:
        """``(F, 2)`` current feature estimates in state order (a view)."""
        return self._mean[3 * self.n_robots : self.dim].reshape(-1, 2)

    @property
    def first_estimates(self) -> np.ndarray:
        """``(F, 2)`` each feature's first estimate (state order)."""
        return self._first[: self.n_features]

    def slots(self, ids: np.ndarray) -> np.ndarray:
        """State slots of feature ids (``-1`` where not in the state)."""
        get = self._slot.get
        return np.array([get(i, -1) for i in np.ravel(ids).tolist()], dtype=np.int64)

    def pose_cov(self, robot: int) -> np.ndarray:
        """3×3 covariance of a robot's pose."""
        return self.pose_covs()[robot]

    def pose_covs(self) -> np.ndarray:
        """``(N, 3, 3)`` covariance of every robot's pose."""
        return self._lower.ravel()[self._pose_index]

    def feature_covs(self) -> np.ndarray:
        """``(F, 2, 2)`` marginal covariance of every feature (state order)."""
        return self._lower.ravel()[self._feature_index]

    def _update_indices(self) -> None:
        """Flat indices into the lower triangle that depend on ``dim``."""
        n, r = self.dim, 3 * self.n_robots
        # full storage (both triangles kept) while small; from then on the lower triangle only
        self._full = self._full and n <= FULL_STORAGE_MAX
        if n == self._index_dim:
            return

        def symmetric(rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
            return np.maximum(rows, cols) * n + np.minimum(rows, cols)

        ar = np.arange(r)
        self._robot_index = symmetric(ar[:, None], ar[None, :])
        pose = 3 * np.arange(self.n_robots)[:, None, None] + np.arange(3)
        self._pose_index = symmetric(pose, np.swapaxes(pose, 1, 2))
        feat = r + 2 * np.arange((n - r) // 2)[:, None, None] + np.arange(2)
        self._feature_index = symmetric(feat, np.swapaxes(feat, 1, 2))
        self._rows = np.arange(n)[:, None]
        self._index_dim = n

    def _columns(self, cols: np.ndarray, robots_first: bool = False) -> np.ndarray:
        """Full columns ``P[:, cols]`` ``(dim, len(cols))`` read from the lower triangle.

        With ``robots_first``, ``cols`` starts with every robot column ``0 … 3N − 1``.
        """
        p = self._lower
        out = p[cols]  # rows of P: right for entries left of the diagonal
        if not self._full:
            fix, below = out, cols
            if robots_first:  # the robot block and the robot–feature block, read as blocks
                r = 3 * self.n_robots
                out[:r, :r] = p.ravel()[self._robot_index]
                out[:r, r:] = p[r:, :r].T
                fix, below = out[r:], cols[r:]
            np.copyto(fix, p.T[below], where=self._rows.T > below[:, None])
        return out.T

    def _grow_mean(self, extra: int) -> None:
        need = self.dim + extra
        if need <= self._capacity:
            return
        cap = max(need, 2 * self._capacity)
        mean = np.zeros(cap)
        mean[: self.dim] = self.mean
        first = np.zeros((cap, 2))
        first[: self.n_features] = self.first_estimates
        self._mean, self._first, self._capacity = mean, first, cap
        r = 3 * self.n_robots
        self._feature_cols = r + 2 * np.arange(cap)[:, None] + np.arange(2)

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
        self._grow_mean(2 * len(feature_ids))
        self.dim = dim
        self._mean[: 3 * self.n_robots] = poses.ravel()
        self._mean[3 * self.n_robots : dim] = features.ravel()
        self._lower = 0.5 * (cov + cov.T)
        self._full = True
        for k, fid in enumerate(feature_ids.tolist()):
            self._slot[fid] = k
            self.feature_ids.append(fid)
        self._first[: len(feature_ids)] = features
        self.prior_poses = poses.copy()
        self._update_indices()

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
        nr = self.n_robots
        n, r = self.dim, 3 * nr
        odometry = np.asarray(odometry, dtype=float).reshape(nr, 3)
        if not np.isfinite(odometry).all():
            raise InputError("odometry contains NaN or infinite values")
        mean = self._mean
        posterior = mean[:r].copy().reshape(nr, 3)
        if self._full and self.record is None:
            # small state: compiled motion and covariance propagation (see ekf2d.kernels)
            kernels = _kernels()
            propagated = kernels.motion(posterior, np.ascontiguousarray(odometry))
            points = LinearizationPoints(
                posterior, self.prior_poses, propagated, true_from, true_to
            )
            pos_from, pos_to = self.policy.propagation_positions(points)
            q = self.odometry_covs if odometry_covs is None else odometry_covs
            kernels.propagate_full(
                self._lower,
                pos_to - pos_from,
                self.policy.propagation_heading(points),
                np.ascontiguousarray(q, dtype=float),
            )
            mean[:r] = propagated.ravel()
            self.prior_poses = propagated
            return
        # G (eq. 6) at the posterior heading: it also moves the means, x' = x + G u (eq. 2)
        phi_g, vals = self._phi_g, self._phi_g_values
        np.cos(posterior[:, 2], out=vals[:, 2])
        np.sin(posterior[:, 2], out=vals[:, 4])
        vals[:, 5] = vals[:, 2]
        np.negative(vals[:, 4], out=vals[:, 3])
        np.put(phi_g, self._g_index, vals[:, 2:])
        propagated = (posterior.ravel() + phi_g[:, r:] @ odometry.ravel()).reshape(nr, 3)
        heading = propagated[:, 2]
        heading += np.pi
        np.remainder(heading, _TWO_PI, out=heading)
        heading -= np.pi
        points = LinearizationPoints(posterior, self.prior_poses, propagated, true_from, true_to)
        pos_from, pos_to = self.policy.propagation_positions(points)
        heading_g = self.policy.propagation_heading(points)
        if not (heading_g.base is posterior and heading_g.strides == heading.strides):
            np.cos(heading_g, out=vals[:, 2])  # the policy rotates the noise elsewhere
            np.sin(heading_g, out=vals[:, 4])
            vals[:, 5] = vals[:, 2]
            np.negative(vals[:, 4], out=vals[:, 3])
            np.put(phi_g, self._g_index, vals[:, 2:])
        # Φ_r (eq. 5): identity but each robot's heading column J Δ, J Δ = (−Δy, Δx)
        np.matmul(pos_to - pos_from, _J_T, out=vals[:, :2])
        np.put(phi_g, self._phi_index, vals[:, :2])
        blocks = self._blocks
        if odometry_covs is not None:
            blocks[r:, r:] = _block_diagonal(np.asarray(odometry_covs, dtype=float))
        p = self._lower
        blocks[:r, :r] = p.ravel()[self._robot_index]
        phi_g = self._phi_g
        p[:r, :r] = phi_g @ blocks @ phi_g.T  # Φ_r P_rr Φ_rᵀ + G Q Gᵀ (lower triangle read)
        if n > r:
            p[r:n, :r] = p[r:n, :r] @ phi_g[:, :r].T  # P_fr Φ_rᵀ
            if self._full:
                p[:r, r:n] = p[r:n, :r].T
        if odometry_covs is not None:
            blocks[r:, r:] = _block_diagonal(self.odometry_covs)
        mean[:r] = propagated.ravel()
        self.prior_poses = propagated
        if self.record is not None:
            full = np.eye(n)
            full[:r, :r] = phi_g[:, :r]
            self.record.phi.append(full)

    # ------------------------------------------------------------------ update
    def update(
        self,
        observations: StepObservations,
        true_poses: np.ndarray | None = None,
        true_features: Mapping[int, np.ndarray] | np.ndarray | None = None,
    ) -> None:
        """Initialise new features, then one batch update with the other observations.

        ``true_features`` (ideal policy only) maps feature id to position, as a mapping or as an
        array indexed by id.
        """
        obs = observations
        nr = self.n_robots
        if obs.robot.size and (obs.robot.min() < 0 or obs.robot.max() >= nr):
            raise InputError("observations name a robot outside 0..N-1")
        poses_now = self._mean[: 3 * nr].copy().reshape(nr, 3)
        lin_poses = self.policy.update_poses(poses_now, true_poses)
        if self.policy.needs_truth and (true_poses is None or true_features is None):
            raise InputError(f"the {self.policy.name} policy needs ground truth")
        get = self._slot.get
        slots = [get(i, -1) for i in obs.feature.tolist()]
        if -1 in slots:
            # the first observation of each new feature initialises it
            new = np.array(slots) < 0
            _, first_rows = np.unique(obs.feature[new], return_index=True)
            rows = np.flatnonzero(new)[np.sort(first_rows)]
            self._initialise(obs.select(rows), lin_poses)
            init_mask = np.zeros(obs.robot.size, dtype=bool)
            init_mask[rows] = True
            obs = obs.select(~init_mask)
            slots = [get(i, -1) for i in obs.feature.tolist()]
        if not slots:
            if self.record is not None:
                self.record.h.append(np.zeros((0, self.dim)))
            return
        slots = np.array(slots)
        truth_f = None if true_features is None else _features_at(true_features, obs.feature)
        r = 3 * nr
        current = self._mean[r : self.dim].reshape(-1, 2)[slots]
        lin_features = self.policy.update_features(current, self._first[slots], truth_f)
        self._batch_update(obs, slots, poses_now, lin_poses, current, lin_features)

    def _initialise(self, obs: StepObservations, lin_poses: np.ndarray) -> None:
        k = obs.robot.size
        n = self.dim
        self._grow_mean(2 * k)
        estimate = models.feature_from_observation(self.poses[obs.robot], obs.z)
        d_pose, d_z = models.feature_from_observation_jacobians(lin_poses[obs.robot], obs.z)
        rows = (3 * obs.robot[:, None] + np.arange(3)).ravel()  # (3k,)
        # cross-covariance with everything already in the state: A P, A selects robot rows
        cross = np.matmul(d_pose, self._columns(rows).T.reshape(k, 3, n)).reshape(2 * k, n)
        new_block = np.einsum("xlc,lbc->xlb", cross[:, rows].reshape(2 * k, k, 3), d_pose)
        new_block = new_block.reshape(2 * k, 2 * k)
        noise = d_z @ obs.covariances(self.observation_covs) @ np.swapaxes(d_z, 1, 2)
        new_block += _block_diagonal(noise)
        grown = np.zeros((n + 2 * k, n + 2 * k))
        grown[:n, :n] = self._lower
        grown[n:, :n] = cross
        if self._full:
            grown[:n, n:] = cross.T
        grown[n:, n:] = 0.5 * (new_block + new_block.T)
        self._lower = grown
        self._mean[n : n + 2 * k] = estimate.ravel()
        f = self.n_features
        self._first[f : f + k] = estimate
        for j, fid in enumerate(obs.feature.tolist()):
            self._slot[fid] = f + j
            self.feature_ids.append(fid)
        self.dim = n + 2 * k
        self._update_indices()

    def _update_shapes(self, m: int) -> tuple[np.ndarray, ...]:
        """Index arrays of an update with ``m`` observations (cached per ``m``)."""
        shapes = self._shapes.get(m)
        if shapes is None:
            r = 3 * self.n_robots
            width = r + 2 * m  # columns of H: every robot's pose, then each observation's feature
            row = np.arange(2 * m).reshape(m, 2, 1)
            local = np.concatenate(
                [np.broadcast_to(np.arange(3), (m, 3)), r + 2 * np.arange(m)[:, None] + (0, 1)],
                axis=1,
            )
            h_index = row * width + local[:, None, :]  # robot 0's columns; + 3 i for robot i
            robot_shift = 3 * np.arange(self.n_robots)[:, None, None] * (1, 1, 1, 0, 0)
            diag = np.arange(m)
            s_index = (2 * diag[:, None, None] + np.arange(2)[:, None]) * (2 * m) + (
                2 * diag[:, None, None] + np.arange(2)
            )
            blk = np.zeros((m, 2, 5))
            blk[:] = self._template
            shapes = (h_index, robot_shift, s_index.ravel(), blk)
            self._shapes[m] = shapes
        return shapes

    def _batch_update(
        self,
        obs: StepObservations,
        slots: np.ndarray,
        poses: np.ndarray,
        lin_poses: np.ndarray,
        current: np.ndarray,
        lin_features: np.ndarray,
    ) -> None:
        """One update with ``m`` observations of features in the state.

        ``poses``/``current`` are the estimates (for the predicted observation),
        ``lin_poses``/``lin_features`` where the policy evaluates ``H``.
        """
        n, m, r = self.dim, slots.size, 3 * self.n_robots
        robot = obs.robot
        if self._full and self.record is None:
            # small state: one compiled call does the whole update (see ekf2d.kernels)
            ok = _kernels().update_full(
                self._lower,
                self._mean[:n],
                self.n_robots,
                robot,
                slots,
                obs.z,
                obs.covariances(self.observation_covs),
                lin_poses[robot],
                lin_features,
                poses[robot],
                current,
            )
            if not ok:
                raise NotPositiveDefiniteError("innovation covariance is not positive definite")
            return
        h_index, robot_shift, s_index, blk = self._update_shapes(m)
        # H of observation i over its five columns [x_ri, x_fi]: C(φ)ᵀ [−I, −J d, I] (10–11)
        lin_pose = lin_poses[robot]
        rot_t = np.empty((m, 2, 2))  # C(φ)ᵀ = [[cos, sin], [−sin, cos]]
        np.cos(lin_pose[:, 2], out=rot_t[:, 0, 0])
        np.sin(lin_pose[:, 2], out=rot_t[:, 0, 1])
        rot_t[:, 1, 1] = rot_t[:, 0, 0]
        np.negative(rot_t[:, 0, 1], out=rot_t[:, 1, 0])
        d = lin_features - lin_pose[:, :2]
        np.matmul(d, _MINUS_J_T, out=blk[:, :, 2])  # −J d = (Δy, −Δx)
        h = rot_t @ blk  # (m, 2, 5)
        # predicted observation at the current estimate (eq. 7)
        if lin_poses is poses:
            diff = d if lin_features is current else current - lin_pose[:, :2]
        else:
            pose = poses[robot]
            rot_t = np.empty((m, 2, 2))
            np.cos(pose[:, 2], out=rot_t[:, 0, 0])
            np.sin(pose[:, 2], out=rot_t[:, 0, 1])
            rot_t[:, 1, 1] = rot_t[:, 0, 0]
            np.negative(rot_t[:, 0, 1], out=rot_t[:, 1, 0])
            diff = current - pose[:, :2]
        # H over [x_r1 … x_rN, x_f of each observation] (features may repeat): P Hᵀ reads only
        # those columns of P
        touched = np.concatenate((self._robot_cols, self._feature_cols[slots].ravel()))
        h_c = np.zeros((2 * m, r + 2 * m))
        h_c.ravel()[h_index + robot_shift[robot]] = h
        # [P Hᵀ; rᵀ] in one (n + 1, 2m) array, so one triangular solve gives [W | v] = U⁻ᵀ [H P | r]
        ext = np.empty((n + 1, 2 * m))
        np.matmul(self._columns(touched, robots_first=True), h_c.T, out=ext[:n])
        s_mat = h_c @ ext[touched]
        s_mat.ravel()[s_index] += obs.covariances(self.observation_covs).ravel()
        # S = Uᵀ U with U upper in Fortran order: the lower triangle of S read in place
        factor, info = scipy.linalg.lapack.dpotrf(s_mat.T, overwrite_a=True)
        if info != 0:
            raise NotPositiveDefiniteError("innovation covariance is not positive definite")
        np.subtract(obs.z, (rot_t @ diff[:, :, None]).reshape(m, 2), out=ext[n].reshape(m, 2))
        # [W | v]ᵀ = [P Hᵀ; rᵀ] U⁻¹: U⁻¹ of the (2m × 2m) triangular factor, then one GEMM
        # over the n + 1 rows (BLAS trsm is several times slower for so few columns and
        # triangular inversion is as accurate as the substitution)
        u_inv, info = scipy.linalg.lapack.dtrtri(factor, overwrite_c=True)
        if info != 0:
            raise NotPositiveDefiniteError("innovation covariance is singular")
        solved = ext @ u_inv
        w = solved[:n].T  # (2m × n), Fortran order
        mean = self._mean
        mean[:n] += solved[:n] @ solved[n]
        heading = mean[2:r:3]
        heading += np.pi
        np.remainder(heading, _TWO_PI, out=heading)
        heading -= np.pi
        # P ← P − Wᵀ W on the lower triangle, in place (Fortran view of the C array: upper)
        if self._full:
            scipy.linalg.blas.dgemm(
                -1.0, w, w, beta=1.0, c=self._lower.T, trans_a=1, overwrite_c=True
            )
        else:
            scipy.linalg.blas.dsyrk(
                -1.0, w, beta=1.0, c=self._lower.T, trans=1, lower=False, overwrite_c=True
            )
        if self.record is not None:
            self.record.h.append(_collapse_columns(h_c, touched, n))

    # ------------------------------------------------------------------ one step
    def step(
        self,
        odometry: np.ndarray,
        observations: StepObservations,
        true_from: np.ndarray | None = None,
        true_to: np.ndarray | None = None,
        true_features: Mapping[int, np.ndarray] | np.ndarray | None = None,
        odometry_covs: np.ndarray | None = None,
    ) -> None:
        """Propagate with ``odometry`` then update with ``observations`` of the new step."""
        self.propagate(odometry, true_from, true_to, odometry_covs)
        self.update(observations, true_to, true_features)
