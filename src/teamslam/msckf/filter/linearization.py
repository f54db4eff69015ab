"""Where the MSCKF evaluates its Jacobians: standard, first-estimate or ideal (one policy).

The three filters run the same propagation, updates, object initialisation and consensus; they
differ only in the point at which the Jacobians are evaluated — the 3D counterpart of
:mod:`teamslam.ekf2d.linearization` (FEJ multi-robot EKF paper, §3).

Derivation
----------
Error state (right perturbation, :mod:`teamslam.geometry`): ``T = T̂ · exp(ε^)``, ``p = p̂ + p̃``.
Odometry and stereo measure only relative quantities, so moving the whole world by a rigid
``G = (R_G, t_G)`` changes no measurement: the system has 6 unobservable directions. In the
error state, an infinitesimal ``G = exp(ξ^)``, ``ξ = (δt, δθ)`` moves

* a pose ``T = (R, t)`` by ``ε = Ad(T⁻¹) ξ = (Rᵀ(δt + δθ × t), Rᵀ δθ)``;
* a point by ``p̃ = δt + δθ × p``.

So the unobservable directions ``N(x)`` depend on the poses and points. With
``p_body = Rᵀ(p − t)`` and ``∂z/∂ε = D [−I, p_body^]``, ``∂z/∂p = D Rᵀ`` (``D = ∂z/∂p_body``,
:mod:`teamslam.msckf.filter.models`), one observation's Jacobian annihilates ``N`` exactly when
pose and
point in ``N`` are the ones the Jacobian was evaluated at:
``D Rᵀ[−(δt + δθ × t) − δθ × (p − t) + δt + δθ × p] = 0``.

Propagation ``T_{k+1} = T_k δT`` has the Jacobian ``Φ = Ad(δ⁻¹)``, which maps
``Ad(T_k⁻¹) ξ`` to ``Ad(T_{k+1}⁻¹) ξ`` exactly when ``δ = T_k⁻¹ T_{k+1}`` for the two points
at which ``N`` is taken. The local observability matrix ``[H_k; H_{k+1} Φ_k; …]`` keeps the
6-dimensional nullspace ``N`` of the true system if and only if, for every pose and every point,

1. **every** Jacobian ``H`` that involves it (object updates, geometric-feature rows, object
   initialisation, at every time step) is evaluated at **one** value of it, and
2. every propagation Jacobian uses ``δ = T̄_k⁻¹ T̄_{k+1}`` with ``T̄`` those values, so the
   ``δ`` telescope: ``δ_0 δ_1 ⋯ δ_{k−1} = T̄_0⁻¹ T̄_k``.

The standard filter breaks both: it evaluates ``H`` at the current estimate, which each update
moves, and ``Φ`` at the measured odometry ``δT = T̂_{k|k}⁻¹ T̂_{k+1|k}``, which does not compose to
the poses it later linearises ``H`` at. The result (shown by
:mod:`teamslam.msckf.filter.observability`) is a rank increase: the filter treats global rotation
directions as observable and becomes overconfident.

The first estimates that satisfy 1 and 2 with the values a filter has:

=========== ====================================== ==========================================
policy      propagation ``Φ = Ad(δ⁻¹)``             ``H``: window pose, object, feature point
=========== ====================================== ==========================================
standard    ``δ = δT`` (measured odometry)          current estimates; feature: triangulated
first       ``δ = T̄_k⁻¹ T̂_{k+1|k}``, ``T̄_k`` the     each pose's ``T̄`` = its value when it
estimate    pose's first estimate                   entered the window (``T̂_{k|k−1}``);
                                                    object: current estimate, compensated to
                                                    annihilate ``N`` at the object's first
                                                    estimate (below); feature: triangulated
                                                    (any one point for all its rows: it is
                                                    projected out, eq. 24)
ideal       ``δ`` = true relative pose              ground truth (simulation only)
=========== ====================================== ==========================================

Residuals are always formed at the current estimate; only the Jacobians move.

**Objects: first-estimate directions, compensated current Jacobians.** Condition 1 asks that
every Jacobian of an object annihilate ``N`` at **one** value ``p̄`` of the object; it does not
ask that the Jacobian be evaluated there. Evaluating it at ``p̄`` (textbook FEJ) is one way, and
a poor one in 3D: an object is first estimated by stereo from a few frames, up to tens of metres
away, so ``p̄`` can lie metres from the truth; and a robot's first-estimate poses are in the
frame its estimate had when they entered the window, which later corrections (objects seen
again, consensus) move, so the relative geometry ``T̄_k⁻¹ p̄`` of a late pose and an early
object can be far from what the camera measures. Jacobians taken there make updates with the
wrong gain and covariance (measured, ``teamslam montecarlo --robots 3 --steps 100 --runs 6``:
first-estimate object Jacobians gave pose ANEES 2.1–2.3 where the standard filter gave 1.1).
So ``fej`` evaluates an object row ``H`` (the 4 × 9 block of the current pose and the object)
at the current estimate — where the residual is formed, the best available point — and changes
it by the least amount that makes it annihilate the directions ``U`` (9 × 6,
:func:`unobservable_directions`) at the pose's and the object's first estimates, "least" in the
metric of what the update uses, the predicted innovation ``ΔH x̃``
with ``x̃ ~ N(0, P)`` (``P`` the 9 × 9 covariance of the pose and the object):

    minimise ``tr(ΔH P ΔHᵀ)`` subject to ``(H + ΔH) U = 0``  ⇒
    ``H* = H − H U (Uᵀ P⁻¹ U)⁻¹ Uᵀ P⁻¹``

(:func:`annihilate`). Every row ``H*`` annihilates the same ``N`` the first-estimate poses and
propagation keep, so the nullspace — and the rank of the observability matrix — is that of
textbook FEJ, whatever ``P``. The residual is formed at the current estimate, so it is
``r ≈ H x̃ + n = H* x̃ − ΔH x̃ + n``: the compensation ``ΔH = H* − H`` leaves a term the rows
do not model, of covariance ``ΔH P ΔHᵀ`` — the very quantity the metric minimises. ``fej`` adds
it to the object's measurement noise, ``R = σ² I + ΔH P ΔHᵀ``
(:meth:`FirstEstimate.linearization_noise`; the rows are whitened by it per object), so the
update does not take the compensated rows for exact. The idea — keep the first estimates'
observability, evaluate at the best estimate, account for the difference — is that of FEJ2
(Chen, Geneva and Huang, ICRA 2022); the compensation above is this module's own.

A fourth policy, ``oc`` (observability-constrained, after Huang, Mourikis and Roumeliotis'
OC-EKF), makes the same kind of change with the unweighted (Frobenius) minimum:
``H* = H − H U (UᵀU)⁻¹ Uᵀ``. That metric mixes metres, radians and the units of ``p`` and
changes the columns the estimate is sure of as readily as the others; it keeps the nullspace
but, measured, leaves the filter more overconfident than the covariance metric.

**Consensus and first estimates.** Consensus (Prop. 2) replaces the marginal of the common
objects and shifts everything else linearly — it evaluates no Jacobian. A robot's own
Jacobians stay consistent with its nullspace only if the points they use stay fixed, so an
object **keeps the first estimate it was initialised with** when consensus moves it; resetting
it to the averaged mean would change the linearisation point of an object whose earlier
Jacobians are already in the covariance — exactly the standard filter's fault. (The robots of a
team then linearise a common object at slightly different points; the information that leaks
between their nullspaces is second order in that difference.)
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


def linearization_policy(name: str) -> LinearizationPolicy:
    """Policy by name: ``std``, ``fej``, ``ideal`` or ``oc``."""
    try:
        return POLICIES[name]()
    except KeyError:
        raise ValueError(f"unknown linearisation {name!r}; choose std, fej, ideal or oc") from None
