"""The centralised MSCKF: one filter holding every robot's window and every object.

The accuracy reference of the distributed filter. One
:class:`~teamslam.msckf.filter.state.MsckfState` holds every robot's window and one map; each
robot runs an ordinary :class:`~teamslam.msckf.agent.MsckfAgent` on its
:class:`~teamslam.msckf.filter.state.RobotWindow`, so every update acts on the joint covariance.
At each frame the robots' steps are applied one after the other (sequential updates of
independent measurements). The result has the shape of
:class:`~teamslam.msckf.team.TeamResult` (each robot's map is the joint map).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from teamslam.datasets.model import TeamDataset
from teamslam.msckf.agent import MsckfAgent
from teamslam.msckf.filter.linearization import GroundTruth
from teamslam.msckf.filter.state import MsckfState
from teamslam.msckf.settings.values import MsckfConfig
from teamslam.msckf.team import RobotDriver, TeamResult, run_drivers

__all__ = ["run_centralised"]


def run_centralised(
    dataset: TeamDataset,
    config: MsckfConfig | Sequence[MsckfConfig] | None = None,
    progress: bool | None = None,
) -> TeamResult:
    """Run one MSCKF over the whole team.

    Parameters
    ----------
    dataset
        The team's data.
    config
        Filter settings, one for the team or one per robot (default:
        :func:`~teamslam.msckf.configure.build_settings`). The first robot's ``filter.debug`` and
        ``filter.initial_pose_std`` apply to the joint state.
    progress
        Show a progress bar (default: when standard error is a terminal).

    Returns
    -------
    TeamResult
        ``consensus=False``, ``graph="centralised"``; ``object_ids``/``objects`` of every robot
        are the joint map; timings are per robot (its share of the joint work).
    """
    from teamslam.msckf.configure import team_configs  # settings calibrate with a team run

    n = dataset.n_robots
    configs = team_configs(dataset, config)
    first = configs[0]
    state = MsckfState.team(
        np.stack([r.T_world_body[0] for r in dataset.robots]),
        0,
        np.eye(6) * first.filter.initial_pose_std**2,
        first.filter.debug,
    )
    agents = [
        MsckfAgent(
            i,
            dataset.calibration,
            r,
            c,
            state=state.window(i),
            truth=GroundTruth(r.T_world_body, dataset),
        )
        for i, (r, c) in enumerate(zip(dataset.robots, configs, strict=True))
    ]
    drivers = [RobotDriver(a) for a in agents]  # no transport: the state is shared
    return run_drivers(
        drivers,
        "centralised",
        0.0,
        progress=progress,
        maps=lambda: [state.full_map()] * n,  # in the state and retired, by id
    )
