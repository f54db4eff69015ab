"""Consensus, unobservable directions: an average that adds nothing along the rigid motions,
and marginals moved to the receiver's first estimates.

A first-estimates filter (``fej``, ``oc``) keeps the six rigid motions of the world unobservable
at the points its Jacobians were evaluated at — for an object, the first estimate this robot
took of it. :func:`shape_average` (the plain average, eq. 19) averages the robots' marginals of
the map's *shape* — each completed marginal with its part along our rigid motions marginalised
out — and keeps our own information along those motions, and our mean along them, exactly as
they were; averaging again a marginal that did not change adds nothing. Contract: ``Ω' U = Ω U``
for the directions ``U`` at the first estimates, ``Uᵀ Ω (μ' − μ) = 0``, and on the shape
(``cᵀ U = 0``) the eq. 19 average of the robots' shape marginals.
:func:`constrained_average` constrains a finished average instead (the hybrid and increments
rules, per-object marginals): the shape takes the average's marginal. Derivation: the concept
page *Linearisation*, section *Consensus and first estimates*.
:func:`reexpressed_information` moves a marginal's rigid-motion directions from one set of
points to another, its information along them — and along every direction orthogonal to them
in its own metric — unchanged (``consensus.at_first_estimates``): a sender moves its marginal
from its first estimates to its means, the receiver from those means to its own first
estimates (:func:`at_first_estimates`), so that a neighbour's marginal says along our rigid
motions what it said along its own, and no more.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from teamslam.gaussian import spd_inverse
from teamslam.msckf.consensus.checks import ReceivedMarginal
from teamslam.msckf.filter.linearization import unobservable_directions
from teamslam.msckf.filter.state import MsckfState

__all__ = [
    "at_first_estimates",
    "constrained_average",
    "reexpressed_information",
    "rigid_directions",
    "shape_average",
]

# directions whose information, relative to the largest (columns scaled to unit information),
# is below this are not six independent motions of the marginal's objects (one object: the
# rotations are translations; objects on one line: the rotation about it moves none) and are
# left out of the basis
_RELATIVE_RANK = 1e-10

#: Fewest objects whose rigid motions span six directions (three not on one line).
MIN_OBJECTS = 3


def rigid_directions(points: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """``(3k, 6)``: the motion ``δt − (p − c)^ δθ`` of points ``(k, 3)`` under a rigid motion
    ``ξ = (δt, δθ)`` about ``centre`` ``c`` (the same span as about the origin)."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    return unobservable_directions(np.eye(4), points - centre)[:, 6:, :].reshape(-1, 6)


def _basis(info: np.ndarray, first: np.ndarray) -> np.ndarray:
    """The rigid motions at ``first`` that the marginal ``info`` tells apart, ``(3k, r)``."""
    u = rigid_directions(first, first.mean(axis=0))
    gram = u.T @ info @ u
    scale = np.sqrt(np.clip(np.diag(gram), 0.0, None))
    keep = scale > 0
    u, gram, scale = u[:, keep], gram[np.ix_(keep, keep)], scale[keep]
    values, vectors = np.linalg.eigh(gram / np.outer(scale, scale))
    kept = values > _RELATIVE_RANK * values[-1]
    return u @ (vectors[:, kept] / scale[:, None])


