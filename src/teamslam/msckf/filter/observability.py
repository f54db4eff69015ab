"""Observability of the 3D team filter under each linearisation policy (eq. 13).

Builds the local observability matrix ``M = [H_0; H_1 Φ_0; …]`` from the filter's own
:class:`~teamslam.msckf.filter.linearization.LinearizationPolicy`, fed with values drawn like a
filter's (:func:`estimates_like_a_filter`). With ``ideal`` and ``fej`` its rank is ``dim − 6``,
with ``std`` larger; :func:`falsely_observable` gives the singular values on the true
unobservable directions. :class:`NullspaceAudit` checks the same property on a running filter:
every edit of a :class:`~teamslam.msckf.filter.state.MsckfState` — propagation, update, object
initialisation, re-entry from the persistent map, with marginalisation and retirement in
between — against the rigid motions of the world at the first estimates, and with
``information=True`` how much information each edit (consensus too) gives the state along them.
See the concept page
*Linearisation* (``docs/concepts/linearization.md``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from teamslam.geometry import se3
from teamslam.geometry.camera import StereoCamera
from teamslam.linalg import nullspace, rank
from teamslam.msckf.filter.linearization import LinearizationPolicy, unobservable_directions
from teamslam.msckf.filter.models import observe_jacobians

__all__ = [
    "AUDITED",
    "INFORMED",
    "FilterValues",
    "NullspaceAudit",
    "estimates_like_a_filter",
    "falsely_observable",
    "nullspace",
    "observability_matrix",
    "rank",
    "team_scenario",
    "unobservable_basis",
]


@dataclass(frozen=True)
class FilterValues:
    """The values a filter holds at each frame (``R`` robots, frames ``0 … K``, ``m`` objects).

    Attributes
    ----------
    true_poses
        ``(R, K + 1, 4, 4)``.
    true_objects
        ``(m, 3)``.
    prior_poses
        ``T̂_{k|k−1}`` ``(R, K + 1, 4, 4)`` (frame 0: the known start).
    posterior_poses
        ``T̂_{k|k}`` ``(R, K + 1, 4, 4)``.
    odometry
        Measured relative poses ``(R, K, 4, 4)``: ``T̂_{k+1|k} = T̂_{k|k} · odometry_k``.
    objects
        Object estimates used at frame ``k`` ``(K + 1, m, 3)``; frame 0's is the first estimate.
    """

    true_poses: np.ndarray
    true_objects: np.ndarray
    prior_poses: np.ndarray
    posterior_poses: np.ndarray
    odometry: np.ndarray
    objects: np.ndarray


def team_scenario(robots: int, frames: int, objects: int) -> tuple[np.ndarray, np.ndarray]:
    """True poses ``(R, frames, 4, 4)`` turning gently, and objects ahead of every robot."""
    k = np.arange(frames)
    poses = np.tile(np.eye(4), (robots, frames, 1, 1))
    for r in range(robots):
        xi = np.zeros((frames, 6))
        xi[:, 0] = k * 1.0
        xi[:, 1] = 3.0 * r
        xi[:, 5] = 0.05 * k * (1 + r) + 0.1 * r
        xi[:, 4] = 0.02 * k
        poses[r, :, :3, :3] = se3.exp(xi)[:, :3, :3]
        poses[r, :, :3, 3] = xi[:, :3]
    j = np.arange(objects)
    points = np.column_stack([18.0 + 2.0 * j, 4.0 * np.sin(1.3 * j + 0.4), np.cos(0.7 * j)])
    return poses, points


def estimates_like_a_filter(
    true_poses: np.ndarray,
    true_objects: np.ndarray,
    rng: np.random.Generator,
    pose_std: float = 0.03,
    object_std: float = 0.3,
) -> FilterValues:
    """Estimates with a filter's structure: priors, updates that move them, noisy odometry."""
    r, n = true_poses.shape[:2]
    perturb = rng.normal(size=(r, n, 6)) * pose_std
    posterior = true_poses @ se3.exp(perturb)
    odometry = se3.inverse(true_poses[:, :-1]) @ true_poses[:, 1:]
    odometry = odometry @ se3.exp(rng.normal(size=(r, n - 1, 6)) * pose_std)
    prior = posterior.copy()
    prior[:, 1:] = posterior[:, :-1] @ odometry
    objects = true_objects + rng.normal(size=(n, *true_objects.shape)) * object_std
    return FilterValues(true_poses, true_objects, prior, posterior, odometry, objects)


