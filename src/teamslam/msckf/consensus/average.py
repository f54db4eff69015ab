"""Consensus, averaging: eq. 19 over the common objects and the rebuilt joint (Prop. 2).

:func:`consensus_average` forms one weighted geometric average (eq. 19) over ``y``, the objects
shared with at least one neighbour heard — each neighbour's marginal completed by our own
conditional (Prop. 2) — and rebuilds the joint. :func:`hybrid_marginal` and
:func:`increment_average` implement the optional rules ``consensus.rule = hybrid`` and
``consensus.rule = increments`` (lock-step only), whose gains never count one robot's new
information more than once; a first-estimates filter's average leaves its rigid motions alone
(:mod:`~teamslam.msckf.consensus.directions`). :func:`persistent_average` averages the objects of
the persistent map, each on its own marginal, the rest of the state a consider state of that
average. Derivations: the concept page *Consensus* (``docs/concepts/consensus.md``).
"""

from __future__ import annotations

from collections.abc import Mapping, MutableMapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from teamslam.errors import InputError, InternalError
from teamslam.gaussian import (
    NotPositiveDefiniteError,
    add_weighted_difference,
    completed_geometric_average,
    spd_inverse,
)
from teamslam.msckf.consensus.checks import ReceivedMarginal, receive_marginal
from teamslam.msckf.consensus.directions import constrained_average, shape_average
from teamslam.msckf.consensus.kernels import symmetric_block
from teamslam.msckf.consensus.messages import CommonMarginalMessage
from teamslam.msckf.filter.state import MsckfState

