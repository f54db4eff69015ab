"""Consensus, selection: which common objects a robot averages jointly (``consensus.set``).

With ``consensus.set = active`` a robot flags at ``consensus.kl_threshold`` only its *active*
objects — observed within the window, or with mutual information above
``consensus.active_information`` nats with the window poses — and the others only when they
moved by more than ``consensus.inactive_kl_threshold``; an object the pair averaged in the
previous exchange is tested at ``consensus.kl_threshold`` (an average once started settles).
Lock-step exchanges only. Derivation, and what is lost against the full joint average: the
concept page *The bounded consensus set* (``docs/concepts/consensus-set.md``).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import LinAlgError, cho_factor, solve_triangular

from teamslam.msckf.filter.state import MsckfState

__all__ = ["active_objects", "pose_mutual_information", "settling_thresholds"]


def pose_mutual_information(
    state: MsckfState, object_covs: np.ndarray, slots: np.ndarray | None = None
) -> np.ndarray:
    """``I(o; x)`` (nats) between objects of the state and its window poses.

    ``object_covs`` are the objects' own ``3×3`` marginals, of the objects at ``slots`` (default:
    every object, in slot order). An object whose conditional covariance is not positive
    definite (it is fully determined by the poses, up to rounding) gets ``inf``; if the pose
    block itself cannot be factorised every object does.
    """
    slots = np.arange(state.n_objects) if slots is None else np.asarray(slots, dtype=np.int64)
    m = slots.size
    if m == 0:
        return np.zeros(0)
    p = 6 * state.n_poses
    cov = state.cov
    try:
        factor, _ = cho_factor(cov[:p, :p], lower=True, check_finite=False)
    except LinAlgError:
        return np.full(m, np.inf)
    # K = L⁻¹ Σ_xo: Σ_oo|x = Σ_oo − KᵀK, block by block
    columns = (p + 3 * slots[:, None] + np.arange(3)).ravel()
    k = solve_triangular(factor, cov[:p, columns], lower=True, check_finite=False)
    k = k.reshape(p, m, 3)
    explained = np.einsum("pmi,pmj->mij", k, k)
    sign_all, logdet_all = np.linalg.slogdet(object_covs)
    sign_cond, logdet_cond = np.linalg.slogdet(object_covs - explained)
    out = 0.5 * (logdet_all - logdet_cond)
    out[(sign_all <= 0) | (sign_cond <= 0) | ~np.isfinite(out)] = np.inf
    return out


def active_objects(state: MsckfState, object_covs: np.ndarray, information: float) -> np.ndarray:
    """Which objects of the state the current window can still change appreciably, ``(m,)``.

    Observed within the window, or with mutual information above ``information`` nats with the
    window poses (:func:`pose_mutual_information`; concept page *The bounded consensus set*).
    State slot order.
    """
    if state.n_objects == 0:
        return np.zeros(0, dtype=bool)
    active = state.object_last_seen >= int(state.frames.min())
    if active.all() or information == np.inf:
        return active
    unseen = np.flatnonzero(~active)
    active[unseen] = pose_mutual_information(state, object_covs[unseen], unseen) > information
    return active


def settling_thresholds(
    thresholds: np.ndarray, exchanged_at: np.ndarray, exchange: int, kl_threshold: float
) -> np.ndarray:
    """How far each object on record with one neighbour must have moved to be averaged again.

    ``thresholds`` are the objects' own (``consensus.kl_threshold`` when active, the inactive
    threshold otherwise); ``exchanged_at`` the number of the exchange in which the pair last
    averaged each. An object the pair averaged in the previous exchange is tested against
    ``kl_threshold`` whatever its own threshold: an average, once started, runs until the pair
    agrees to within the paper's threshold (concept page *The bounded consensus set*, settling).
    """
    settling = np.asarray(exchanged_at) == int(exchange) - 1
    return np.where(settling, np.minimum(thresholds, kl_threshold), thresholds)