def observability_matrix(
    policy: LinearizationPolicy,
    values: FilterValues,
    camera: StereoCamera,
    T_cam_body: np.ndarray,
) -> np.ndarray:
    """Stack (13) over every frame, every robot observing every object."""
    r, n = values.true_poses.shape[:2]
    m = values.true_objects.shape[0]
    dim = 6 * r + 3 * m
    transition = np.eye(dim)
    blocks = []
    for k in range(n):
        if k > 0:
            phi = np.eye(dim)
            for i in range(r):
                true_step = se3.inverse(values.true_poses[i, k - 1]) @ values.true_poses[i, k]
                step = policy.propagation_step(
                    values.prior_poses[i, k - 1],
                    values.prior_poses[i, k],
                    values.odometry[i, k - 1],
                    true_step,
                )
                phi[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] = se3.adjoint(se3.inverse(step))
            transition = phi @ transition
        points = policy.objects(values.objects[k], values.objects[0], values.true_objects)
        for i in range(r):
            # pose k enters with its prior T̂_{k|k−1}: current and first estimate at frame k
            pose = policy.poses(
                values.prior_poses[i, k], values.prior_poses[i, k], values.true_poses[i, k]
            )
            _, d_pose, d_point = observe_jacobians(camera, T_cam_body, pose, points)
            d_pose, d_point = policy.constrain(
                d_pose, d_point, values.prior_poses[i, k], values.objects[0]
            )
            h = np.zeros((m, 4, dim))
            h[:, :, 6 * i : 6 * i + 6] = d_pose
            for j in range(m):
                h[j, :, 6 * r + 3 * j : 6 * r + 3 * j + 3] = d_point[j]
            blocks.append(h.reshape(4 * m, dim) @ transition)
    return np.vstack(blocks)


def unobservable_basis(poses: np.ndarray, objects: np.ndarray) -> np.ndarray:
    """``(6R + 3m, 6)``: a rigid motion ``ξ = (δt, δθ)`` of the world in the error state at
    poses ``(R, 4, 4)`` and objects ``(m, 3)``."""
    r, m = poses.shape[0], objects.shape[0]
    out = np.zeros((6 * r + 3 * m, 6))
    for i in range(r):
        out[6 * i : 6 * i + 6] = unobservable_directions(poses[i], objects[:1])[0, :6]
    for j in range(m):
        out[6 * r + 3 * j : 6 * r + 3 * j + 3] = unobservable_directions(
            poses[0], objects[j : j + 1]
        )[0, 6:]
    return out


