"""Simulated teams: 3D stereo robots on Lissajous curves (distributed-MSCKF paper, §VI-B),
along a long non-repeating route (a long mission) or through the streets of a grid city."""

from __future__ import annotations

from typing import TYPE_CHECKING

from teamslam._lazy import attach

__all__ = [
    "SENSOR_SCENARIOS",
    "SimulationConfig",
    "grid_city_team",
    "lissajous_team",
    "long_route_team",
    "scenario_team",
]

__getattr__, __dir__ = attach(
    __name__,
    ("grid_city", "lissajous", "long_route", "scenarios"),
    {
        "SimulationConfig": "teamslam.sim.lissajous",
        "grid_city_team": "teamslam.sim.grid_city",
        "lissajous_team": "teamslam.sim.lissajous",
        "long_route_team": "teamslam.sim.long_route",
        "SENSOR_SCENARIOS": "teamslam.sim.scenarios",
        "scenario_team": "teamslam.sim.scenarios",
    },
)


if TYPE_CHECKING:  # what a type checker and an IDE see; nothing is imported at run time
    from teamslam.sim.grid_city import grid_city_team
    from teamslam.sim.lissajous import SimulationConfig, lissajous_team
    from teamslam.sim.long_route import long_route_team
    from teamslam.sim.scenarios import SENSOR_SCENARIOS, scenario_team
