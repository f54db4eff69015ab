"""Consensus, unobservable directions: a marginal's information moved to other first estimates.

A first-estimates filter (``fej``, ``oc``) keeps the rigid motions of the world unobservable at
the points its Jacobians were evaluated at; for an object that is the object's own first
estimate, which each robot took for itself. :func:`reexpressed_information` changes the
coordinates of a joint marginal of objects so that its rigid-motion directions, taken at one set
of points, become those at another, leaving its information along them — and along everything
orthogonal to them in its own metric — as it was. A robot's marginal then travels with its
directions at its own mean, and the receiver moves them to its first estimates before it
averages, so that a neighbour's marginal tells it no more about the rigid motions than it tells
the neighbour. Derivation: the concept page *Linearisation*, section *Consensus and first
estimates*.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from teamslam.gaussian import spd_inverse
from teamslam.msckf.consensus.checks import ReceivedMarginal
from teamslam.msckf.filter.linearization import unobservable_directions
from teamslam.msckf.filter.state import MsckfState

__all__ = ["MIN_OBJECTS", "at_first_estimates", "reexpressed_information", "rigid_directions"]

#: Fewest objects whose rigid motions span six directions (three not on one line).
MIN_OBJECTS = 3

# smallest eigenvalue, relative to the largest, of the correlation of the six directions in the
# marginal's metric (below: the objects almost on a line, the rotation about it not seen)
_MIN_CONDITION = 1e-10


def rigid_directions(points: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """``(3k, 6)``: the motion ``δt − (p − c)^ δθ`` of points ``(k, 3)`` under a rigid motion
    ``ξ = (δt, δθ)`` about ``centre`` ``c`` (the same span as about the origin)."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    return unobservable_directions(np.eye(4), points - centre)[:, 6:, :].reshape(-1, 6)


def reexpressed_information(
    info: np.ndarray,
    points_from: np.ndarray,
    points_to: np.ndarray,
    cov: np.ndarray | None = None,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """``(3k, 3k)`` information of ``k`` objects with its rigid motions moved from
    ``points_from`` to ``points_to`` (both ``(k, 3)`` or ``(3k,)``); with ``cov`` (``info⁻¹``)
    the pair ``(info, cov)`` re-expressed, the covariance as ``T Σ Tᵀ`` (no inversion).

    With ``U_a``, ``U_b`` the directions at the two sets of points (:func:`rigid_directions`,
    about the same centre) the coordinates change by ``T = I + (U_b − U_a) G`` with
    ``G = (U_aᵀ Ω U_a)⁻¹ U_aᵀ Ω``, so ``T U_a = U_b`` and ``T`` leaves every direction
    ``Ω``-orthogonal to ``U_a`` as it is; the result is ``T⁻ᵀ Ω T⁻¹``, whose information along
    ``U_b`` is ``Ω``'s along ``U_a``. ``info`` is returned unchanged (the same array) when the
    points agree, with fewer than :data:`MIN_OBJECTS` objects or when the objects lie almost on
    one line (then a rigid motion is not six directions of the marginal).
    """
    info = np.asarray(info, dtype=float)
    unchanged = info if cov is None else (info, cov)
    points_from = np.asarray(points_from, dtype=float).reshape(-1, 3)
    points_to = np.asarray(points_to, dtype=float).reshape(-1, 3)
    k = points_from.shape[0]
    if k < MIN_OBJECTS or np.array_equal(points_from, points_to):
        return unchanged
    centre = points_from.mean(axis=0)
    u_from = rigid_directions(points_from, centre)
    change = rigid_directions(points_to, centre) - u_from  # (3k, 6): rotation columns only
    info_u = info @ u_from
    gram = u_from.T @ info_u
    gram = 0.5 * (gram + gram.T)
    scale = np.sqrt(np.diag(gram))
    if not np.all(scale > 0):
        return unchanged
    correlation = np.linalg.eigvalsh(gram / np.outer(scale, scale))
    if not correlation[0] > _MIN_CONDITION * correlation[-1]:
        return unchanged
    g = np.linalg.solve(gram, info_u.T)  # (6, 3k)
    # T⁻¹ = I − D (I + G D)⁻¹ G (Woodbury, D = U_b − U_a)
    inner = np.eye(6) + g @ change
    try:
        middle = np.linalg.solve(inner, g)  # (6, 3k)
    except np.linalg.LinAlgError:
        return unchanged
    right = info - (info @ change) @ middle  # Ω T⁻¹
    out = right - middle.T @ (change.T @ right)  # T⁻ᵀ Ω T⁻¹
    out = 0.5 * (out + out.T)
    if cov is None:
        return out
    # T Σ Tᵀ with G Σ = (U_aᵀ Ω U_a)⁻¹ U_aᵀ: Σ + D M + Mᵀ Dᵀ + D (U_aᵀ Ω U_a)⁻¹ Dᵀ
    m = np.linalg.solve(gram, u_from.T)  # (6, 3k)
    moved = change @ m
    cov_out = cov + moved + moved.T + change @ np.linalg.solve(gram, change.T)
    return out, 0.5 * (cov_out + cov_out.T)


def at_first_estimates(state: MsckfState, marginal: ReceivedMarginal) -> ReceivedMarginal:
    """A neighbour's joint marginal (and prior), sent with its rigid-motion directions at its
    means, with them moved to our first estimates of its objects (:func:`reexpressed_information`);
    a per-object marginal, or one without its mean, as it is."""
    if marginal.per_object or marginal.mean is None:
        return marginal
    first = state.object_fe[state.object_slots(marginal.ids)]
    info = reexpressed_information(marginal.info, marginal.mean, first)
    prior = marginal.prior
    if prior is not None and prior[0].any():
        held, p_info, p_eta = prior
        p_mean = spd_inverse(p_info, "prior information") @ p_eta
        p_info = reexpressed_information(p_info, p_mean, first[held])
        prior = (held, p_info, p_info @ p_mean)
    return replace(marginal, info=info, info_vector=info @ marginal.mean, prior=prior)
