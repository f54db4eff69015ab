"""Consistent planar multi-robot EKF SLAM (the FEJ multi-robot EKF paper).

* :mod:`~teamslam.ekf2d.models` — motion (eqs. 2–6) and observation (eqs. 7–11) models;
* :mod:`~teamslam.ekf2d.linearization` — standard / first-estimate / ideal Jacobian policies;
* :mod:`~teamslam.ekf2d.filter` — the EKF over ``[robot poses, features]`` (eq. 1);
  :mod:`~teamslam.ekf2d.kernels` — its compiled small-state propagation and update (numba);
* :mod:`~teamslam.ekf2d.start` — step-0 Gauss–Newton start (eq. 12);
* :mod:`~teamslam.ekf2d.observability` — local observability matrix and rank (eq. 13, Lemma 1);
* :mod:`~teamslam.ekf2d.environments`, :mod:`~teamslam.ekf2d.simulate` — environments 1 and 2
  and Monte Carlo data; :mod:`~teamslam.ekf2d.experiments` — Tables 1–2;
* :mod:`~teamslam.ekf2d.victoria_park` — the two-robot Victoria Park split (Fig. 6).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from teamslam._lazy import attach

__all__ = [
    "FirstEstimate",
    "Ideal",
    "MultiRobotEKF",
    "Standard",
    "StartError",
    "StepObservations",
    "gauss_newton_start",
    "policy",
]

__getattr__, __dir__ = attach(
    __name__,
    (
        "environments",
        "experiments",
        "filter",
        "kernels",
        "linearization",
        "models",
        "observability",
        "run",
        "simulate",
        "start",
        "victoria_park",
    ),
    {
        "MultiRobotEKF": "teamslam.ekf2d.filter",
        "StepObservations": "teamslam.ekf2d.filter",
        "FirstEstimate": "teamslam.ekf2d.linearization",
        "Ideal": "teamslam.ekf2d.linearization",
        "Standard": "teamslam.ekf2d.linearization",
        "policy": "teamslam.ekf2d.linearization",
        "StartError": "teamslam.ekf2d.start",
        "gauss_newton_start": "teamslam.ekf2d.start",
    },
)


if TYPE_CHECKING:  # what a type checker and an IDE see; nothing is imported at run time
    from teamslam.ekf2d.filter import MultiRobotEKF, StepObservations
    from teamslam.ekf2d.linearization import FirstEstimate, Ideal, Standard, policy
    from teamslam.ekf2d.start import StartError, gauss_newton_start
