"""Linear-Gaussian distributed variational inference (distributed-MSCKF paper, §IV and App. B–C).

* :mod:`~teamslam.dvi.models` — agent models (eq. 10) and a generated team tracking problem;
* :mod:`~teamslam.dvi.mirror_descent` — lifted form (11–12), local posteriors (17) and the
  distributed mirror descent of Prop. 3 (16);
* :mod:`~teamslam.dvi.filters` — the recursive distributed Kalman filter (consensus, predict,
  update) and the centralised Kalman filter it is compared with;
* :mod:`~teamslam.dvi.kalman` — prediction and the update with correlated noise (65–67).

These are the reference the nonlinear filters are tested against.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from teamslam._lazy import attach

__all__ = [
    "CentralizedKalmanFilter",
    "DistributedKalmanFilter",
    "DistributedRun",
    "LiftedModel",
    "LinearGaussianModel",
    "NeighbourMarginal",
    "TeamProblem",
    "centralized_lifted_posterior",
    "kalman_predict",
    "kalman_update",
    "lifted_common_index",
    "local_posterior",
    "mirror_descent",
    "mirror_descent_step",
    "mirror_descent_step_moment",
    "run_centralized",
    "run_distributed",
    "split_common_prior",
    "tracking_problem",
]

__getattr__, __dir__ = attach(
    __name__,
    ("demo", "filters", "kalman", "mirror_descent", "models"),
    {
        "CentralizedKalmanFilter": "teamslam.dvi.filters",
        "DistributedKalmanFilter": "teamslam.dvi.filters",
        "DistributedRun": "teamslam.dvi.filters",
        "NeighbourMarginal": "teamslam.dvi.filters",
        "run_centralized": "teamslam.dvi.filters",
        "run_distributed": "teamslam.dvi.filters",
        "kalman_predict": "teamslam.dvi.kalman",
        "kalman_update": "teamslam.dvi.kalman",
        "LiftedModel": "teamslam.dvi.mirror_descent",
        "centralized_lifted_posterior": "teamslam.dvi.mirror_descent",
        "lifted_common_index": "teamslam.dvi.mirror_descent",
        "local_posterior": "teamslam.dvi.mirror_descent",
        "mirror_descent": "teamslam.dvi.mirror_descent",
        "mirror_descent_step": "teamslam.dvi.mirror_descent",
        "mirror_descent_step_moment": "teamslam.dvi.mirror_descent",
        "split_common_prior": "teamslam.dvi.mirror_descent",
        "LinearGaussianModel": "teamslam.dvi.models",
        "TeamProblem": "teamslam.dvi.models",
        "tracking_problem": "teamslam.dvi.models",
    },
)


if TYPE_CHECKING:  # what a type checker and an IDE see; nothing is imported at run time
    from teamslam.dvi.filters import (
        CentralizedKalmanFilter,
        DistributedKalmanFilter,
        DistributedRun,
        NeighbourMarginal,
        run_centralized,
        run_distributed,
    )
    from teamslam.dvi.kalman import kalman_predict, kalman_update
    from teamslam.dvi.mirror_descent import (
        LiftedModel,
        centralized_lifted_posterior,
        lifted_common_index,
        local_posterior,
        mirror_descent,
        mirror_descent_step,
        mirror_descent_step_moment,
        split_common_prior,
    )
    from teamslam.dvi.models import LinearGaussianModel, TeamProblem, tracking_problem
