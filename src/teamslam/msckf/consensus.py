"""Consensus averaging of the common objects on one robot's state (distributed MSCKF, eqs. 19–21).

The protocol around it — who sends what, which messages are accepted, the weights — is
:mod:`teamslam.msckf.protocol`. This module holds what it does to the state:

* :func:`common_marginal_message` — our marginal of the objects a neighbour asked about, in
  information form by default (we invert it anyway for our own average; the neighbour then
  only checks it);
* :func:`receive_marginal` — a neighbour's marginal checked against our map and factorised once
  (its information matrix is what the average uses);
* :func:`consensus_average` — agent ``i`` forms one weighted geometric average (eq. 19) over
  ``y``, the objects it shares with at least one neighbour it heard: neighbour ``j``'s message
  covers ``C_ij ⊆ y`` and is completed with ``i``'s own conditional ``p_i(y∖C_ij | C_ij)``
  (Prop. 2) — :func:`teamslam.gaussian.completed_geometric_average` — then the joint is rebuilt
  with Prop. 2 and the window poses corrected with ``exp`` (eq. 21) by
  :meth:`~teamslam.msckf.state.MsckfState.replace_marginal`;
* :func:`shared_prior` and :func:`hybrid_marginal` — the optional hybrid weighting
  (``consensus_hybrid``), below.

**Hybrid consensus: new information at full weight.** Eq. 19 averages whole marginals, so
information that robot ``j`` gathered since the last exchange enters robot ``i``'s estimate with
the weight ``A_ij``: on a complete graph of ``N`` robots one average keeps ``1/N`` of the team's
new information, and the filter ends up markedly conservative (pose ANEES ≈ 0.7, object ANEES ≈
0.25 where the centralised filter gives 1). After Battistelli, Chisci, Mugnai, Farina and
Graziano's hybrid consensus on measurements and on information (HCMCI, IEEE TAC 2015), each
marginal is split into the prior ``P`` — the robot's marginal right after its last exchange — and
the new information ``Δ = Ω − P`` gathered since (``Ω`` its marginal information now; objects
initialised since have ``P = 0``), and the new part is scaled by a gain ``γ``:

    ``Ω' = P + γ Δ = Ω + (γ − 1)(Ω − P)``,  ``η' = η + (γ − 1)(η − η_P)``.

The average of these is eq. 19 on the priors plus ``γ`` times eq. 19 on the new information. The
gains are the largest that never count one robot's new information more than once in any estimate.
A sender scales what it sends by ``γ = 1 + d_i`` (``d_i`` the neighbours it heard this step), which
a receiver weighs with ``A_ji = 1/(1 + max(d_i, d_j)) ≤ 1/(1 + d_i)``. In its own average (eq. 42)
a robot's own marginal already enters with its own weight and, on the objects a neighbour's message
lacks, with that neighbour's weight (the completion by its own conditional); so it adds its new
information ``Ω − P`` (and ``η − η_P``) once more with the total weight of the messages that hold
every averaged object, which brings that weight to one where every message holds the object and
never above one elsewhere. On a complete graph with every link up (``A_ij = 1/N``) this sums the
new information of all robots — for the common objects, one exchange then equals centralised fusion
of everyone's new information; on a sparse graph with partial maps no robot ever holds more
information than the centralised filter (both tested on a linear model; scaling the own marginal
before the average, even with the largest gain that counts it once per object, fails the second
test). The new information is a difference of two marginals; when it is not positive semi-definite
enough for the result to stay positive definite (after relinearisation, or an object re-entering
from the persistent map) the plain marginal is used (``hybrid_fallbacks``).

A message with unknown ids, wrong sizes, or a covariance that is not symmetric positive definite
is rejected; the estimate is unaffected.
"""

from __future__ import annotations

from collections.abc import Mapping, MutableMapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import lapack, solve_triangular

from teamslam.errors import InputError, InternalError
from teamslam.gaussian import NotPositiveDefiniteError, completed_geometric_average, spd_inverse
from teamslam.msckf.messages import CommonMarginalMessage
from teamslam.msckf.state import MsckfState

__all__ = [
    "FLOAT32_MAX_KL",
    "ReceivedMarginal",
    "SharedPrior",
    "common_marginal_message",
    "consensus_average",
    "hybrid_marginal",
    "information_rounding_bound",
    "object_marginals",
    "prior_information",
    "receive_marginal",
    "rounding_divergence",
    "rounding_divergence_bound",
    "shared_prior",
    "validate_marginal",
]


def object_marginals(state: MsckfState) -> tuple[np.ndarray, np.ndarray]:
    """Each map object's own marginal: ``(m, 3)`` means and ``(m, 3, 3)`` covariance blocks."""
    return state.objects.copy(), state.object_covs()


