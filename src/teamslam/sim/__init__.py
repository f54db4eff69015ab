"""Simulated teams: 3D stereo robots on Lissajous curves (distributed-MSCKF paper, §VI-B) or
along a long non-repeating route (a long mission)."""

from teamslam.sim.lissajous import SimulationConfig, lissajous_team
from teamslam.sim.long_route import long_route_team
from teamslam.sim.scenarios import SENSOR_SCENARIOS, scenario_team

__all__ = [
    "SENSOR_SCENARIOS",
    "SimulationConfig",
    "lissajous_team",
    "long_route_team",
    "scenario_team",
]
