"""The distributed multi-state constraint Kalman filter (distributed MSCKF paper, §V).

Rooms, each importing only from those listed before it:

* :mod:`~teamslam.msckf.settings` — the settings' values, where each came from, sensor health;
* :mod:`~teamslam.msckf.filter` — one robot's state (window of poses and objects, the one door
  to its covariance), models, updates, linearisation policies, persistent map, observability;
* :mod:`~teamslam.msckf.objects` — a robot's own object tracker and loop closure;
* :mod:`~teamslam.msckf.consensus` — what robots exchange and how they average it: protocol,
  messages, transport, averaging rules, checks;
* at the top: :mod:`~teamslam.msckf.agent` (Algorithm 1 for one robot),
  :mod:`~teamslam.msckf.team` (the one frame loop, lock-step team runner),
  :mod:`~teamslam.msckf.centralised` (one filter for the whole team, the reference),
  :mod:`~teamslam.msckf.calibration` (the sensor model estimated from the data by running the
  filter) and :mod:`~teamslam.msckf.configure` (a run's settings, built once).
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
    "build_settings",
    "calibrate",
    "config_for",
    "run_team",
]

__getattr__, __dir__ = attach(
    __name__,
    (
        "agent",
        "calibration",
        "centralised",
        "configure",
        "consensus",
        "filter",
        "objects",
        "settings",
        "team",
    ),
    {
        "MsckfAgent": "teamslam.msckf.agent",
        "CalibrationResult": "teamslam.msckf.calibration",
        "calibrate": "teamslam.msckf.calibration",
        "MsckfConfig": "teamslam.msckf.settings.values",
        "PersistentMap": "teamslam.msckf.filter.persistent_map",
        "EffectiveConfig": "teamslam.msckf.settings.sources",
        "build_settings": "teamslam.msckf.configure",
        "config_for": "teamslam.msckf.configure",
        "MsckfState": "teamslam.msckf.filter.state",
        "TeamResult": "teamslam.msckf.team",
        "run_team": "teamslam.msckf.team",
    },
)


if TYPE_CHECKING:  # what a type checker and an IDE see; nothing is imported at run time
    from teamslam.msckf.agent import MsckfAgent
    from teamslam.msckf.calibration import CalibrationResult, calibrate
    from teamslam.msckf.configure import build_settings, config_for
    from teamslam.msckf.filter.persistent_map import PersistentMap
    from teamslam.msckf.filter.state import MsckfState
    from teamslam.msckf.settings.sources import EffectiveConfig
    from teamslam.msckf.settings.values import MsckfConfig
    from teamslam.msckf.team import TeamResult, run_team
