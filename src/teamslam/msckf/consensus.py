"""Consensus averaging of the common objects (distributed MSCKF paper, §V-B, eqs. 19–21).

Two rounds per step, each through the :class:`~teamslam.runtime.transport.Transport`:

1. every agent sends each active neighbour the ids of its map objects;
2. every agent sends each neighbour the marginal (mean and covariance) of just the objects the
   two share.

Agent ``i`` then forms one weighted geometric average (eq. 19) over ``y``, the objects it shares
with at least one neighbour it heard: neighbour ``j``'s message covers the objects ``C_ij ⊆ y``;
for the rest of ``y`` agent ``i`` completes it with its own conditional ``p_i(y∖C_ij | C_ij)``
(Prop. 2), so every term is a Gaussian over the same ``y`` and the average is one
information-form sum with the weights ``A_ii, A_ij`` — not a sequence of pairwise averages. The
joint is rebuilt with Prop. 2 and the window poses corrected with ``exp`` (eq. 21).

A message with unknown ids, wrong sizes, or a covariance that is not symmetric positive definite
is rejected and counted; the estimate is unaffected.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from teamslam.gaussian import spd_inverse
from teamslam.msckf.state import MsckfState
from teamslam.runtime.transport import CommonMarginalMessage, MapIdsMessage

__all__ = ["common_marginal_message", "consensus_average", "validate_marginal"]


def common_marginal_message(
    state: MsckfState, sender: int, receiver: int, step: int, ids: np.ndarray
) -> CommonMarginalMessage | None:
    """The marginal of the objects ``ids`` (those the sender holds), or ``None`` if none."""
    ids = np.asarray(ids, dtype=np.int64)
    slots = state.object_slots(ids)
    held = slots >= 0
    if not held.any():
        return None
    cols = state.object_columns(slots[held]).ravel()
    return CommonMarginalMessage(
        sender,
        receiver,
        step,
        ids[held].copy(),
        state.objects[slots[held]].ravel().copy(),
        state.cov[np.ix_(cols, cols)].copy(),
    )


def validate_marginal(state: MsckfState, message: CommonMarginalMessage) -> str | None:
    """Why a received marginal cannot be used (``None`` when it can)."""
    ids = np.asarray(message.ids)
    k = ids.size
    if ids.ndim != 1 or k == 0 or np.unique(ids).size != k:
        return "ids must be a non-empty list without repeats"
    if np.shape(message.mean) != (3 * k,) or np.shape(message.cov) != (3 * k, 3 * k):
        return "mean/covariance sizes do not match the ids"
    if not (np.all(np.isfinite(message.mean)) and np.all(np.isfinite(message.cov))):
        return "non-finite mean or covariance"
    if np.any(state.object_slots(ids) < 0):
        return "ids not in this robot's map"
    cov = message.cov
    if not np.allclose(cov, cov.T, rtol=1e-9, atol=1e-12):
        return "covariance is not symmetric"
    try:
        np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        return "covariance is not positive definite"
    return None


def _marginal_information(info: np.ndarray, cov: np.ndarray, sub: np.ndarray) -> np.ndarray:
    """Information matrix of the ``sub`` block's marginal, the cheaper way round.

    Either invert ``cov[sub, sub]`` (``|sub|³``) or take the Schur complement of the rest in the
    joint information, ``Ω_CC − Ω_CR Ω_RR⁻¹ Ω_RC`` (``|rest|³``) — a neighbour usually shares
    most of the common objects, so the rest is small.
    """
    rest = np.setdiff1d(np.arange(info.shape[0]), sub)
    if rest.size == 0:
        return info[np.ix_(sub, sub)]
    if rest.size >= sub.size:
        return spd_inverse(cov[np.ix_(sub, sub)], "own common-object covariance")
    factor = scipy.linalg.cho_factor(info[np.ix_(rest, rest)])
    cross = info[np.ix_(rest, sub)]
    return info[np.ix_(sub, sub)] - cross.T @ scipy.linalg.cho_solve(factor, cross)


def consensus_average(
    state: MsckfState,
    self_weight: float,
    received: list[tuple[float, CommonMarginalMessage]],
) -> int:
    """Average the common objects with the neighbours' marginals and rebuild the joint.

    Parameters
    ----------
    state
        The agent's state (edited in place).
    self_weight
        ``A_ii``.
    received
        ``(A_ij, message)`` for every valid neighbour marginal.

    Returns
    -------
    int
        Number of objects averaged.
    """
    if not received:
        return 0
    y_ids = np.unique(np.concatenate([m.ids for _, m in received]))
    slots = state.object_slots(y_ids)
    cols = state.object_columns(slots).ravel()
    own_mean = state.objects[slots].ravel()
    own_cov = state.cov[np.ix_(cols, cols)]
    position = {int(i): k for k, i in enumerate(y_ids)}
    # In information form the completed neighbour term q_i(y∖C | C) q_j(C) differs from our
    # own marginal only on C: Ω̃_j = Ω_i + Lᵀ(M_j − M_i,C)L, η̃_j = η_i + Lᵀ(M_j μ_j − M_i,C μ_i,C)
    # (App. B, eq. 42). With Σ w = 1 the average is Ω_i + Σ_j w_j Lᵀ(M_j − M_i,C)L.
    total = self_weight + sum(w for w, _ in received)
    own_info = spd_inverse(own_cov, "own common-object covariance")
    info = own_info.copy()
    info_vector = own_info @ own_mean
    for weight, msg in received:
        w = weight / total
        sub = (3 * np.array([position[int(i)] for i in msg.ids])[:, None] + np.arange(3)).ravel()
        own_sub_info = _marginal_information(own_info, own_cov, sub)
        msg_info = spd_inverse(msg.cov, "received covariance")
        info[np.ix_(sub, sub)] += w * (msg_info - own_sub_info)
        info_vector[sub] += w * (msg_info @ msg.mean - own_sub_info @ own_mean[sub])
    cov = spd_inverse(info, "averaged common-object information")
    mean = cov @ info_vector
    state.replace_marginal(cols, mean, cov)
    return int(y_ids.size)


def map_ids_message(state: MsckfState, sender: int, receiver: int, step: int) -> MapIdsMessage:
    """Round 1: the ids of every object in the map."""
    return MapIdsMessage(sender, receiver, step, state.object_ids.copy())
