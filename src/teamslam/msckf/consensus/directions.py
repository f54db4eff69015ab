"""Consensus, unobservable directions: an average that adds nothing along the rigid motions.

A first-estimates filter (``fej``, ``oc``) keeps the six rigid motions of the world unobservable
at the points its Jacobians were evaluated at — for an object, the first estimate this robot
took of it. :func:`constrained_average` turns the consensus average of the common objects'
marginal into a change that leaves this robot's information along those directions, and its
mean along them, exactly as they were; every quantity the rigid motions leave unchanged (the
map's shape) takes the average's mean and variance. Contract: ``Ω' U = Ω U`` for the directions
``U`` at the first estimates, and ``cᵀ μ' = cᵀ μ̄``, ``cᵀ Σ' c = cᵀ Σ̄ c`` for every ``c`` with
``cᵀ U = 0``. Derivation: the concept page *Linearisation*, section *Consensus and first
estimates*.
"""

from __future__ import annotations

import numpy as np

from teamslam.gaussian import spd_inverse
from teamslam.msckf.filter.linearization import unobservable_directions

__all__ = ["constrained_average", "rigid_directions"]

# directions whose information, relative to the largest (columns scaled to unit information),
# is below this are not six independent motions of the marginal's objects (one object: the
# rotations are translations; objects on one line: the rotation about it moves none) and are
# left out of the basis
_RELATIVE_RANK = 1e-10


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
