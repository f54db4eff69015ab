"""Where the MSCKF evaluates its Jacobians: ``std``, ``fej``, ``ideal`` or ``oc`` (one policy).

The filters share propagation, updates, initialisation and consensus and differ only in where
a :class:`LinearizationPolicy` evaluates the Jacobians; residuals are always formed at the
current estimate. ``fej`` and ``oc`` change an object row by the least amount that makes it
annihilate the unobservable directions at the first estimates (:func:`annihilate`), ``fej`` in
the covariance metric with the compensation added to the noise. Derivation (unobservable
directions, the two conditions, why objects keep their first estimate under consensus): the
concept page *Linearisation* (``docs/concepts/linearization.md``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from teamslam.datasets.model import TeamDataset
from teamslam.gaussian import NotPositiveDefiniteError
from teamslam.geometry import se3, so3

__all__ = [
    "POLICIES",
    "FirstEstimate",
    "GroundTruth",
    "Ideal",
    "LinearizationPolicy",
    "ObservabilityConstrained",
    "Standard",
    "annihilate",
    "first_estimate_distance",
    "keeps_first_estimates",
    "linearization_policy",
    "unobservable_directions",
]


@dataclass(frozen=True)
class GroundTruth:
    """What the ideal filter linearises at: true poses, objects and feature points.

    Attributes
    ----------
    T_world_body
        ``(N, 4, 4)`` true poses of one robot, by frame.
    dataset
        The team (true objects; the landmark behind each geometric track).
    """

    T_world_body: np.ndarray
    dataset: TeamDataset

    def objects(self, ids: np.ndarray) -> np.ndarray:
        """True positions ``(k, 3)`` of object ids."""
        out = self.dataset.object_position(ids)
        if not np.all(np.isfinite(out)):
            raise ValueError("the ideal linearisation needs every object's true position")
        return out

    def track_points(self, track_ids: np.ndarray) -> np.ndarray:
        """True positions ``(k, 3)`` of the landmarks geometric tracks observe."""
        pairs = self.dataset.track_landmarks
        order = np.argsort(pairs[:, 0])
        tracks = pairs[order, 0]
        track_ids = np.asarray(track_ids, dtype=np.int64)
        if tracks.size == 0:
            raise ValueError("the ideal linearisation needs the landmark of every feature track")
        pos = np.clip(np.searchsorted(tracks, track_ids), 0, tracks.size - 1)
        if not np.all(tracks[pos] == track_ids):
            raise ValueError("the ideal linearisation needs the landmark of every feature track")
        landmarks = pairs[order[pos], 1]
        index = np.searchsorted(self.dataset.landmark_ids, landmarks)
        return self.dataset.landmark_positions[index]


class LinearizationPolicy:
    """Base class: which pose, object and point values the Jacobians are evaluated at."""

    name = "base"
    needs_truth = False

    def propagation_step(
        self, fe_last: np.ndarray, new_pose: np.ndarray, odometry: np.ndarray, true_step
    ) -> np.ndarray:
        """Relative pose ``δ`` of the propagation Jacobian ``Ad(δ⁻¹)``.

        Parameters
        ----------
        fe_last
            First estimate of the pose being propagated.
        new_pose
            The propagated pose ``T̂_{k+1|k}``.
        odometry
            The measured (or substituted) relative pose.
        true_step
            The true relative pose, or ``None``.
        """
        raise NotImplementedError

    def poses(self, current: np.ndarray, first: np.ndarray, truth: np.ndarray | None):
        """Window poses ``(..., 4, 4)`` for ``H``."""
        raise NotImplementedError

    def objects(self, current: np.ndarray, first: np.ndarray, truth: np.ndarray | None):
        """Object positions ``(k, 3)`` for ``H``."""
        raise NotImplementedError

    def feature_points(self, triangulated: np.ndarray, truth: np.ndarray | None):
        """Geometric feature points ``(k, 3)`` for ``H``."""
        return triangulated

    #: whether :meth:`linearization_noise` adds to the object rows' noise
    compensates = False

    def linearization_noise(
        self, h_used: np.ndarray, h_current: np.ndarray, cov: np.ndarray
    ) -> np.ndarray:
        """``(k, 4, 4)`` covariance added to the object rows' noise for using ``h_used``
        instead of the current-estimate Jacobians ``h_current`` (both ``(k, 4, 9)``, pose
        then object columns; ``cov`` their ``(k, 9, 9)`` covariance): zero unless the policy
        :attr:`compensates`."""
        return np.zeros((*h_used.shape[:-1], h_used.shape[-2]))

    def constrain(
        self,
        d_pose: np.ndarray,
        d_point: np.ndarray,
        pose_first: np.ndarray,
        object_first: np.ndarray,
        cov: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Object-observation Jacobians ``(k, 4, 6)``, ``(k, 4, 3)`` as the update uses them.

        Parameters
        ----------
        d_pose, d_point
            The Jacobians evaluated at :meth:`poses` and :meth:`objects`.
        pose_first, object_first
            ``(4, 4)`` first estimate of the observing pose, ``(k, 3)`` of the objects.
        cov
            ``(k, 9, 9)`` covariance of the observing pose and each object (pose columns
            first), or ``None`` (no covariance at hand, e.g. an observability analysis).
        """
        return d_pose, d_point


