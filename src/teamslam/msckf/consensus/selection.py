"""Consensus, selection: which common objects a robot averages jointly (``consensus.set``).

The paper averages every common object at every step (eq. 19 over ``y``, Prop. 2 rebuild), so
each step inverts the joint marginal of all of them: the cost is cubic in the map the robots
share and keeps growing on a route that revisits a fixed area, long after the map stopped
growing. With ``consensus.set = active`` a robot flags for the joint average only the objects
its current window can still change appreciably — the *active* objects:

* observed within the window (``object_last_seen`` at or after the oldest window frame) — by
  default the only test, or also
* correlated with the window poses: the mutual information between the object and the window
  poses, ``I(o; x) = ½ log det Σ_oo − ½ log det Σ_oo|x`` (nats, unit-free: the same for any
  camera, unit or noise level), above ``consensus.active_information`` (default ``inf``: not
  used). ``Σ_oo|x = Σ_oo − Σ_oxΣ_xx⁻¹Σ_xo`` costs one Cholesky factorisation of the pose block
  and one triangular solve with the pose–object cross-covariance, ``O(p² m)`` for ``p`` pose
  coordinates and ``m`` objects — linear in the map.

Why the correlation test is off by default: on a route that keeps revisiting one area every
mapped object stays correlated with the current poses (the poses were estimated from those
objects), so the test keeps most of the map active and the joint grows with the map. Measured
on the ``make run`` team over 300 frames (``benchmarks/msckf_long.py revisit``): with 0.3 nats
the consensus CPU time at the end was 0.76× the paper's set, with the window test alone 0.30×,
at the same trajectory RMSE and object error; on KITTI 00 the per-step mutual information over
a large map cost more than the smaller joint saved (1.22× the paper's consensus time, against
0.53× without it).

The other common objects (*inactive*) keep their agreement by the cheaper rule of averaging only
when they change: the protocol's moved flags (:mod:`teamslam.msckf.consensus.protocol`) flag an
active
object when its marginal moved by more than ``consensus.kl_threshold`` since the pair last
exchanged it, and an inactive one only when it moved by more than
``consensus.inactive_kl_threshold``. Both ends of a link average the objects flagged by either,
so an object one robot observes now is averaged jointly with every neighbour that shares it —
the joint a robot averages is what the team sees now, not what it has mapped.

**What is lost against the full joint average.** Write ``y = J ∪ I`` (averaged jointly this
step, left out) and ``x`` the window poses and all other objects. The full average replaces the
marginal of ``y`` by ``p̄(y)`` and keeps our conditional ``p(x | y)``; the bounded set replaces
the marginal of ``J`` by ``p̄(J)`` and keeps ``p(x, I | J)``. Both are eq. 42 + Prop. 2, on
different sets, so each result is a proper Gaussian and each neighbour's information enters
with its Metropolis weight. The difference is confined to what neighbours know about ``I``
beyond what our own conditional ``p(I | J)`` predicts from the averaged ``J``:

* ``I``'s own marginal follows ``p̄(J)`` through our conditional instead of being averaged, so
  a neighbour's information on ``I`` arrives only when ``I`` moves by more than the inactive
  threshold (then it is in ``J`` again), or when ``I`` becomes active (observed by either robot
  of the pair). Each such average runs until the pair agrees to within
  ``consensus.kl_threshold`` (*settling*, below); between two of them the pair's marginals of
  an inactive object drift apart by at most about the threshold on each side plus what the two
  conditionals add — that drift is bounded by the threshold, not driven to
  ``consensus.kl_threshold``;
* the window poses are corrected through ``J`` only (``A = Σ_xJ Σ_J⁻¹`` instead of
  ``Σ_xy Σ_y⁻¹``). With the correlation test at ``ε`` nats an inactive object is weakly
  correlated with them: ``I(o; x) = −½ Σ_k log(1 − ρ_k²) ≤ ε`` over its canonical
  correlations ``ρ_k`` with the poses, so the poses explain at most a fraction
  ``ρ_k² ≤ 1 − e^{−2ε}`` (``≈ 2ε`` for small ``ε``) of its variance in any direction, and its
  correction of the poses is weaker by that much, not absent. Without it (the default) no such
  bound holds: an object seen a few frames before the window may still be strongly correlated
  with the poses, and what a neighbour knows about it beyond our conditional reaches our poses
  only once it moves past the inactive threshold or is seen again. That is the price of the
  bound; the benchmark above measures it (over 1,000 frames, with the settling rule below:
  trajectory RMSE 1.000×, object error 1.002×, disagreement 2.01× the paper's set — the pairs'
  disagreement is flat in the frames since they last averaged an object, and as large on the
  objects they averaged in the last two frames, so it is not left-out objects drifting apart;
  most likely it is this price on the poses).

**Settling: an average once started runs to agreement.** The moved flags compare a robot's
marginal with its own marginal at the pair's last exchange, so a residual disagreement shows
up as movement only while the pair keeps averaging. Averages are often partial: an object one
robot flags is averaged on that robot's links only, and each neighbour moves only ``A_ij`` of
the way towards it. The paper's set then keeps averaging (the neighbour moved by more than
``consensus.kl_threshold``, so it flags the object on all its links); with the inactive
threshold alone an inactive object whose first average moved it by less than that threshold
kept the residual of the partial average for good. Over 300 frames of the ``make run`` team
the objects averaged 10–200 frames before the end were where the rule below took the pairs'
disagreement down (mean pair distance 2.9 / 2.0 / 2.1 mm for 10–50 / 50–100 / 100–200 frames
without it, 1.9 / 1.2 / 1.8 mm with it); over 1,000 frames it took the benchmark's
disagreement from 2.16× to 2.01× the paper's set. So an object a pair averaged in the
previous exchange is tested at ``consensus.kl_threshold``, whatever its own threshold
(:func:`settling_thresholds`): the inactive threshold only decides when drift starts a new
average, and each average started runs until the pair agrees to within the paper's
threshold. Its cost is the few exchanges a pair's average takes to settle (it contracts
geometrically), not the map. (Of the disagreement the benchmark reports at the end of a run,
most can come from objects a robot initialised at the very last frame, which no consensus set
has averaged yet: over 300 frames 28 of 2,614 robot-pair estimates of an object, never
exchanged, carried 82% of it in a run of the bounded set, and the paper's set's run had such
an object too.)

Left out of a step's average, an object keeps its *conditional* given the averaged objects
exactly, not its marginal: keeping the marginals of the left-out objects as well would mean
rebuilding the joint without Prop. 2 on them, and then the averaged objects' correction no
longer reaches the objects correlated with them — tried with the poses rebuilt by Prop. 2 and
the left-out objects' rows kept (``O(n (p + k)²)`` instead of ``O(n² k)``), it gave 5.6% more
RMSE and 6.2% more object error than the paper's set on the ``make run`` team at 200 frames and
was not faster (consensus CPU 7.0 against 6.0 ms over the last frames, separate runs), since the
averaged set was large. When every common object is active (or both thresholds equal) the
bounded set is exactly the paper's average (tested), and an object that is not flagged by
either robot of any pair keeps the marginal our own conditional gives it — it is never
averaged with stale information. Only lock-step exchanges use it (asynchronous exchanges
average every common object).
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
    window poses (:func:`pose_mutual_information`; module docstring). State slot order.
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
    agrees to within the paper's threshold (module docstring, *settling*).
    """
    settling = np.asarray(exchanged_at) == int(exchange) - 1
    return np.where(settling, np.minimum(thresholds, kl_threshold), thresholds)
