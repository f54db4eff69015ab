"""The distributed multi-state constraint Kalman filter (distributed MSCKF paper, §V).

* :mod:`~teamslam.msckf.state` — window of poses + objects and every covariance edit
  (eqs. 18–23, 28, 30);
* :mod:`~teamslam.msckf.models` — stereo observation model and Jacobians;
* :mod:`~teamslam.msckf.update` — triangulation, null-space rows (24), gating, compression;
* :mod:`~teamslam.msckf.persistent_map` — objects retired from the state (bounded cost over a
  long mission) and their re-entry;
* :mod:`~teamslam.msckf.agent` — Algorithm 1 for one robot;
* :mod:`~teamslam.msckf.consensus` — averaging of the common objects (19–21);
* :mod:`~teamslam.msckf.team` — the lock-step team runner;
* :mod:`~teamslam.msckf.linearization` — where Jacobians are evaluated: standard,
  first-estimate, ideal, observability-constrained;
* :mod:`~teamslam.msckf.centralised` — one MSCKF over the whole team (the reference);
* :mod:`~teamslam.msckf.observability` — rank and nullspace of the 3D team filter;
* :mod:`~teamslam.msckf.settings` — where every setting comes from (defaults scaled to the
  camera, the dataset's sensor model, calibration, file, flags);
* :mod:`~teamslam.msckf.calibration` — the sensor model estimated from the data alone;
* :mod:`~teamslam.msckf.health` — NIS and gate statistics of every sensor.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from teamslam._lazy import attach

__all__ = [
    "CalibrationResult",
    "EffectiveConfig",
    "MsckfAgent",
    "MsckfConfig",
    "MsckfState",
    "PersistentMap",
    "TeamResult",
    "calibrate",
    "config_for",
    "resolve_config",
    "run_team",
]

__getattr__, __dir__ = attach(
    __name__,
    (
        "agent",
        "calibration",
        "centralised",
        "config",
        "consensus",
        "health",
        "kernels",
        "linearization",
        "messages",
        "models",
        "observability",
        "persistent_map",
        "protocol",
        "settings",
        "state",
        "team",
        "transport",
        "update",
    ),
    {
        "MsckfAgent": "teamslam.msckf.agent",
        "CalibrationResult": "teamslam.msckf.calibration",
        "calibrate": "teamslam.msckf.calibration",
        "MsckfConfig": "teamslam.msckf.config",
        "PersistentMap": "teamslam.msckf.persistent_map",
        "EffectiveConfig": "teamslam.msckf.settings",
        "config_for": "teamslam.msckf.settings",
        "resolve_config": "teamslam.msckf.settings",
        "MsckfState": "teamslam.msckf.state",
        "TeamResult": "teamslam.msckf.team",
        "run_team": "teamslam.msckf.team",
    },
)


if TYPE_CHECKING:  # what a type checker and an IDE see; nothing is imported at run time
    from teamslam.msckf.agent import MsckfAgent
    from teamslam.msckf.calibration import CalibrationResult, calibrate
    from teamslam.msckf.config import MsckfConfig
    from teamslam.msckf.persistent_map import PersistentMap
    from teamslam.msckf.settings import EffectiveConfig, config_for, resolve_config
    from teamslam.msckf.state import MsckfState
    from teamslam.msckf.team import TeamResult, run_team
