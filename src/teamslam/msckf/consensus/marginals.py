"""Consensus, building messages: our marginal of the objects a neighbour asked about.

:func:`common_marginal_message` takes our marginal of the common objects — in information form
by default — and rounds it to single precision where that stays within :data:`FLOAT32_MAX_KL`
nats of the exact one (the bounds below; derivation on the concept page *Consensus*).
"""

from __future__ import annotations

from collections.abc import MutableMapping

import numpy as np
from scipy.linalg import lapack, solve_triangular

from teamslam.errors import InternalError
from teamslam.gaussian import spd_inverse
from teamslam.msckf.consensus.average import SharedPrior, prior_marginal
from teamslam.msckf.consensus.directions import reexpressed_information
from teamslam.msckf.consensus.kernels import rounding_bound, single_rounding, symmetric_block
from teamslam.msckf.consensus.messages import CommonMarginalMessage
from teamslam.msckf.filter.state import MsckfState

__all__ = [
    "FLOAT32_MAX_KL",
    "common_marginal_message",
    "information_rounding_bound",
    "object_marginals",
    "rounding_divergence",
    "rounding_divergence_bound",
]


def object_marginals(state: MsckfState) -> tuple[np.ndarray, np.ndarray]:
    """Each map object's own marginal: ``(m, 3)`` means and ``(m, 3, 3)`` covariance blocks."""
    return state.objects.copy(), state.object_covs()


def _single(values: np.ndarray) -> np.ndarray:
    """``values`` rounded to single precision (what a float32 wire carries), as doubles."""
    return values.astype(np.float32).astype(float)


def common_marginal_message(
    state: MsckfState,
    sender: int,
    receiver: int,
    step: int,
    ids: np.ndarray,
    degree: int = 0,
    per_object: bool = False,
    float32: bool = False,
    source: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    information: bool = False,
    keep: MutableMapping[bytes, np.ndarray] | None = None,
    prior: SharedPrior | None = None,
    directions: bool = False,
) -> CommonMarginalMessage | None:
    """The marginal of the objects ``ids`` (those the sender holds), or ``None`` if none.

    ``source`` — ``(ids, mean, cov)`` of a joint marginal over a superset of ``ids`` (ids
    increasing) — replaces the state's marginal, e.g. the hybrid marginal of
    :func:`hybrid_marginal`.

    ``per_object`` sends each object's own 3×3 covariance instead of the joint one; ``float32``
    rounds every number to single precision (what the wire then carries exactly) where that is
    safe: when the rounded marginal is within :data:`FLOAT32_MAX_KL` nats of the exact one
    (:func:`rounding_divergence` per object, :func:`rounding_divergence_bound` for a joint
    marginal, :func:`information_rounding_bound` in information form); otherwise the message
    stays in double precision.

    ``information`` sends a joint marginal in information form (``info = Σ⁻¹``); ``keep``, a
    mapping, then receives the exact (unrounded) ``Σ⁻¹`` under the key ``ids.tobytes()`` of
    the message's ids (``int64``), for :func:`consensus_average`'s ``own_information``.

    ``directions`` (information form): the marginal and prior sent have their rigid-motion
    directions moved from our first estimates of the objects to their means
    (:func:`~teamslam.msckf.consensus.directions.reexpressed_information`); ``keep`` still
    receives our own ``Σ⁻¹``.
    """
    ids = np.unique(np.asarray(ids, dtype=np.int64))  # increasing, as messages carry them
    slots = state.object_slots(ids)
    held = slots >= 0
    if not held.any():
        return None
    if source is None:
        cols = state.object(slots[held]).columns
        mean = state.objects[slots[held]].ravel().copy()
        if information and not per_object:  # the symmetric part, which is what is inverted
            cov = symmetric_block(state.cov, cols.ravel())
        else:
            cov = state.covariance(cols if per_object else cols.ravel())
    else:
        source_ids, source_mean, full_cov = source
        pos = np.minimum(np.searchsorted(source_ids, ids[held]), source_ids.size - 1)
        if source_ids.size == 0 or np.any(source_ids[pos] != ids[held]):
            raise InternalError("the source marginal does not hold every object asked for")
        cols = 3 * pos[:, None] + np.arange(3)
        mean = source_mean[cols.ravel()].copy()
        if per_object:
            cov = full_cov[cols[:, :, None], cols[:, None, :]]
        else:
            flat = cols.ravel()
            cov = full_cov[np.ix_(flat, flat)]
    if information and not per_object:
        info = spd_inverse(cov, "own marginal covariance", symmetric=source is None)
        if keep is not None:
            keep[ids[held].tobytes()] = info
        message_info, message_cov = info, cov
        first = state.object_fe[slots[held]]
        if directions:
            message_info, message_cov = reexpressed_information(info, first, mean, cov)
        if float32:
            mean, message_info = _rounded_information(mean, message_cov, message_info)
        prior_part = {}
        if prior is not None:
            prior_held, prior_mean, prior_info, prior_cov = prior_marginal(prior, ids[held])
            if directions and prior_held.any():
                prior_info, prior_cov = reexpressed_information(
                    prior_info, first[prior_held], prior_mean, prior_cov
                )
            if float32 and prior_held.any():
                prior_mean, prior_info = _rounded_information(prior_mean, prior_cov, prior_info)
            prior_part = {
                "prior_held": prior_held,
                "prior_mean": prior_mean,
                "prior_info": prior_info,
            }
        return CommonMarginalMessage(
            sender,
            receiver,
            step,
            ids[held].copy(),
            mean,
            None,
            int(degree),
            info=message_info,
            **prior_part,
        )
    if float32:
        mean32, cov32 = _single(mean), _single(cov)
        divergence = rounding_divergence if per_object else rounding_divergence_bound
        if divergence(mean, cov, mean32, cov32) <= FLOAT32_MAX_KL:
            mean, cov = mean32, cov32
    return CommonMarginalMessage(
        sender, receiver, step, ids[held].copy(), mean, cov.copy(), int(degree)
    )


