"""The distributed multi-state constraint Kalman filter (distributed MSCKF paper, §V).

Rooms, each importing only from those listed before it: :mod:`~teamslam.msckf.settings`
(values, their sources, sensor health), :mod:`~teamslam.msckf.filter` (one robot's state,
models, updates, linearisation, persistent map, observability), :mod:`~teamslam.msckf.objects`
(tracking, loop closure), :mod:`~teamslam.msckf.consensus` (what robots exchange and how they
average), and at the top :mod:`~teamslam.msckf.agent`, :mod:`~teamslam.msckf.team`,
:mod:`~teamslam.msckf.centralised`, :mod:`~teamslam.msckf.calibration` and
:mod:`~teamslam.msckf.configure`.
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
