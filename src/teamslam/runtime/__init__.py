"""Robots as processes: the wire format, the team file, a Zenoh transport and team launch.

This layer sits above :mod:`teamslam.msckf`: it implements the
:class:`~teamslam.msckf.consensus.transport.Transport` over a network and drives the consensus
protocol
(:class:`~teamslam.msckf.consensus.protocol.ConsensusProtocol`) in one process per robot.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from teamslam._lazy import attach

__all__ = ["load_robot_result", "run_agent"]

__getattr__, __dir__ = attach(
    __name__,
    ("agent_process", "launch", "netns", "security", "team_file", "wire", "zenoh_transport"),
    {
        "load_robot_result": "teamslam.runtime.agent_process",
        "run_agent": "teamslam.runtime.agent_process",
    },
)


if TYPE_CHECKING:  # what a type checker and an IDE see; nothing is imported at run time
    from teamslam.runtime.agent_process import load_robot_result, run_agent
