"""Consensus by intersection: fusion that is consistent whatever the robots share, without the
dilution of a fixed-weight average (``consensus.rule = ci`` and ``consensus.rule = ici``).

The paper's average (eq. 19) is covariance intersection with fixed weights — the Metropolis
weights: whatever the correlation between the robots' marginals it never claims more than
they hold, but a robot that knew an object better than its neighbours ends with less than it
had. Here the weight is chosen per exchange, not fixed:

* :func:`intersection_fusion` with ``kind="ci"`` is covariance intersection (Julier and
  Uhlmann 1997), ``Ω' = ω Ω_a + (1 − ω) Ω_b``, consistent for any correlation between the two
  estimates;
* with ``kind="ici"`` it is inverse covariance intersection (Noack, Sijs, Reinhardt and
  Hanebeck 2017), ``Ω' = Ω_a + Ω_b − (ω Σ_a + (1 − ω) Σ_b)⁻¹``, consistent when what the two
  share is common information of unknown size (information one robot received from the other
  through consensus, or both from a third) — tighter than covariance intersection, and fusing
  an estimate with itself returns it.

In both, ``ω ∈ [0, 1]`` minimises the determinant of the fused covariance. Both estimates are
brought to the coordinates in which ``Σ_a = I`` and ``Σ_b`` is diagonal (one Cholesky factor and
one symmetric eigendecomposition), where the fused information is diagonal for every ``ω``, so
the search over ``ω`` costs a few vector operations. A robot fuses its marginal of the common
objects ``y`` with each neighbour's marginal (completed by its own conditional, Prop. 2) in turn
and rebuilds its joint (Prop. 2); a first-estimates filter keeps its own information along its
rigid motions (:func:`~teamslam.msckf.consensus.directions.constrained_average`). Derivation:
the concept page *Consensus*, section *Intersection*.
"""

from __future__ import annotations

from collections.abc import Mapping, MutableMapping, Sequence

import numpy as np
import scipy.linalg

from teamslam.errors import InternalError
from teamslam.gaussian import NotPositiveDefiniteError, spd_inverse
from teamslam.msckf.consensus.checks import ReceivedMarginal
from teamslam.msckf.consensus.directions import constrained_average
from teamslam.msckf.consensus.kernels import symmetric_block
from teamslam.msckf.filter.state import MsckfState

__all__ = ["INTERSECTION_KINDS", "intersection_average", "intersection_fusion"]

#: The fusion rules (``consensus.rule`` values) this module implements.
INTERSECTION_KINDS = ("ci", "ici")

# the search over ω: a grid, then golden-section steps in the grid cell around its best point
_GRID = 33
_GOLDEN_STEPS = 24
_GOLDEN = 0.5 * (np.sqrt(5.0) - 1.0)


def _log_det(kind: str, omega: np.ndarray, ratio: np.ndarray) -> np.ndarray:
    """``log det`` of the fused information in the diagonal coordinates, for each ``ω``.

    ``ratio`` holds the eigenvalues ``e_k`` of ``Ω_b`` in the coordinates where ``Ω_a = I``.
    """
    omega = np.asarray(omega, dtype=float)[..., None]
    return np.log(_fused_information(kind, omega, ratio)).sum(axis=-1)


def _fused_information(kind: str, omega, ratio: np.ndarray) -> np.ndarray:
    """The fused information's diagonal in the coordinates where ``Ω_a = I``, ``Ω_b = diag(e)``."""
    if kind == "ci":
        return omega + (1.0 - omega) * ratio
    # 1 + e − (ω + (1 − ω)/e)⁻¹, written to stay finite for tiny or huge e
    return 1.0 + ratio - ratio / (omega * ratio + 1.0 - omega)