def falsely_observable(matrix: np.ndarray, basis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Singular values ``(6,)`` of ``M`` on the unobservable directions, relative to ``‖M‖``,
    with the right singular vectors in ``ξ = (δt, δθ)`` coordinates as rows ``(6, 6)``:
    a value well above round-off is a direction the filter wrongly treats as observable."""
    q, r_factor = np.linalg.qr(basis)
    _, s, vt = np.linalg.svd(matrix @ q)
    directions = vt @ r_factor  # back to ξ coordinates (up to scale)
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return s / np.linalg.norm(matrix, 2), directions


#: The edits :class:`NullspaceAudit` measures.
AUDITED = ("propagation", "update", "initialisation", "re-entry")
#: The edits whose information along the rigid motions :class:`NullspaceAudit` measures
#: (``information=True``), under the name it records them by, with the state's method.
INFORMED = {
    "propagation": "augment",
    "update": "update",
    "initialisation": "add_object",
    "marginalisation": "marginalize_oldest",
    "retirement": "retire_objects",
    "re-entry": "reenter_objects",
    "re-anchoring": "marginalize_objects",
    "consensus": "replace_marginal",
}


class NullspaceAudit:
    """How far each edit of a running filter's state leaves the six rigid motions of the world.

    Watches one :class:`~teamslam.msckf.filter.state.MsckfState` (wrapping its ``augment``,
    ``update``, ``add_object`` and ``reenter_objects`` on the instance; the filter runs as
    usual). Each window pose and object is given the point its unobservable directions are
    taken at — its first estimate when it enters (a pose at propagation, an object at
    initialisation) — and the point is kept through marginalisation, retirement and re-entry.
    With ``N`` those directions (:func:`unobservable_basis`'s columns), a filter keeps its
    null space when, as relative errors (``0``: kept, to round-off):

    * ``propagation``: the propagation Jacobian maps the last pose's directions onto the new
      pose's, ``‖Φ N_last − N_new‖ / ‖N_new‖``;
    * ``update``: every update's rows, whitened by their noise, annihilate ``N``,
      ``max_j ‖H N_j‖ / (‖H‖ ‖N_j‖)``;
    * ``initialisation``: a new object's cross-covariance carries the directions of its first
      estimate, ``‖F N_window − N_object‖ / ‖N_object‖`` with ``F`` the map from the window
      poses to the object that its cross-covariance implies;
    * ``re-entry``: a retired object comes back with the first estimate it left with.

    With ``information=True`` it also measures, around every edit of :data:`INFORMED`
    (consensus's rebuild of the joint included), the state's information along those
    directions, ``J = Nᵀ Σ⁻¹ N`` (``6 × 6``; ``Σ`` the whole joint, the persistent map's
    consider states included, scaled to a unit diagonal before it is factored), and records the
    information the edit gave, the largest generalised eigenvalue of
    ``(J_after, J_before)`` less one: ``0`` to round-off for an edit that adds none (an update
    whose rows annihilate ``N``), negative for one that removes some (marginalisation), positive
    for one that invents it. A Cholesky factor of the state per edit: for tests and probes.

    Attributes
    ----------
    errors
        ``{edit: [(frame, relative error), …]}`` for the edits of :data:`AUDITED`.
    information
        ``{edit: [(frame, information gained), …]}`` for the edits of :data:`INFORMED` (empty
        without ``information=True``).
    """

    def __init__(self, state, information: bool = False) -> None:
        self.state = state
        self.errors: dict[str, list[tuple[int, float]]] = {k: [] for k in AUDITED}
        self.information: dict[str, list[tuple[int, float]]] = (
            {k: [] for k in INFORMED} if information else {}
        )
        self._pose_point = {
            (int(r), int(f)): t.copy()
            for r, f, t in zip(state.robots, state.frames, state.pose_fe, strict=True)
        }
        retired = state.retired.arrays()
        self._object_point = {
            int(i): p.copy()
            for i, p in zip(
                np.concatenate([state.object_ids, retired["ids"]]),
                np.concatenate([state.object_fe, retired["fe"]]),
                strict=True,
            )
        }
        for name in ("augment", "update", "add_object", "reenter_objects"):
            setattr(state, name, getattr(self, f"_{name}")(getattr(state, name)))
        self._inside = False
        if information:
            for edit, name in INFORMED.items():
                setattr(state, name, self._informed(edit, getattr(state, name)))

    def worst(self) -> dict[str, float]:
        """The largest relative error of each edit (``nan`` for an edit that never happened)."""
        return {k: max((e for _, e in v), default=float("nan")) for k, v in self.errors.items()}

    def most_information(self) -> dict[str, float]:
        """The most information along the rigid motions any one edit gave (``nan`` for an edit
        that never happened; ``information=True``)."""
        return {
            k: max((e for _, e in v), default=float("nan")) for k, v in self.information.items()
        }

    def rigid_information(self) -> np.ndarray:
        """``J = Nᵀ Σ⁻¹ N`` ``(6, 6)``: the state's information along the rigid motions of the
        world at the points the audit keeps — of the whole joint, the persistent map's consider
        states included (retirement and re-entry move objects within it)."""
        cov, retired = self.state.with_consider()
        basis = self.basis()
        if retired.size:
            points = np.stack([self._object_point[int(i)] for i in retired])
            basis = np.vstack([basis, _point_directions(points).reshape(-1, 6)])
        scale = 1.0 / np.sqrt(np.diag(cov))
        basis = basis * scale[:, None]
        factor = scipy.linalg.cho_factor(cov * np.outer(scale, scale))
        return basis.T @ scipy.linalg.cho_solve(factor, basis)

    def _informed(self, edit: str, original):
        def informed(*args, **kwargs):
            if self._inside:  # an edit made of others (an iterated update) counts once each
                return original(*args, **kwargs)
            before = self.rigid_information()
            self._inside = True
            try:
                out = original(*args, **kwargs)
            finally:
                self._inside = False
            after = self.rigid_information()
            gained = scipy.linalg.eigh(after, before, eigvals_only=True)[-1] - 1.0
            self.information[edit].append((self._frame(), float(gained)))
            return out

        return informed

    def basis(self) -> np.ndarray:
        """``(dim, 6)``: the rigid motions ``ξ = (δt, δθ)`` of the world in the state's error
        state, at the points the audit keeps."""
        s = self.state
        out = np.zeros((s.dim, 6))
        if s.n_poses:
            points = np.stack(
                [self._pose_point[int(r), int(f)] for r, f in zip(s.robots, s.frames, strict=True)]
            )
            out[: 6 * s.n_poses] = se3.adjoint(se3.inverse(points)).reshape(-1, 6)
        if s.n_objects:
            points = np.stack([self._object_point[int(i)] for i in s.object_ids])
            out[6 * s.n_poses :] = _point_directions(points).reshape(-1, 6)
        return out

    def _frame(self) -> int:
        return int(self.state.frames.max())

    def _augment(self, original):
        def augment(odometry, frame, odometry_cov, robot=0, jacobian_step=None):
            s = self.state
            last = int(np.flatnonzero(s.robots == robot)[-1])
            before = self._pose_point[int(robot), int(s.frames[last])]
            step = odometry if jacobian_step is None else jacobian_step
            original(odometry, frame, odometry_cov, robot, jacobian_step)
            point = s.pose_fe[last + 1].copy()
            self._pose_point[int(robot), int(frame)] = point
            moved = se3.adjoint(se3.inverse(step)) @ se3.adjoint(se3.inverse(before))
            want = se3.adjoint(se3.inverse(point))
            error = np.linalg.norm(moved - want) / np.linalg.norm(want)
            self.errors["propagation"].append((int(frame), float(error)))

        return augment

    def _update(self, original):
        def update(jacobian, residual, noise_cov, robot=None, columns=None):
            basis = self.basis()
            if columns is not None:
                basis = basis[np.asarray(columns)]
            h = np.linalg.solve(np.linalg.cholesky(noise_cov), jacobian)
            scale = np.linalg.norm(h, 2) * np.linalg.norm(basis, axis=0)
            error = np.max(np.linalg.norm(h @ basis, axis=0) / scale) if h.size else 0.0
            self.errors["update"].append((self._frame(), float(error)))
            return original(jacobian, residual, noise_cov, robot, columns)

        return update

    def _add_object(self, original):
        def add_object(
            object_id, position, cov_pp, cov_ps, robot=None, first_estimate=None, **kwargs
        ):
            s = self.state
            window = 6 * s.n_poses
            implied = np.asarray(cov_ps)[:, :window] @ np.linalg.solve(
                s.covariance(slice(0, window)), self.basis()[:window]
            )
            original(object_id, position, cov_pp, cov_ps, robot, first_estimate, **kwargs)
            point = s.object_fe[-1].copy()
            self._object_point[int(object_id)] = point
            want = _point_directions(point[None])[0]
            error = np.linalg.norm(implied - want) / np.linalg.norm(want)
            self.errors["initialisation"].append((self._frame(), float(error)))

        return add_object

    def _reenter_objects(self, original):
        def reenter_objects(ids, frame):
            original(ids, frame)
            s = self.state
            for i in np.asarray(ids, dtype=np.int64).ravel().tolist():
                want = _point_directions(self._object_point[i][None])[0]
                got = _point_directions(s.object_fe[s.object_slots(np.array([i]))])[0]
                error = np.linalg.norm(got - want) / np.linalg.norm(want)
                self.errors["re-entry"].append((int(frame), float(error)))

        return reenter_objects


def _point_directions(points: np.ndarray) -> np.ndarray:
    """``(k, 3, 6)``: a point's motion ``δt − p^ δθ`` under a rigid motion of the world."""
    return unobservable_directions(np.eye(4), points)[:, 6:, :]