def constrained_average(
    own_mean: np.ndarray,
    own_info: np.ndarray,
    mean: np.ndarray,
    cov: np.ndarray,
    first: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The consensus average ``N(mean, cov)`` of our marginal ``N(own_mean, own_info⁻¹)`` of
    ``k`` objects, with our own information and mean along our rigid motions at the objects'
    first estimates ``first`` (``(k, 3)``) in place of the average's.

    With ``Ω`` our information, ``Ω̄ = cov⁻¹`` the average's and ``U`` the rigid motions at
    ``first``: the average's information about the quantities the rigid motions leave unchanged
    is ``Ω̄ − Ω̄ U (Uᵀ Ω̄ U)⁻¹ Uᵀ Ω̄`` (its information along ``U`` marginalised out), ours along
    ``U`` is ``Ω U (Uᵀ Ω U)⁻¹ Uᵀ Ω``; their sum is ``Ω'`` (positive definite), and
    ``μ' = μ + P (μ̄ − μ)`` with ``P = I − U (Uᵀ Ω U)⁻¹ Uᵀ Ω`` (``P U = 0``) moves the mean
    to the average's on those quantities and not at all along ``U``.
    Returns ``(μ', Ω'⁻¹)``.
    """
    u = _basis(own_info, np.asarray(first, dtype=float).reshape(-1, 3))
    avg_info = spd_inverse(cov, "averaged covariance")
    info_u, avg_u = own_info @ u, avg_info @ u
    gram, avg_gram = u.T @ info_u, u.T @ avg_u
    gram, avg_gram = 0.5 * (gram + gram.T), 0.5 * (avg_gram + avg_gram.T)
    solve = np.linalg.solve(gram, info_u.T)  # (r, 3k): (Uᵀ Ω U)⁻¹ Uᵀ Ω
    info = avg_info - avg_u @ np.linalg.solve(avg_gram, avg_u.T) + info_u @ solve
    info = 0.5 * (info + info.T)
    new_cov = spd_inverse(info, "constrained average")
    step = mean - own_mean
    return own_mean + step - u @ (solve @ step), new_cov


def shape_average(
    own_mean: np.ndarray,
    own_info: np.ndarray,
    terms: list[tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray]],
    first: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 19 on the map's shape: the robots' marginals of the quantities our rigid motions
    leave unchanged are averaged, our own marginal along the rigid motions is kept.

    Our marginal of the ``k`` objects ``y`` is ``N(own_mean, own_info⁻¹)``; ``first`` (``(k, 3)``)
    our first estimates of them. Each neighbour's term ``(w_j, index_j, M_j, m_j, Ω_C)`` is
    its information ``M_j`` and information vector ``m_j`` of the coordinates ``index_j`` of
    ``y`` (whole objects) and ``Ω_C`` our own information of those, completed by our conditional
    (eq. 42): ``Ω_j = Ω + Lⱼᵀ (M_j − Ω_C) Lⱼ``. With ``S(A) = A − A U (Uᵀ A U)⁻¹ Uᵀ A`` the
    information of ``A`` about the shape (its part along the rigid motions ``U`` marginalised
    out) and weights summing to one with our own,

        ``Ω' = Ω + Σ_j w_j (S(Ω_j) − S(Ω))``,  ``μ' = μ + Ω'⁻¹ Σ_j w_j S(Ω_j) (μ_j − μ)``

    — ``S(Ω') = Σ w_j S(Ω_j)`` (ours included), ``Ω' U = Ω U`` and ``Uᵀ Ω (μ' − μ) = 0``. The
    shape terms are a convex combination, so a marginal that equals ours adds nothing, and
    averaging again marginals that did not change does not add information (the marginal of the
    joint average, :func:`constrained_average`, gains ``S(Σ w_j Ω_j) − Σ w_j S(Ω_j)`` each time).
    Returns ``(μ', Ω'⁻¹)``.
    """
    u = _basis(own_info, np.asarray(first, dtype=float).reshape(-1, 3))
    own_u = own_info @ u
    own_gram = u.T @ own_u
    own_rigid = own_u @ np.linalg.solve(0.5 * (own_gram + own_gram.T), own_u.T)
    info = own_info.copy()
    shift = np.zeros(own_mean.size)
    for weight, index, m_info, m_eta, own_sub in terms:
        sub = np.asarray(index, dtype=np.intp)
        # Ω_j − Ω lives on the neighbour's objects; d_j = Ω_j (μ_j − μ) too
        delta = np.asarray(m_info, dtype=float) - own_sub
        info_j = own_info.copy()
        info_j[np.ix_(sub, sub)] += delta
        d = np.zeros(own_mean.size)
        d[sub] = m_eta - m_info @ own_mean[sub]
        w_u = info_j @ u
        gram = u.T @ w_u
        solve = np.linalg.solve(0.5 * (gram + gram.T), np.column_stack([w_u.T, u.T @ d]))
        rigid_j = w_u @ solve[:, :-1]
        info[np.ix_(sub, sub)] += weight * delta
        info += weight * (own_rigid - rigid_j)
        shift += weight * (d - w_u @ solve[:, -1])
    info = 0.5 * (info + info.T)
    new_cov = spd_inverse(info, "constrained average")
    return own_mean + new_cov @ shift, new_cov


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
    if not correlation[0] > _RELATIVE_RANK * correlation[-1]:
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
    means, with them moved to our first estimates of its objects
    (:func:`reexpressed_information`); a per-object marginal as it is."""
    if marginal.per_object:
        return marginal
    first = state.object_fe[state.object_slots(marginal.ids)]
    mean = spd_inverse(marginal.info, "neighbour marginal information") @ marginal.info_vector
    info = reexpressed_information(marginal.info, mean, first)
    prior = marginal.prior
    if prior is not None and prior[0].any():
        held, p_info, p_eta = prior
        p_mean = spd_inverse(p_info, "prior information") @ p_eta
        p_info = reexpressed_information(p_info, p_mean, first[held])
        prior = (held, p_info, p_info @ p_mean)
    return replace(marginal, info=info, info_vector=info @ mean, prior=prior)
