"""Consensus, averaging: eq. 19 over the common objects and the rebuilt joint (Prop. 2).

* :func:`consensus_average` — agent ``i`` forms one weighted geometric average (eq. 19) over
  ``y``, the objects it shares with at least one neighbour it heard: neighbour ``j``'s message
  covers ``C_ij ⊆ y`` and is completed with ``i``'s own conditional ``p_i(y∖C_ij | C_ij)``
  (Prop. 2) — :func:`teamslam.gaussian.completed_geometric_average` — then the joint is rebuilt
  with Prop. 2 and the window poses corrected with ``exp`` (eq. 21) by
  :meth:`~teamslam.msckf.filter.state.MsckfState.replace_marginal`;
* :func:`shared_prior`, :func:`prior_information`, :func:`new_information` and
  :func:`hybrid_marginal` — the optional hybrid weighting (``consensus.rule = hybrid``), below.

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

**Consensus on information increments** (``consensus.rule = increments``;
:func:`increment_average`). The hybrid rule adds our own new information with the weight of
the messages that hold *every* averaged object; where a message lacks some object of ``y`` —
partial maps, or pairs that
exchange different subsets because only some objects moved — our own new information on the
objects it does hold enters with less than full weight, and with the map of our team (objects
seen by two to five robots) that is most averages. And a message of one matrix cannot tell the
sender's prior from its scaled new information: when an object enters a robot's map after a
neighbour has held it for a while, the newcomer (prior zero) would keep ``A_ij`` of the
neighbour's prior and the old holder ``1 − A_ij`` of its own, for good. So each message of this
rule carries two parts: the hybrid marginal ``M_j = P_j + γ_j Δ_j`` of ``C_j`` (the new
information scaled in the sender's joint, then marginalised) and the sender's *prior* ``P_j`` of
the objects ``H_j ⊆ C_j`` it held at its last exchange (flags, mean, information matrix). Robot
``i`` forms

    ``Ω̄ = P̄ + (Ω − P_y) + Σ_j A_ij Lⱼᵀ (M_j − P_j) Lⱼ``  (and ``η̄`` alike),

``Ω = P + Δ`` its own marginal of ``y`` and ``P_y`` its prior of ``y`` (zero on objects it
initialised since), with the average of the priors

    ``P̄ = R + Σ_j A_ij L_{H_j}ᵀ (P_j − R_{H_j}) L_{H_j}``.

``R`` is the *reference*: our prior of ``y``, completed on the objects it lacks by the prior
conditional ``p_j(new | rest of H_j)`` of the heaviest neighbour that holds them; ``R_{H_j}`` is
its marginal of ``H_j``. ``P̄`` is eq. 42 on the priors — each neighbour's prior completed by the
reference's conditional, weights summing to one: a convex combination — so an object new to us
takes the old holders' prior whole, and an object new to a neighbour (not in ``H_j``) keeps ours
whole. Then comes our own increment, once on every object of ``y``, and each neighbour's,
``γ_j Δ_j``, with weight ``A_ij``. Where every prior holds every object of ``y`` this equals the
one-matrix form ``Ω + Σ_j A_ij Lⱼᵀ (M_j − P_{C_j}) Lⱼ``.

*The condition.* An increment — the information one robot gathered between two exchanges, from
measurement noise independent of every prior — must enter any estimate with a total weight of
at most one. In one exchange robot ``i`` receives ``Δ_j`` only from ``j`` itself, with weight
``A_ij γ_j``; so the condition is ``A_ij γ_j ≤ 1`` for every receiver ``i`` of ``j``. With
Metropolis weights ``A_ij = 1/(1 + max(d_i, d_j)) ≤ 1/(1 + d_j)``, the largest gain the sender
can use without knowing its receivers' degrees is ``γ_j = 1 + d_j`` (``d_j`` the neighbours it
heard this step): the weight is then exactly one wherever ``d_i ≤ d_j`` — on a complete graph
everywhere, where one exchange equals the centralised Kalman filter on the common objects — and
``(1 + d_j)/(1 + d_i) < 1`` elsewhere. Later exchanges carry the increment only inside priors,
which enter ``P̄`` as one convex combination (the reference takes each object's prior from one
robot: ours, or the heaviest neighbour's conditional), so by induction — with the completion by
a conditional that eq. 42 and Prop. 2 rest on — no increment ever weighs more than one in any
estimate: never more information than the centralised filter (tested, not proved, where
completions meet partial maps).
*Link loss*: a robot renews its prior after every step in which it sent a marginal, whether or not
it arrived, so an increment is sent at gain ``γ`` once; a lost message loses that increment for
that neighbour (it arrives later only inside a prior, at a Metropolis weight) but never doubles it;
a neighbour heard in round 1 whose marginal did not arrive keeps its weight on the reference.
*Partial maps*: a neighbour's increment only enters on the objects its message holds; ours enters
on all of ``y`` once; objects initialised since the prior have ``P = 0``, so their whole marginal
counts as new — once — and their prior comes from the neighbours that held them. A marginal without
a prior (a neighbour not on this rule, or one whose objects had to be marginalised in translation)
counts as a prior only: its new information is then lost, never doubled.
*Iterations* (``consensus.iterations = L`` exchanges per step): HCMCI averages the increments
``L`` times and then scales the result by one ``ω``, so robot ``k``'s increment ends in robot
``i`` with the weight ``ω (Π^L)_ik``; never counting it twice needs ``ω ≤ 1 / max_ik (Π^L)_ik``,
which on a sparse graph is close to one (the diagonal of ``Π^L`` stays large) and needs ``Π^L``,
which no robot knows. Here a robot renews its prior after every exchange, so its increment is
sent — at the gain ``γ_j = 1 + d_j`` — in the first exchange after it was gathered and never
again: exchanges ``2 … L`` of a step find no new information (``Ω = P``) and are eq. 42 on the
priors. After them ``Δ_k`` weighs ``Σ_j (Π^{L−1})_ij c_jk`` in robot ``i`` (``c_kk = 1``,
``c_jk = A_jk γ_k ≤ 1``): a convex combination of weights of at most one. So the condition is
``A_ij γ_j ≤ 1`` in the exchange that carries the increment, for any ``L``; on a complete graph
the first exchange is the centralised Kalman filter and the others change nothing, on a sparse
graph they spread each increment beyond one hop inside the priors (tested with ``L = 3``, link
loss and partial maps).
*Asynchronous exchanges*
may use one marginal at several steps, counting its increment again, so the rule (like hybrid) is
lock-step only. All of this is tested on a linear team (``tests/test_consistent_consensus.py``),
including objects that enter a second robot's map late.
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

    ``Ω' = Ω + (γ − 1)(Ω − P)`` and ``η' = η + (γ − 1)(η − η_P)`` (module docstring). Returns
    ``(μ', Σ', Ω')``, or ``None`` when ``Ω'`` is not positive definite (the new information
    ``Ω − P`` is then too far from positive semi-definite to be scaled).
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

    What hybrid consensus adds to a marginal (module docstring): ``s = γ − 1`` for the marginal
    a robot sends (:func:`hybrid_marginal`), ``s`` = the weight of the messages holding every
    averaged object for its own average (:func:`consensus_average`).
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
    increments
        With ``prior``: consensus on information increments (module docstring,
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
    if per_object.pop():
        mean, cov = completed_geometric_average(own_mean, own_cov, terms, block=3)
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
            state.replace_marginal(cols, *averaged, info=own_info)
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
        state.replace_marginal(cols, mean, cov, info=own_info)
    return int(y_ids.size)


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
    """Consensus on information increments over ``y`` (module docstring), or ``None``.

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