def _best_weight(kind: str, ratio: np.ndarray) -> float:
    """The ``ω ∈ [0, 1]`` that maximises the fused information's determinant (bounded search)."""
    grid = np.linspace(0.0, 1.0, _GRID)
    values = _log_det(kind, grid, ratio)
    best = int(np.argmax(values))
    lo, hi = grid[max(best - 1, 0)], grid[min(best + 1, _GRID - 1)]
    a, b = hi - _GOLDEN * (hi - lo), lo + _GOLDEN * (hi - lo)
    fa, fb = _log_det(kind, np.array([a, b]), ratio)
    for _ in range(_GOLDEN_STEPS):
        if fa >= fb:
            hi, b, fb = b, a, fa
            a = hi - _GOLDEN * (hi - lo)
            fa = float(_log_det(kind, np.array(a), ratio))
        else:
            lo, a, fa = a, b, fb
            b = lo + _GOLDEN * (hi - lo)
            fb = float(_log_det(kind, np.array(b), ratio))
    candidates = np.array([grid[best], a, b])
    return float(candidates[int(np.argmax(_log_det(kind, candidates, ratio)))])


def intersection_fusion(
    mean_a: np.ndarray,
    info_a: np.ndarray,
    info_b: np.ndarray,
    vector_b: np.ndarray,
    kind: str = "ici",
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Fuse ``N(mean_a, info_a⁻¹)`` with the estimate of information ``info_b`` and information
    vector ``vector_b`` by covariance intersection (``ci``) or inverse covariance intersection
    (``ici``), the weight minimising the fused covariance's determinant.

    With ``Ω_a = L Lᵀ`` and ``L⁻¹ Ω_b L⁻ᵀ = V diag(e) Vᵀ``, in the coordinates
    ``z = Vᵀ Lᵀ x`` the two informations are ``I`` and ``diag(e)``, and

    * ``ci``: ``Ω' = diag(ω + (1 − ω) e)``, ``η' = ω z_a + (1 − ω) e z_b``;
    * ``ici``: with ``Γ = ω I + (1 − ω) diag(1/e)`` (the bound on the common information's
      covariance), ``Ω' = I + diag(e) − Γ⁻¹``, ``η' = z_a + e z_b − Γ⁻¹ (ω z_a + (1 − ω) z_b)``.

    Parameters
    ----------
    mean_a, info_a
        The first estimate: mean ``(n,)`` and information matrix ``(n, n)``.
    info_b, vector_b
        The second: information matrix ``(n, n)`` and information vector ``Ω_b μ_b``.
    kind
        ``ci`` or ``ici``.

    Returns
    -------
    mean, cov, info, omega
        The fused estimate (covariance and information symmetric) and the weight ``ω`` of the
        first estimate.

    Raises
    ------
    NotPositiveDefiniteError
        Either information matrix is not positive definite.
    """
    if kind not in INTERSECTION_KINDS:
        raise InternalError(f"intersection fusion must be ci or ici, not {kind!r}")
    info_a = 0.5 * (info_a + info_a.T)
    info_b = 0.5 * (info_b + info_b.T)
    try:
        lower = np.linalg.cholesky(info_a)
    except np.linalg.LinAlgError:
        raise NotPositiveDefiniteError("first information is not positive definite") from None
    # N = L⁻¹ Ω_b L⁻ᵀ
    left = scipy.linalg.solve_triangular(lower, info_b, lower=True)
    normalised = scipy.linalg.solve_triangular(lower, left.T, lower=True)
    ratio, vectors = np.linalg.eigh(0.5 * (normalised + normalised.T))
    if not ratio[0] > 0:
        raise NotPositiveDefiniteError("second information is not positive definite")
    omega = _best_weight(kind, ratio)
    z_a = vectors.T @ (lower.T @ mean_a)
    h_b = vectors.T @ scipy.linalg.solve_triangular(lower, vector_b, lower=True)  # e z_b
    fused = _fused_information(kind, omega, ratio)
    if kind == "ci":
        vector = omega * z_a + (1.0 - omega) * h_b
    else:
        gamma = omega + (1.0 - omega) / ratio
        vector = z_a + h_b - (omega * z_a + (1.0 - omega) * h_b / ratio) / gamma
    # back from z: x = L⁻ᵀ V z
    back = scipy.linalg.solve_triangular(lower, vectors, lower=True, trans="T")  # L⁻ᵀ V
    mean = back @ (vector / fused)
    cov = (back / fused) @ back.T
    forward = lower @ vectors  # L V
    info = (forward * fused) @ forward.T
    return mean, 0.5 * (cov + cov.T), 0.5 * (info + info.T), omega


def intersection_average(
    state: MsckfState,
    received: Sequence[tuple[float, ReceivedMarginal]],
    kind: str,
    counters: MutableMapping[str, int] | None = None,
    own_information: Mapping[bytes, np.ndarray] | None = None,
    rigid_directions: bool = False,
) -> int:
    """Fuse our marginal of the common objects with each neighbour's in turn and rebuild the joint.

    ``y`` is every object some neighbour sent; each neighbour's marginal of its objects
    ``C_j ⊆ y`` is completed by our own conditional of the rest (Prop. 2, eq. 42):
    ``Ω_j = Ω + Lⱼᵀ (M_j − Ω_{C_j}) Lⱼ``. The running estimate starts at ours and is fused with
    each completed marginal in the order of ``received`` (:func:`intersection_fusion`); the
    Metropolis weights play no part. With ``rigid_directions`` (a first-estimates filter) our
    own information and mean along our rigid motions at our first estimates of ``y`` are kept
    (:func:`~teamslam.msckf.consensus.directions.constrained_average`). The joint is rebuilt
    with our conditional of everything else (Prop. 2).

    Parameters
    ----------
    state
        The agent's state (edited in place).
    received
        ``(A_ij, marginal)`` per usable neighbour joint marginal (the weight is not used).
    kind
        ``ci`` or ``ici``.
    counters
        ``counters["intersection_fusions"]`` counts the fusions made,
        ``counters["intersection_fallbacks"]`` the neighbours left out because their completed
        marginal was not positive definite.
    own_information
        Our own information of object sets already inverted this step (as for
        :func:`~teamslam.msckf.consensus.average.consensus_average`).
    rigid_directions
        Keep our information along the rigid motions at our first estimates.

    Returns
    -------
    int
        Number of objects averaged.
    """
    if not received:
        return 0
    marginals = [m for _, m in received]
    if any(m.per_object for m in marginals):
        raise InternalError(f"consensus rule {kind} needs joint marginals")
    y_ids = np.unique(np.concatenate([m.ids for m in marginals]))
    slots = state.object_slots(y_ids)
    cols = state.object(slots).columns.ravel()
    own_mean = state.objects[slots].ravel()
    own_cov = symmetric_block(state.cov, cols)
    own_info = None if own_information is None else own_information.get(y_ids.tobytes())
    if own_info is None:
        own_info = spd_inverse(own_cov, "own marginal covariance", symmetric=True)
    own_vector = own_info @ own_mean
    mean, info = own_mean, own_info
    cov = own_cov
    for m in marginals:
        sub = (3 * np.searchsorted(y_ids, m.ids)[:, None] + np.arange(3)).ravel()
        if sub.size == own_mean.size:
            own_sub = own_info
        else:
            known = None if own_information is None else own_information.get(m.ids.tobytes())
            own_sub = (
                known
                if known is not None
                else spd_inverse(own_cov[np.ix_(sub, sub)], "own marginal covariance")
            )
        completed = own_info.copy()
        completed[np.ix_(sub, sub)] += m.info - own_sub
        completed_vector = own_vector.copy()
        completed_vector[sub] += m.info_vector - own_sub @ own_mean[sub]
        try:
            fused = intersection_fusion(mean, info, completed, completed_vector, kind)
        except NotPositiveDefiniteError:
            # a completed marginal that is not positive definite: this neighbour is left out
            if counters is not None:
                counters["intersection_fallbacks"] += 1
            continue
        mean, cov, info, _ = fused
        if counters is not None:
            counters["intersection_fusions"] += 1
    if rigid_directions:
        mean, cov = constrained_average(own_mean, own_info, mean, cov, state.object_fe[slots])
    state.replace_marginal(cols, mean, cov, info=own_info)
    return int(y_ids.size)
