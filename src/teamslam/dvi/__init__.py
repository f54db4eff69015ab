"""Linear-Gaussian distributed variational inference (distributed-MSCKF paper, §IV and App. B–C).

* :mod:`~teamslam.dvi.models` — agent models (eq. 10) and a generated team tracking problem;
* :mod:`~teamslam.dvi.mirror_descent` — lifted form (11–12), local posteriors (17) and the
  distributed mirror descent of Prop. 3 (16);
* :mod:`~teamslam.dvi.filters` — the recursive distributed Kalman filter (consensus, predict,
  update) and the centralised Kalman filter it is compared with;
* :mod:`~teamslam.dvi.kalman` — prediction and the update with correlated noise (65–67).

These are the reference the nonlinear filters are tested against.
"""

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