__all__ = [
    "IncrementTerm",
    "SharedPrior",
    "consensus_average",
    "hybrid_marginal",
    "increment_average",
    "new_information",
    "persistent_average",
    "prior_information",
    "prior_marginal",
    "shared_prior",
]


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
    objects = state.object(order)
    return SharedPrior(
        state.object_ids[order].copy(),
        state.objects[order].ravel().copy(),
        state.covariance(objects),
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
    held, mean, held_info, _ = prior_marginal(prior, ids)
    if held.any():
        target = _coords(np.flatnonzero(held))
        info[np.ix_(target, target)] = held_info
        eta[target] = held_info @ mean
    return info, eta


def _coords(positions: np.ndarray) -> np.ndarray:
    """The ``3k`` coordinates of the objects at ``positions`` of a stacked marginal."""
    return (3 * np.asarray(positions)[:, None] + np.arange(3)).ravel()


def prior_marginal(
    prior: SharedPrior, ids: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The prior's marginal of those of ``ids`` (increasing) it holds.

    Returns
    -------
    held, mean, info, cov
        One flag per id (the object is in the prior), and the prior mean, information matrix
        and covariance of the flagged objects, in the order of ``ids`` — what a message of
        consensus on information increments carries as the sender's prior.
    """
    ids = np.asarray(ids, dtype=np.int64)
    held = np.zeros(ids.size, dtype=bool)
    if prior.ids.size and ids.size:
        pos = np.minimum(np.searchsorted(prior.ids, ids), prior.ids.size - 1)
        held = prior.ids[pos] == ids
    if not held.any():
        return held, np.zeros(0), np.zeros((0, 0)), np.zeros((0, 0))
    source = _coords(pos[held])
    cov = prior.cov[np.ix_(source, source)]
    return held, prior.mean[source], spd_inverse(cov, "hybrid prior marginal"), cov


def hybrid_marginal(
    mean: np.ndarray,
    info: np.ndarray,
    prior_info: np.ndarray,
    prior_eta: np.ndarray,
    gain: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """``N(μ', Σ')`` with the new information since the prior scaled by ``gain`` (≥ 1).

    ``Ω' = Ω + (γ − 1)(Ω − P)`` and ``η' = η + (γ − 1)(η − η_P)`` (concept page *Consensus*).
    Returns ``(μ', Σ', Ω')``, or ``None`` when ``Ω'`` is not positive definite (the new
    information ``Ω − P`` is then too far from positive semi-definite to be scaled).
    """
    if not gain >= 1:
        raise InternalError(f"the hybrid gain must be at least 1, not {gain}")
    eta = info @ mean
    d_info, d_eta = new_information(info, eta, prior_info, prior_eta, gain - 1.0)
    info_h = info + d_info
    try:
        cov_h = spd_inverse(info_h, "hybrid information")
    except NotPositiveDefiniteError:
        return None
    return cov_h @ (eta + d_eta), cov_h, info_h


def new_information(
    info: np.ndarray, eta: np.ndarray, prior_info: np.ndarray, prior_eta: np.ndarray, scale: float
) -> tuple[np.ndarray, np.ndarray]:
    """The new information since the prior, scaled: ``s (Ω − P)`` and ``s (η − η_P)``.

    What hybrid consensus adds to a marginal (concept page *Consensus*): ``s = γ − 1`` for the
    marginal a robot sends (:func:`hybrid_marginal`), ``s`` = the weight of the messages holding
    every averaged object for its own average (:func:`consensus_average`).
    """
    return scale * (info - prior_info), scale * (eta - prior_eta)


def consensus_average(
    state: MsckfState,
    self_weight: float,
    received: Sequence[tuple[float, ReceivedMarginal | CommonMarginalMessage]],
    prior: SharedPrior | None = None,
    counters: MutableMapping[str, int] | None = None,
    own_information: Mapping[bytes, np.ndarray] | None = None,
    increments: bool = False,
    rigid_directions: bool = False,
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
        Hybrid consensus (concept page *Consensus*): our own new information since ``prior``
        is added to the average once more, with the total weight of the neighbour marginals
        that hold every object of ``y``. The rebuild (Prop. 2) still uses our actual
        conditional. Joint marginals only.
        ``counters["hybrid_fallbacks"]`` is incremented when the result is not positive definite
        and the plain average is used instead.
    increments
        With ``prior``: consensus on information increments (concept page *Consensus*,
        :func:`increment_average`) — the neighbours' priors (carried by their messages) are
        averaged with ours, our own new information counts once and each neighbour's with
        weight ``A_ij γ_j`` (the gain ``γ_j`` applied by the sender, :func:`hybrid_marginal`).
    own_information
        Our own information matrices of object sets already inverted this step (by
        :func:`common_marginal_message` with ``keep``), under the key ``ids.tobytes()``
        (``int64``, increasing): a neighbour marginal over such a set is completed with it
        instead of inverting our marginal of the set again (and when the set is ``y``, our own
        information of ``y`` is taken from it too). The state must not have changed since they
        were computed.
    rigid_directions
        Keep our information along the rigid motions of the world at our first estimates of
        the averaged objects as it was (a first-estimates filter, ``consensus.rigid_directions``):
        the plain average averages the robots' marginals of the map's shape
        (:func:`~teamslam.msckf.consensus.directions.shape_average`), the hybrid and increments
        rules and per-object marginals constrain their finished average
        (:func:`~teamslam.msckf.consensus.directions.constrained_average`).

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
    cols = state.object(slots).columns.ravel()
    own_mean = state.objects[slots].ravel()
    own_cov = symmetric_block(state.cov, cols)  # the symmetric part, which is what is inverted
    terms = []
    for w, m in zip(weights, marginals, strict=True):
        position = np.searchsorted(y_ids, m.ids)
        sub = (3 * position[:, None] + np.arange(3)).ravel()
        own_sub = None if own_information is None else own_information.get(m.ids.tobytes())
        terms.append((w, sub, m.info, m.info_vector, own_sub))
    first = state.object_fe[slots] if rigid_directions else None
    if per_object.pop():
        mean, cov = completed_geometric_average(own_mean, own_cov, terms, block=3)
        if first is not None:
            own = spd_inverse(own_cov, "own marginal covariance", symmetric=True)
            mean, cov = constrained_average(own_mean, own, mean, cov, first)
        state.replace_marginal(cols, mean, cov)
    else:
        # Σʸ⁻¹ serves the average (our own information) and the rebuild (A = Σˣʸ Σʸ⁻¹); when
        # every neighbour's set is the one we sent (y itself), we inverted it already
        own_info = None if own_information is None else own_information.get(y_ids.tobytes())
        if own_info is None:
            own_info = spd_inverse(own_cov, "own marginal covariance", symmetric=True)
        if prior is not None and increments:
            increment_terms = [
                IncrementTerm(w, np.searchsorted(y_ids, m.ids), m.info, m.info_vector, m.prior)
                for w, m in zip(weights, marginals, strict=True)
            ]
            averaged = increment_average(own_mean, own_info, y_ids, increment_terms, prior)
            if averaged is None:
                if counters is not None:
                    counters["hybrid_fallbacks"] += 1
                averaged = completed_geometric_average(own_mean, own_cov, terms, info=own_info)
            if first is not None:
                averaged = constrained_average(own_mean, own_info, *averaged, first)
            state.replace_marginal(cols, *averaged, info=own_info)
            return int(y_ids.size)
        if first is not None and prior is None:
            # the plain average of a first-estimates filter: eq. 19 on the map's shape
            terms = [
                (w, sub, info, vector, _own_sub_information(own_info, own_cov, sub, known))
                for w, sub, info, vector, known in terms
            ]
            mean, cov = shape_average(own_mean, own_info, terms, first)
            state.replace_marginal(cols, mean, cov, info=own_info)
            return int(y_ids.size)
        extra = None
        if prior is not None:
            # our own new information Δ, added with the weight of the messages that hold all
            # of y (its weight elsewhere is already that of the messages lacking an object)
            full = sum(term[0] for term in terms if term[1].size == own_mean.size)
            if full > 0:
                extra = new_information(
                    own_info, own_info @ own_mean, *prior_information(prior, y_ids), full
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
        if first is not None:
            mean, cov = constrained_average(own_mean, own_info, mean, cov, first)
        state.replace_marginal(cols, mean, cov, info=own_info)
    return int(y_ids.size)


def _own_sub_information(
    own_info: np.ndarray, own_cov: np.ndarray, sub: np.ndarray, known: np.ndarray | None
) -> np.ndarray:
    """Our information of the coordinates ``sub`` of ``y`` (``known`` if already inverted)."""
    if known is not None:
        return known
    if sub.size == own_info.shape[0]:  # positions increase: all of y, in order
        return own_info
    return spd_inverse(own_cov[np.ix_(sub, sub)], "own marginal covariance", symmetric=True)


@dataclass(frozen=True)
class IncrementTerm:
    """One neighbour's part of consensus on information increments (:func:`increment_average`).

    Attributes
    ----------
    weight
        ``A_ij``.
    position
        Where its objects ``C_j`` sit among the averaged objects ``y`` (object indices).
    info, info_vector
        Its marginal information of ``C_j`` now, new information scaled by its gain
        ``γ_j = 1 + d_j`` (:func:`hybrid_marginal`).
    prior
        ``(held, P_j, η_P)``: which of ``C_j`` were in its prior and its prior information of
        those; ``None`` for a marginal sent without a prior (it then counts as a prior only).
    """

    weight: float
    position: np.ndarray
    info: np.ndarray
    info_vector: np.ndarray
    prior: tuple[np.ndarray, np.ndarray, np.ndarray] | None


def increment_average(
    own_mean: np.ndarray,
    own_info: np.ndarray,
    y_ids: np.ndarray,
    terms: Sequence[IncrementTerm],
    prior: SharedPrior,
) -> tuple[np.ndarray, np.ndarray] | None:
    """Consensus on information increments over ``y`` (concept page *Consensus*), or ``None``.

    ``Ω̄ = P̄ + (Ω − P_y) + Σ_j A_ij Lⱼᵀ (M_j − P_j) Lⱼ``: the average ``P̄`` of the priors,
    our own new information since our prior once, and each neighbour's with weight
    ``A_ij γ_j`` (its marginal ``M_j`` carries its new information scaled by ``γ_j``). The
    priors' average starts from our prior of ``y`` completed, on the objects it lacks, by
    the prior conditional of the heaviest neighbour that holds them (the reference ``R``),
    and adds ``A_ij (P_j − R_{H_j})`` for the objects ``H_j`` of each
    neighbour's prior (``R_{H_j}`` the reference's marginal of them): eq. 42 on the priors,
    each completed by the reference's conditional.

    Parameters
    ----------
    own_mean, own_info
        Our marginal of ``y`` (mean and information matrix).
    y_ids
        The averaged objects, increasing.
    terms
        One per neighbour marginal (:class:`IncrementTerm`).
    prior
        Our objects' marginal right after our last exchange.

    Returns
    -------
    tuple or None
        ``(mean, cov)`` of the averaged marginal of ``y``; ``None`` when ``Ω̄`` (or the
        reference) is not positive definite (a new information that is far from positive
        semi-definite: after relinearisation, or an object that re-entered the state).
    """
    own_prior = prior_information(prior, y_ids)
    info_bar = own_info - own_prior[0]  # our increment, then the reference and the rest
    eta_bar = own_info @ own_mean - own_prior[1]
    ref_info, ref_eta = own_prior[0].copy(), own_prior[1].copy()
    have = prior_marginal(prior, y_ids)[0]
    for term in sorted(terms, key=lambda t: -t.weight):  # stable: ties in sender order
        if term.prior is None:
            continue
        held, p_info, p_eta = term.prior
        new = ~have[term.position[held]]
        if new.any():
            _add_conditional(ref_info, ref_eta, term.position[held], new, p_info, p_eta)
            have[term.position[held][new]] = True
    support = _coords(np.flatnonzero(have))
    ref_cov, ref_mean = np.zeros((0, 0)), np.zeros(0)  # no prior of any object of y anywhere
    if support.size:
        try:
            ref_cov = spd_inverse(ref_info[np.ix_(support, support)], "prior reference")
        except NotPositiveDefiniteError:
            return None
        ref_mean = ref_cov @ ref_eta[support]
    # where each object of y sits in the support (−1: no prior information anywhere)
    in_support = np.full(y_ids.size, -1)
    in_support[have] = np.arange(int(have.sum()))
    info_bar += ref_info
    eta_bar += ref_eta
    for term in terms:
        held = np.ones(term.position.size, dtype=bool) if term.prior is None else term.prior[0]
        p_info, p_eta = (term.info, term.info_vector) if term.prior is None else term.prior[1:]
        positions = term.position[held]
        if positions.size:
            kept = in_support[positions] >= 0
            r_info, r_eta = np.zeros_like(p_info), np.zeros_like(p_eta)
            if kept.any():
                at = _coords(in_support[positions[kept]])
                marginal = spd_inverse(ref_cov[np.ix_(at, at)], "prior reference marginal")
                local = _coords(np.flatnonzero(kept))
                r_info[np.ix_(local, local)] = marginal
                r_eta[local] = marginal @ ref_mean[at]
            target = _coords(positions)
            add_weighted_difference(
                info_bar,
                eta_bar,
                np.ix_(target, target),
                target,
                term.weight,
                (p_info, p_eta),
                (r_info, r_eta),
            )
        if term.prior is not None:  # the increment γ_j (Ω_j − P_j) at weight A_ij
            sub = _coords(term.position)
            local = _coords(np.flatnonzero(held))
            d_info, d_eta = term.info.copy(), term.info_vector.copy()
            d_info[np.ix_(local, local)] -= p_info
            d_eta[local] -= p_eta
            info_bar[np.ix_(sub, sub)] += term.weight * d_info
            eta_bar[sub] += term.weight * d_eta
    try:
        cov = spd_inverse(info_bar, "averaged information")
    except NotPositiveDefiniteError:
        return None
    return cov @ eta_bar, cov


def _add_conditional(
    info: np.ndarray,
    eta: np.ndarray,
    position: np.ndarray,
    new: np.ndarray,
    p_info: np.ndarray,
    p_eta: np.ndarray,
) -> None:
    """Add, in place, the conditional of the ``new`` objects given the others of a marginal.

    ``p_info``, ``p_eta`` hold a marginal of the objects at ``position`` (object indices of
    ``info``); in information form the conditional ``p(n | r)`` is the marginal minus the
    marginal of ``r``: ``[[Λnn, Λnr], [Λrn, Λrn Λnn⁻¹ Λnr]]`` and ``[ηn, Λrn Λnn⁻¹ ηn]``.
    """
    n, r = _coords(np.flatnonzero(new)), _coords(np.flatnonzero(~new))
    yn, yr = _coords(position[new]), _coords(position[~new])
    info[np.ix_(yn, yn)] += p_info[np.ix_(n, n)]
    eta[yn] += p_eta[n]
    if r.size:
        cross = p_info[np.ix_(r, n)]
        gain = cross @ spd_inverse(p_info[np.ix_(n, n)], "prior conditional")
        info[np.ix_(yn, yr)] += cross.T
        info[np.ix_(yr, yn)] += cross
        info[np.ix_(yr, yr)] += gain @ cross.T
        eta[yr] += gain @ p_eta[n]


def persistent_average(
    state: MsckfState,
    received: Sequence[tuple[float, tuple[np.ndarray, np.ndarray, np.ndarray]]],
) -> int:
    """Average the objects of the persistent map with the neighbours' marginals of them.

    Eq. 19 object by object on its own ``3×3`` marginal, ``Ω ← Ω_i + Σ_j A_ij (Ω_j − Ω_i)`` and
    ``η ← η_i + Σ_j A_ij (η_j − η_i)`` over the neighbours ``j`` that sent it (a neighbour
    heard without it contributes our own term, as in :func:`consensus_average`). Its first
    estimate is kept. A retired object is a consider state correlated with the active state and
    the other retired objects: the average replaces its marginal and the rest of the joint is a
    consider state of it (:meth:`~teamslam.msckf.filter.state.MsckfState.average_retired`).

    Parameters
    ----------
    state
        Our state, whose persistent map is averaged (edited in place).
    received
        ``(A_ij, (ids, Ω, η))`` per neighbour: its marginals of objects of ours that are in
        the persistent map (:attr:`~teamslam.msckf.consensus.checks.ReceivedMarginal.retired`).

    Returns
    -------
    int
        The objects averaged. An object whose average is not positive definite keeps its
        marginal (not counted).
    """
    received = [(w, part) for w, part in received if part is not None and part[0].size]
    if not received:
        return 0
    ids = np.unique(np.concatenate([part[0] for _, part in received]))
    means, covs, _ = state.retired.get(ids)
    own_info = np.linalg.inv(0.5 * (covs + np.swapaxes(covs, 1, 2)))
    own_vector = np.einsum("kij,kj->ki", own_info, means)
    info, vector = own_info.copy(), own_vector.copy()
    for weight, (their_ids, their_info, their_vector) in received:
        k = np.searchsorted(ids, their_ids)
        np.add.at(info, k, weight * (their_info - own_info[k]))
        np.add.at(vector, k, weight * (their_vector - own_vector[k]))
    info = 0.5 * (info + np.swapaxes(info, 1, 2))
    ok = np.linalg.eigvalsh(info)[:, 0] > 0
    if not ok.any():
        return 0
    cov = np.linalg.inv(info[ok])
    cov = 0.5 * (cov + np.swapaxes(cov, 1, 2))
    mean = np.einsum("kij,kj->ki", cov, vector[ok])
    state.average_retired(ids[ok], mean, cov)
    return int(ok.sum())