class Standard(LinearizationPolicy):
    """Every Jacobian at the current estimate; propagation at the measured odometry."""

    name = "std"

    def propagation_step(self, fe_last, new_pose, odometry, true_step):
        return odometry

    def poses(self, current, first, truth):
        return current

    def objects(self, current, first, truth):
        return current


class FirstEstimate(LinearizationPolicy):
    """Each pose at its first estimate, ``δ`` telescoping over first estimates; object rows at
    the current estimate, compensated (covariance metric) to annihilate the unobservable
    directions at the first estimates."""

    name = "fej"

    def propagation_step(self, fe_last, new_pose, odometry, true_step):
        return se3.inverse(fe_last) @ new_pose

    def poses(self, current, first, truth):
        return first

    def objects(self, current, first, truth):
        return current

    compensates = True

    def constrain(self, d_pose, d_point, pose_first, object_first, cov=None):
        return _annihilate_rows(d_pose, d_point, pose_first, object_first, cov)

    def linearization_noise(self, h_used, h_current, cov):
        change = h_used - h_current
        noise = change @ cov @ np.swapaxes(change, -1, -2)
        return 0.5 * (noise + np.swapaxes(noise, -1, -2))


class Ideal(LinearizationPolicy):
    """Every Jacobian at the ground truth (simulation only)."""

    name = "ideal"
    needs_truth = True

    def propagation_step(self, fe_last, new_pose, odometry, true_step):
        return true_step

    def poses(self, current, first, truth):
        return truth

    def objects(self, current, first, truth):
        return truth

    def feature_points(self, triangulated, truth):
        return truth


def unobservable_directions(T_world_body: np.ndarray, p_world: np.ndarray) -> np.ndarray:
    """``(k, 9, 6)``: error-state motion of a pose and a point under a global ``ξ = (δt, δθ)``.

    Pose: ``Ad(T⁻¹) ξ``; point: ``δt − p^ δθ``.
    """
    T_world_body = np.broadcast_to(T_world_body, (*p_world.shape[:-1], 4, 4))
    out = np.zeros((*p_world.shape[:-1], 9, 6))
    out[..., :6, :] = se3.adjoint(se3.inverse(T_world_body))
    out[..., 6:, :3] = np.eye(3)
    out[..., 6:, 3:] = -so3.hat(p_world)
    return out


