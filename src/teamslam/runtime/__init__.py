"""Robots as processes: the wire format, the team file, a Zenoh transport and team launch.

This layer sits above :mod:`teamslam.msckf`: it implements the
:class:`~teamslam.msckf.transport.Transport` over a network and drives the consensus protocol
(:class:`~teamslam.msckf.protocol.ConsensusProtocol`) in one process per robot.
"""

from teamslam.runtime.agent_process import load_robot_result, run_agent

__all__ = ["load_robot_result", "run_agent"]
