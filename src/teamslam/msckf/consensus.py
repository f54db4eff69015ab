"""Consensus averaging of the common objects on one robot's state (distributed MSCKF, eqs. 19–21).

The protocol around it — who sends what, which messages are accepted, the weights — is
:mod:`teamslam.msckf.protocol`. What consensus does to the state is split by job:

* building messages — :mod:`teamslam.msckf.consensus_messages`:
  :func:`common_marginal_message`, our marginal of the objects a neighbour asked about, in
  information form by default (we invert it anyway for our own average; the neighbour then
  only checks it), in single precision where that is safe;
* checking them — :mod:`teamslam.msckf.consensus_checks`: :func:`check_message` and
  :func:`receive_marginal`, a neighbour's marginal checked against our map and factorised once
  (its information matrix is what the average uses);
* averaging — :mod:`teamslam.msckf.consensus_average`: :func:`consensus_average` (eq. 19 over
  the common objects, each neighbour completed by our own conditional, then Prop. 2 and eq. 21)
  and the optional hybrid weighting (``consensus_hybrid``, new information at full weight) and
  consensus on information increments (``consensus_increments``, :func:`increment_average`:
  the hybrid messages, each neighbour completed against our prior so every robot's new
  information counts once — the gain condition, link loss and partial maps are derived
  there).

* selecting them — :mod:`teamslam.msckf.consensus_set`: with ``consensus_set = active`` only
  the objects the window can still change are averaged at every move
  (:func:`~teamslam.msckf.consensus_set.active_objects`), the others when they moved further.

This module gathers their public names. A message with unknown ids, wrong sizes, or a
covariance that is not symmetric positive definite is rejected; the estimate is unaffected.
"""

from __future__ import annotations

from teamslam.msckf.consensus_average import (
    SharedPrior,
    consensus_average,
    hybrid_marginal,
    increment_average,
    new_information,
    prior_information,
    shared_prior,
)
from teamslam.msckf.consensus_checks import (
    ReceivedMarginal,
    check_message,
    receive_marginal,
    validate_marginal,
)
from teamslam.msckf.consensus_messages import (
    FLOAT32_MAX_KL,
    common_marginal_message,
    information_rounding_bound,
    object_marginals,
    rounding_divergence,
    rounding_divergence_bound,
)

__all__ = [
    "FLOAT32_MAX_KL",
    "ReceivedMarginal",
    "SharedPrior",
    "check_message",
    "common_marginal_message",
    "consensus_average",
    "hybrid_marginal",
    "increment_average",
    "information_rounding_bound",
    "new_information",
    "object_marginals",
    "prior_information",
    "receive_marginal",
    "rounding_divergence",
    "rounding_divergence_bound",
    "shared_prior",
    "validate_marginal",
]