@dataclass(frozen=True)
class SharedPrior:
    """A robot's joint marginal of its objects right after its last exchange (hybrid prior ``P``).

    Attributes
    ----------
    ids
        Its objects, increasing.
    mean, cov
        Their joint marginal, ``(3m,)`` and ``(3m, 3m)``, in the order of ``ids``.
    """

    ids: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    # the last marginal asked of :func:`prior_information` (both rounds of a step usually ask
    # for the same objects): ids bytes → (P, η_P)
    _last: dict = field(default_factory=dict, repr=False, compare=False)


def shared_prior(state: MsckfState) -> SharedPrior:
    """The robot's joint marginal of every object in its state, as the next hybrid prior."""
    order = np.argsort(state.object_ids)
    cols = state.object_columns(order).ravel()
    return SharedPrior(
        state.object_ids[order].copy(),
        state.objects[order].ravel().copy(),
        state.cov[np.ix_(cols, cols)].copy(),
    )


def prior_information(prior: SharedPrior, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Information ``P`` and vector ``η_P`` of the prior's marginal of ``ids`` (increasing).

    Objects the prior does not hold (initialised since) get zero information: all they carry
    is new. The result of the last call is kept on ``prior`` and returned again for the same
    ids; callers must not modify it.
    """
    ids = np.asarray(ids, dtype=np.int64)
    key = ids.tobytes()
    if key not in prior._last:
        prior._last.clear()
        prior._last[key] = _prior_information(prior, ids)
    return prior._last[key]


def _prior_information(prior: SharedPrior, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`prior_information`, computed."""
    k = ids.size
    info = np.zeros((3 * k, 3 * k))
    eta = np.zeros(3 * k)
    if prior.ids.size == 0 or k == 0:
        return info, eta
    pos = np.minimum(np.searchsorted(prior.ids, ids), prior.ids.size - 1)
    present = prior.ids[pos] == ids
    if not present.any():
        return info, eta
    source = (3 * pos[present][:, None] + np.arange(3)).ravel()
    target = (3 * np.flatnonzero(present)[:, None] + np.arange(3)).ravel()
    held = spd_inverse(prior.cov[np.ix_(source, source)], "hybrid prior marginal")
    info[np.ix_(target, target)] = held
    eta[target] = held @ prior.mean[source]
    return info, eta


def hybrid_marginal(
    mean: np.ndarray,
    info: np.ndarray,
    prior_info: np.ndarray,
    prior_eta: np.ndarray,
    gain: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """``N(μ', Σ')`` with the new information since the prior scaled by ``gain`` (≥ 1).

    ``Ω' = Ω + (γ − 1)(Ω − P)`` and ``η' = η + (γ − 1)(η − η_P)`` (module docstring). Returns
    ``(μ', Σ', Ω')``, or ``None`` when ``Ω'`` is not positive definite (the new information
    ``Ω − P`` is then too far from positive semi-definite to be scaled).
    """
    if not gain >= 1:
        raise InternalError(f"the hybrid gain must be at least 1, not {gain}")
    extra = gain - 1.0
    eta = info @ mean
    info_h = info + extra * (info - prior_info)
    try:
        cov_h = spd_inverse(info_h, "hybrid information")
    except NotPositiveDefiniteError:
        return None
    return cov_h @ (eta + extra * (eta - prior_eta)), cov_h, info_h


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
    """
    ids = np.unique(np.asarray(ids, dtype=np.int64))  # increasing, as messages carry them
    slots = state.object_slots(ids)
    held = slots >= 0
    if not held.any():
        return None
    if source is None:
        cols = state.object_columns(slots[held])
        full_cov = state.cov
        mean = state.objects[slots[held]].ravel().copy()
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
        info = spd_inverse(cov, "own marginal covariance")
        if keep is not None:
            keep[ids[held].tobytes()] = info
        message_info = info
        if float32:
            mean32 = mean.astype(np.float32).astype(float)
            info32 = info.astype(np.float32).astype(float)
            if information_rounding_bound(mean, cov, info, mean32, info32) <= FLOAT32_MAX_KL:
                mean, message_info = mean32, info32
        return CommonMarginalMessage(
            sender, receiver, step, ids[held].copy(), mean, None, int(degree), info=message_info
        )
    if float32:
        mean32 = mean.astype(np.float32).astype(float)
        cov32 = cov.astype(np.float32).astype(float)
        divergence = rounding_divergence if per_object else rounding_divergence_bound
        if divergence(mean, cov, mean32, cov32) <= FLOAT32_MAX_KL:
            mean, cov = mean32, cov32
    return CommonMarginalMessage(
        sender, receiver, step, ids[held].copy(), mean, cov.copy(), int(degree)
    )


FLOAT32_MAX_KL = 1e-4
"""Largest Kullback–Leibler divergence (nats) of a marginal rounded to single precision from
the exact one for which a ``float32`` message is sent — a thousandth of a typical
``consensus_kl_threshold``, so rounding never changes what consensus sees."""


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
    are known.
    """
    std = np.sqrt(np.diagonal(cov))
    scale = np.outer(std, std)
    correlation_norm = float((np.abs(cov) / scale).sum(axis=0).max())
    scaled_info_norm = float((np.abs(info) * scale).sum(axis=0).max())
    d_info = float(np.sum(((info_rounded - info) * scale) ** 2))
    d_mean = float(np.sum(((mean_rounded - mean) / std) ** 2))
    return 0.25 * correlation_norm**2 * d_info + 0.5 * scaled_info_norm * d_mean


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


@dataclass(frozen=True)
class ReceivedMarginal:
    """A neighbour's marginal that passed every check, in information form.

    Attributes
    ----------
    sender
        Who sent it.
    ids
        Its objects (all in our map, no repeats).
    info, info_vector
        ``Σ⁻¹`` and ``Σ⁻¹ μ`` of the neighbour's marginal.
    """

    sender: int
    ids: np.ndarray
    info: np.ndarray
    info_vector: np.ndarray
    per_object: bool = False


def receive_marginal(
    state: MsckfState, message: CommonMarginalMessage
) -> tuple[str | None, ReceivedMarginal | None]:
    """Check a neighbour's marginal against our map and factorise it once.

    A marginal in moment form is inverted (its Cholesky factor gives the information matrix);
    one in information form is checked to be positive definite by its Cholesky factorisation.
    Objects that have left our state for the persistent map since the neighbour asked (an
    asynchronous message) are marginalised out of it; an object we never had makes it unusable.
    Returns ``(None, marginal)`` when it can be used, ``(reason, None)`` when it cannot.
    """
    ids = np.asarray(message.ids)
    k = ids.size
    if ids.ndim != 1 or k == 0 or np.unique(ids).size != k:
        return "ids must be a non-empty list without repeats", None
    information = message.info is not None
    name = "information matrix" if information else "covariance"
    per_object = not information and np.ndim(message.cov) == 3
    shape = (k, 3, 3) if per_object else (3 * k, 3 * k)
    if np.shape(message.mean) != (3 * k,) or np.shape(message.matrix) != shape:
        return f"mean/{name} sizes do not match the ids", None
    mean = np.asarray(message.mean, dtype=float)
    matrix = np.asarray(message.matrix, dtype=float)
    if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(matrix))):
        return f"non-finite mean or {name}", None
    transposed = np.swapaxes(matrix, -1, -2)
    if np.abs(matrix - transposed).max() > 1e-9 * np.abs(matrix).max() + 1e-12:
        return f"{name} is not symmetric", None
    matrix = 0.5 * (matrix + transposed)
    absent = state.object_slots(ids) < 0
    if absent.any():
        # an asynchronous message may be older than our last retirement: objects that left our
        # state for the persistent map are marginalised out of it (exact for a Gaussian);
        # objects we never had make the message unusable
        if not state.retired.contains(ids[absent]).all():
            return "ids not in this robot's map", None
        if absent.all():
            return "every object of the marginal has retired from this robot's state", None
        if information:  # marginalise in moment form (a rare path)
            try:
                matrix = spd_inverse(matrix, name)
            except NotPositiveDefiniteError:
                return f"{name} is not positive definite", None
            information = False
        keep = np.flatnonzero(~absent)
        coords = (3 * keep[:, None] + np.arange(3)).ravel()
        ids, mean, k = ids[keep], mean[coords], keep.size
        matrix = matrix[keep] if per_object else matrix[np.ix_(coords, coords)]
    if information:
        _, failed = lapack.dpotrf(matrix, lower=1)
        if failed != 0:
            return f"{name} is not positive definite", None
        info = matrix
    else:
        try:
            info = spd_inverse(matrix, name)
        except NotPositiveDefiniteError:
            return f"{name} is not positive definite", None
    if per_object:  # block-diagonal information of the per-object marginals
        blocks = info
        info = np.zeros((3 * k, 3 * k))
        index = 3 * np.arange(k)[:, None] + np.arange(3)
        info[index[:, :, None], index[:, None, :]] = blocks
    return None, ReceivedMarginal(
        int(message.sender), ids.astype(np.int64), info, info @ mean, per_object
    )


