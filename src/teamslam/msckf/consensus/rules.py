"""The consensus rule (``consensus.rule``): what the average does with the neighbours' marginals.

One strategy object per rule, asked by :class:`~teamslam.msckf.consensus.protocol.
ConsensusProtocol` for everything that differs between them:

* :class:`AverageRule` (``average``, the paper's eq. 19 and Prop. 2): each robot sends its
  plain marginal and averages with Metropolis weights; no prior is kept;
* :class:`HybridRule` (``hybrid``): the robot keeps its joint marginal after the last exchange
  (the *prior*), sends the marginal with its new information scaled by the gain ``1 + d_i``
  and adds its own new information once more in its average;
* :class:`IncrementsRule` (``increments``): hybrid messages that also carry the sender's
  prior, so each neighbour's marginal is completed against our prior and our own new
  information enters exactly once on every object;
* :class:`IntersectionRule` (``ci``, ``ici``): the plain marginal is sent and fused with each
  neighbour's by (inverse) covariance intersection with the weight that minimises the fused
  covariance's determinant (:mod:`teamslam.msckf.consensus.intersection`).

The rules and their derivations: :mod:`teamslam.msckf.consensus.average`. Hybrid and increments
hold for lock-step exchanges only; asynchronous robots use :class:`AverageRule`.
"""

from __future__ import annotations

from collections.abc import Mapping, MutableMapping, Sequence

import numpy as np

from teamslam.errors import InputError
from teamslam.gaussian import spd_inverse
from teamslam.msckf.consensus.average import (
    SharedPrior,
    consensus_average,
    hybrid_marginal,
    prior_information,
    shared_prior,
)
from teamslam.msckf.consensus.checks import ReceivedMarginal
from teamslam.msckf.consensus.intersection import intersection_average
from teamslam.msckf.filter.state import MsckfState

__all__ = [
    "AverageRule",
    "ConsensusRule",
    "HybridRule",
    "IncrementsRule",
    "IntersectionRule",
    "consensus_rule",
]


class ConsensusRule:
    """What one consensus rule sends and how it averages (the base is the plain average)."""

    #: The rule's name (``consensus.rule``).
    name = "average"
    #: Whether the rule keeps the robot's joint marginal after each exchange (its prior).
    keeps_prior = False

    def initial_prior(self, state: MsckfState) -> SharedPrior | None:
        """The prior before the first exchange (``None``: the rule keeps none)."""
        return None

    def sent_marginal(
        self,
        state: MsckfState,
        ids: np.ndarray,
        heard: int,
        prior: SharedPrior | None,
        counters: MutableMapping[str, int],
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """``(ids, mean, information)`` of the joint marginal sent in place of the state's
        (``ids`` increasing, ``heard`` neighbours heard this exchange); ``None``: the state's
        own marginals."""
        return None

    def message_prior(self, prior: SharedPrior | None) -> SharedPrior | None:
        """The prior a marginal message carries (``None``: none)."""
        return None

    def average(
        self,
        state: MsckfState,
        self_weight: float,
        used: Sequence[tuple[float, ReceivedMarginal]],
        prior: SharedPrior | None,
        counters: MutableMapping[str, int],
        own_information: Mapping[bytes, np.ndarray],
        rigid_directions: bool = False,
    ) -> int:
        """Average the common objects in place; the number averaged
        (:func:`~teamslam.msckf.consensus.average.consensus_average`)."""
        return consensus_average(
            state,
            self_weight,
            used,
            counters=counters,
            own_information=own_information,
            rigid_directions=rigid_directions,
        )

    def next_prior(
        self, state: MsckfState, prior: SharedPrior | None, exchanged: bool
    ) -> SharedPrior | None:
        """The prior after an exchange (``exchanged``: some neighbour was expected or some
        object averaged)."""
        return None


class AverageRule(ConsensusRule):
    """The Metropolis-weighted geometric average of the paper (eq. 19, Prop. 2)."""


class HybridRule(ConsensusRule):
    """Hybrid consensus: new information at full weight, never counted twice."""

    name = "hybrid"
    keeps_prior = True

    def initial_prior(self, state: MsckfState) -> SharedPrior | None:
        return shared_prior(state)

    def sent_marginal(self, state, ids, heard, prior, counters):
        """Our joint marginal of every object we send, new information scaled by ``1 + d_i``
        (``None`` when that is not positive definite, counted as a ``hybrid_fallbacks``)."""
        slots = state.object_slots(ids)
        mean = state.objects[slots].ravel()
        info = spd_inverse(state.covariance(state.object(slots)), "own marginal covariance")
        gain = 1.0 + heard
        hybrid = hybrid_marginal(mean, info, *prior_information(prior, ids), gain)
        if hybrid is None:
            counters["hybrid_fallbacks"] += 1
            return None
        return ids, hybrid[0], hybrid[1]

    #: whether the averages are of information increments (:class:`IncrementsRule`)
    increments = False

    def average(
        self, state, self_weight, used, prior, counters, own_information, rigid_directions=False
    ):
        return consensus_average(
            state,
            self_weight,
            used,
            prior=prior,
            counters=counters,
            own_information=own_information,
            increments=self.increments,
            rigid_directions=rigid_directions,
        )

    def next_prior(self, state, prior, exchanged):
        return shared_prior(state) if exchanged else prior


class IncrementsRule(HybridRule):
    """Consensus on information increments: hybrid messages carrying the sender's prior."""

    name = "increments"
    increments = True

    def message_prior(self, prior):
        return prior


class IntersectionRule(ConsensusRule):
    """Covariance intersection (``ci``) or inverse covariance intersection (``ici``) with the
    neighbours' plain marginals, each weight chosen per fusion; no prior is kept."""

    name = "ici"

    def average(
        self, state, self_weight, used, prior, counters, own_information, rigid_directions=False
    ):
        return intersection_average(
            state,
            used,
            self.name,
            counters=counters,
            own_information=own_information,
            rigid_directions=rigid_directions,
        )


class CovarianceIntersectionRule(IntersectionRule):
    """Covariance intersection with the weight that minimises the fused determinant."""

    name = "ci"


_RULES: dict[str, type[ConsensusRule]] = {
    "average": AverageRule,
    "hybrid": HybridRule,
    "increments": IncrementsRule,
    "ci": CovarianceIntersectionRule,
    "ici": IntersectionRule,
}


def consensus_rule(name: str) -> ConsensusRule:
    """The rule called ``name`` (``average``, ``hybrid``, ``increments``, ``ci`` or ``ici``)."""
    try:
        return _RULES[name]()
    except KeyError:
        raise InputError(
            f"consensus rule must be one of {', '.join(_RULES)}, not {name!r}"
        ) from None