def annihilate(h: np.ndarray, u: np.ndarray, cov: np.ndarray | None = None) -> np.ndarray:
    """The least change of Jacobians ``h`` that makes them annihilate directions ``u``.

    Parameters
    ----------
    h
        ``(k, m, n)`` Jacobians.
    u
        ``(k, n, d)`` directions, full column rank.
    cov
        ``(k, n, n)`` positive definite metric, or ``None`` for the identity.

    Returns
    -------
    ``(k, m, n)`` ``H* = H − H U (Uᵀ P⁻¹ U)⁻¹ Uᵀ P⁻¹``: ``H* U = 0`` and ``tr((H* − H) P
    (H* − H)ᵀ)`` least (``P = I``: the Frobenius norm of the change). Rows that already
    annihilate ``u`` are unchanged.
    """
    if cov is None:
        p_inv_u = u
    else:
        # P⁻¹U by Cholesky: W = L⁻¹U, P⁻¹U = L⁻ᵀW
        try:
            chol = np.linalg.cholesky(cov)
        except np.linalg.LinAlgError:
            raise NotPositiveDefiniteError(
                "the covariance that weighs the Jacobian change is not positive definite"
            ) from None
        p_inv_u = np.linalg.solve(np.swapaxes(chol, -1, -2), np.linalg.solve(chol, u))
    gram = np.swapaxes(u, -1, -2) @ p_inv_u
    gram = 0.5 * (gram + np.swapaxes(gram, -1, -2))
    return h - (h @ u) @ np.linalg.solve(gram, np.swapaxes(p_inv_u, -1, -2))


def first_estimate_distance(current: np.ndarray, first: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Squared Mahalanobis distance of objects' first estimates from their current estimates,
    in their marginal covariances.

    Parameters
    ----------
    current, first
        ``(k, 3)`` current and first estimates of the objects.
    cov
        ``(k, 3, 3)`` marginal covariances of the objects.

    Returns
    -------
    ``(k,)`` ``(p̂ − p̄)ᵀ Σ⁻¹ (p̂ − p̄)`` (Cholesky solves): χ²(3)-distributed when ``p̄`` is a
    value of the object its estimate still allows.
    """
    chol = np.linalg.cholesky(0.5 * (cov + np.swapaxes(cov, -1, -2)))
    white = np.linalg.solve(chol, (current - first)[..., None])[..., 0]
    return (white**2).sum(axis=-1)


def _annihilate_rows(d_pose, d_point, pose_first, object_first, cov):
    """Object rows ``(k, 4, 6)``, ``(k, 4, 3)`` changed to annihilate the first estimates'
    unobservable directions (:func:`annihilate`)."""
    u = unobservable_directions(pose_first, object_first)  # (k, 9, 6)
    h = annihilate(np.concatenate([d_pose, d_point], axis=-1), u, cov)
    return h[..., :6], h[..., 6:]


class ObservabilityConstrained(FirstEstimate):
    """Poses at first estimates; objects at the current estimate, Jacobians changed by the
    least Frobenius norm so that they annihilate the unobservable directions taken at the first
    estimates (OC-EKF)."""

    name = "oc"
    compensates = False

    def constrain(self, d_pose, d_point, pose_first, object_first, cov=None):
        return _annihilate_rows(d_pose, d_point, pose_first, object_first, None)


POLICIES: dict[str, type[LinearizationPolicy]] = {
    "std": Standard,
    "fej": FirstEstimate,
    "ideal": Ideal,
    "oc": ObservabilityConstrained,
}


def keeps_first_estimates(name: str) -> bool:
    """Whether policy ``name`` keeps the unobservable directions at first estimates (``fej``,
    ``oc``)."""
    return issubclass(POLICIES.get(name, LinearizationPolicy), FirstEstimate)


def linearization_policy(name: str) -> LinearizationPolicy:
    """Policy by name: ``std``, ``fej``, ``ideal`` or ``oc``."""
    try:
        return POLICIES[name]()
    except KeyError:
        raise ValueError(f"unknown linearisation {name!r}; choose std, fej, ideal or oc") from None
