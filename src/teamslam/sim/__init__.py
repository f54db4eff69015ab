"""Simulated teams: 3D stereo robots on Lissajous curves (distributed-MSCKF paper, §VI-B)."""

from teamslam.sim.lissajous import SimulationConfig, lissajous_team

__all__ = ["SimulationConfig", "lissajous_team"]
