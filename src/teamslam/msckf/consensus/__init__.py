"""Consensus between robots (distributed MSCKF paper, §V-B, eqs. 19–21, Props. 1–3).

:mod:`~teamslam.msckf.consensus.protocol` runs one robot's side;
:mod:`~teamslam.msckf.consensus.messages` and :mod:`~teamslam.msckf.consensus.transport` say
what robots tell each other and how; :mod:`~teamslam.msckf.consensus.marginals` and
:mod:`~teamslam.msckf.consensus.checks` build and check messages;
:mod:`~teamslam.msckf.consensus.average` holds the averaging rules (chosen by the strategy of
:mod:`~teamslam.msckf.consensus.rules`, ``consensus.rule``),
:mod:`~teamslam.msckf.consensus.selection` the bounded consensus set and
:mod:`~teamslam.msckf.consensus.kernels` compiled passes. The public names of the averaging,
checking and message modules are re-exported here and loaded on first use.
"""

from __future__ import annotations

from teamslam._lazy import attach

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

__getattr__, __dir__ = attach(
    __name__,
    (
        "average",
        "checks",
        "kernels",
        "marginals",
        "messages",
        "protocol",
        "rules",
        "selection",
        "transport",
    ),
    {
        "FLOAT32_MAX_KL": "teamslam.msckf.consensus.marginals",
        "ReceivedMarginal": "teamslam.msckf.consensus.checks",
        "SharedPrior": "teamslam.msckf.consensus.average",
        "check_message": "teamslam.msckf.consensus.checks",
        "common_marginal_message": "teamslam.msckf.consensus.marginals",
        "consensus_average": "teamslam.msckf.consensus.average",
        "hybrid_marginal": "teamslam.msckf.consensus.average",
        "increment_average": "teamslam.msckf.consensus.average",
        "information_rounding_bound": "teamslam.msckf.consensus.marginals",
        "new_information": "teamslam.msckf.consensus.average",
        "object_marginals": "teamslam.msckf.consensus.marginals",
        "prior_information": "teamslam.msckf.consensus.average",
        "receive_marginal": "teamslam.msckf.consensus.checks",
        "rounding_divergence": "teamslam.msckf.consensus.marginals",
        "rounding_divergence_bound": "teamslam.msckf.consensus.marginals",
        "shared_prior": "teamslam.msckf.consensus.average",
        "validate_marginal": "teamslam.msckf.consensus.checks",
    },
)