def validate_marginal(state: MsckfState, message: CommonMarginalMessage) -> str | None:
    """Why a received marginal cannot be used (``None`` when it can)."""
    return receive_marginal(state, message)[0]


def consensus_average(
    state: MsckfState,
    self_weight: float,
    received: Sequence[tuple[float, ReceivedMarginal | CommonMarginalMessage]],
    prior: SharedPrior | None = None,
    counters: MutableMapping[str, int] | None = None,
    own_information: Mapping[bytes, np.ndarray] | None = None,
) -> int:
    """Average the common objects with the neighbours' marginals and rebuild the joint.

    Per-object marginals (every neighbour's, or none) are averaged object by object: each
    is compared with our own per-object marginal (``block=3`` of
    :func:`~teamslam.gaussian.completed_geometric_average`).

    Parameters
    ----------
    state
        The agent's state (edited in place).
    self_weight
        ``A_ii``; with the neighbours' weights (and those of neighbours heard without a usable
        marginal, whose term is our own marginal) it sums to one.
    received
        ``(A_ij, marginal)`` for every usable neighbour marginal (a message is checked with
        :func:`receive_marginal` first and raises ``ValueError`` if it cannot be used).
    prior
        Hybrid consensus (module docstring): our own new information since ``prior`` is added to the
        average once more, with the total weight of the neighbour marginals that hold every object
        of ``y``. The rebuild (Prop. 2) still uses our actual conditional. Joint marginals only.
        ``counters["hybrid_fallbacks"]`` is incremented when the result is not positive definite
        and the plain average is used instead.
    own_information
        Our own information matrices of object sets already inverted this step (by
        :func:`common_marginal_message` with ``keep``), under the key ``ids.tobytes()``
        (``int64``, increasing): a neighbour marginal over such a set is completed with it
        instead of inverting our marginal of the set again (and when the set is ``y``, our own
        information of ``y`` is taken from it too). The state must not have changed since they
        were computed.

    Returns
    -------
    int
        Number of objects averaged.
    """
    if not received:
        return 0
    weights = [float(w) for w, _ in received]
    if self_weight < -1e-12 or min(weights) < 0 or self_weight + sum(weights) > 1 + 1e-9:
        raise InternalError(
            f"consensus weights must be non-negative with a sum of at most one "
            f"(self {self_weight}, neighbours {weights})"
        )
    marginals = []
    for _, m in received:
        if isinstance(m, CommonMarginalMessage):
            problem, m = receive_marginal(state, m)
            if m is None:
                raise InputError(f"unusable neighbour marginal: {problem}")
        marginals.append(m)
    per_object = {m.per_object for m in marginals}
    if len(per_object) > 1:
        raise InternalError("neighbour marginals mix joint and per-object messages")
    # y: every object shared with a neighbour heard; one eq. 19 average and one Prop. 2
    # rebuild for all neighbours together
    y_ids = np.unique(np.concatenate([m.ids for m in marginals]))
    slots = state.object_slots(y_ids)
    cols = state.object_columns(slots).ravel()
    own_mean = state.objects[slots].ravel()
    own_cov = state.cov.take(cols, axis=0).take(cols, axis=1)
    terms = []
    for w, m in zip(weights, marginals, strict=True):
        position = np.searchsorted(y_ids, m.ids)
        sub = (3 * position[:, None] + np.arange(3)).ravel()
        own_sub = None if own_information is None else own_information.get(m.ids.tobytes())
        terms.append((w, sub, m.info, m.info_vector, own_sub))
    if per_object.pop():
        mean, cov = completed_geometric_average(own_mean, own_cov, terms, block=3)
        state.replace_marginal(cols, mean, cov)
    else:
        # Σʸ⁻¹ serves the average (our own information) and the rebuild (A = Σˣʸ Σʸ⁻¹); when
        # every neighbour's set is the one we sent (y itself), we inverted it already
        own_info = None if own_information is None else own_information.get(y_ids.tobytes())
        if own_info is None:
            own_info = spd_inverse(own_cov, "own marginal covariance")
        extra = None
        if prior is not None:
            # our own new information Δ, added with the weight of the messages that hold all
            # of y (its weight elsewhere is already that of the messages lacking an object)
            full = sum(term[0] for term in terms if term[1].size == own_mean.size)
            if full > 0:
                prior_info, prior_eta = prior_information(prior, y_ids)
                extra = (
                    full * (own_info - prior_info),
                    full * (own_info @ own_mean - prior_eta),
                )
        try:
            mean, cov = completed_geometric_average(
                own_mean, own_cov, terms, info=own_info, extra=extra
            )
        except NotPositiveDefiniteError:
            if extra is None:
                raise
            if counters is not None:
                counters["hybrid_fallbacks"] += 1
            mean, cov = completed_geometric_average(own_mean, own_cov, terms, info=own_info)
        state.replace_marginal(cols, mean, cov, info=own_info)
    return int(y_ids.size)