def _rounded_information(
    mean: np.ndarray, cov: np.ndarray, info: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``(mean, info)`` rounded to single precision when that is within
    :data:`FLOAT32_MAX_KL` (:func:`information_rounding_bound`), else as they are."""
    mean32, info32, bound = single_rounding(
        np.ascontiguousarray(mean, dtype=float),
        np.ascontiguousarray(cov, dtype=float),
        np.ascontiguousarray(info, dtype=float),
    )
    if bound <= FLOAT32_MAX_KL:
        return mean32, info32
    return mean, info


FLOAT32_MAX_KL = 1e-4
"""Largest Kullback–Leibler divergence (nats) of a marginal rounded to single precision from
the exact one for which a ``float32`` message is sent — a thousandth of a typical
``consensus.kl_threshold``, so rounding never changes what consensus sees."""


def rounding_divergence_bound(
    mean: np.ndarray, cov: np.ndarray, mean_rounded: np.ndarray, cov_rounded: np.ndarray
) -> float:
    """An upper estimate of :func:`rounding_divergence` for one ``(d, d)`` covariance, in
    ``d³/3`` flops (one Cholesky factorisation) instead of ``7d³/3``.

    With ``‖E‖_F ≤ ‖Σ⁻¹‖₂ ‖ΔΣ‖_F``, ``‖e‖² ≤ ‖Σ⁻¹‖₂ ‖Δμ‖²`` and ``‖Σ⁻¹‖₂ ≤ ‖Σ⁻¹‖₁``, where
    ``‖Σ⁻¹‖₁`` is LAPACK's condition estimate (``dpocon``, O(d²) after the factorisation;
    an estimate that is rarely off by more than a small factor). ``inf`` when ``cov`` is not
    positive definite.
    """
    cov = np.asarray(cov, dtype=float)
    chol, info = lapack.dpotrf(cov, lower=1)
    if info != 0:
        return float("inf")
    norm_1 = float(np.abs(cov).sum(axis=0).max())
    rcond, info = lapack.dpocon(chol, norm_1, uplo="L")
    if info != 0 or not rcond > 0:
        return float("inf")
    inverse_norm = 1.0 / (rcond * norm_1)
    d_cov = float(np.sum((cov_rounded - cov) ** 2))
    d_mean = float(np.sum((mean_rounded - mean) ** 2))
    return 0.25 * inverse_norm**2 * d_cov + 0.5 * inverse_norm * d_mean


def information_rounding_bound(
    mean: np.ndarray,
    cov: np.ndarray,
    info: np.ndarray,
    mean_rounded: np.ndarray,
    info_rounded: np.ndarray,
) -> float:
    """An upper estimate of ``KL(N(mean_rounded, info_rounded⁻¹) ‖ N(mean, cov))`` for a
    marginal sent in information form (``info = cov⁻¹``), in ``O(d²)``: no factorisation.

    To second order the divergence is ``¼‖E‖²_F + ½ Δμᵀ Ω Δμ`` with ``E = Σ^½ ΔΩ Σ^½``
    (``ΔΩ`` the rounding of the information matrix, ``Δμ`` of the mean). With ``D`` the
    standard deviations (``Σ = D C D``, ``C`` the correlations) ``‖E‖²_F = tr(C F C F)`` with
    ``F = D ΔΩ D``, so ``‖E‖_F ≤ ‖C‖₂ ‖F‖_F``, and ``Δμᵀ Ω Δμ ≤ ‖D Ω D‖₂ ‖D⁻¹ Δμ‖²``; for a
    symmetric matrix ``‖·‖₂ ≤ ‖·‖₁`` (the largest column sum of absolute values). Scaling by
    ``D`` first keeps the estimate independent of units and of how differently the objects
    are known. One compiled pass (:func:`~teamslam.msckf.consensus.kernels.rounding_bound`).
    """
    as_array = np.ascontiguousarray
    return float(
        rounding_bound(
            *(as_array(a, dtype=float) for a in (mean, cov, info, mean_rounded, info_rounded))
        )
    )


def rounding_divergence(
    mean: np.ndarray, cov: np.ndarray, mean_rounded: np.ndarray, cov_rounded: np.ndarray
) -> float:
    """``KL(N(mean_rounded, cov_rounded) ‖ N(mean, cov))`` to second order, in nats.

    With ``cov = L Lᵀ``, ``E = L⁻¹ (cov_rounded − cov) L⁻ᵀ`` and ``e = L⁻¹ (mean_rounded −
    mean)``, the divergence is ``¼‖E‖²_F + ½‖e‖²`` up to third-order terms. ``cov`` is one
    ``(d, d)`` matrix, or ``(k, 3, 3)`` blocks of independent parts (their divergences add).
    ``inf`` when ``cov`` is not positive definite.
    """
    try:
        chol = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        return float("inf")
    if np.ndim(cov) == 3:
        e = np.linalg.solve(chol, (mean_rounded - mean).reshape(-1, 3, 1))
        half = np.linalg.solve(chol, cov_rounded - cov)
        whitened = np.linalg.solve(chol, np.swapaxes(half, -1, -2))
    else:
        e = solve_triangular(chol, mean_rounded - mean, lower=True)
        half = solve_triangular(chol, cov_rounded - cov, lower=True)
        whitened = solve_triangular(chol, half.T, lower=True)
    return float(0.25 * np.sum(whitened**2) + 0.5 * np.sum(e**2))
