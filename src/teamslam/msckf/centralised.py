"""The centralised MSCKF: one filter holding every robot's window and every object.

What a single server receiving all the team's data would run, and the accuracy reference of the
distributed filter. One :class:`~teamslam.msckf.state.MsckfState` holds the windows of all
robots (each robot's poses kept together) and one map of objects; robot ``i`` is processed by
an ordinary :class:`~teamslam.msckf.agent.MsckfAgent` whose state is its
:class:`~teamslam.msckf.state.RobotWindow` into the joint state — the same propagation,
feature and object updates, object initialisation and linearisation policy as a robot alone,
but every update acts on the joint covariance, so an object seen by two robots correlates and
corrects both. At each frame the robots' steps are applied one after the other (sequential
Kalman updates of independent measurements). An object enters the map once, from whichever
robot first sees it often enough; afterwards every robot updates it.

The result has the shape of :class:`~teamslam.msckf.team.TeamResult` (each robot's "map" is the
one joint map), so :func:`~teamslam.eval.metrics.team_metrics` gives the same keys.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence

import numpy as np
from tqdm import tqdm

from teamslam.datasets.model import TeamDataset
from teamslam.msckf.agent import MsckfAgent
from teamslam.msckf.config import MsckfConfig
from teamslam.msckf.health import SensorHealth
from teamslam.msckf.linearization import GroundTruth
from teamslam.msckf.state import MsckfState
from teamslam.msckf.team import TeamResult

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
        :func:`~teamslam.msckf.settings.resolve_config`). The first robot's ``debug`` and
        ``initial_pose_std`` apply to the joint state.
    progress
        Show a progress bar (default: when standard error is a terminal).

    Returns
    -------
    TeamResult
        ``consensus=False``, ``graph="centralised"``; ``object_ids``/``objects`` of every robot
        are the joint map; timings are per robot (its share of the joint work).
    """
    from teamslam.msckf.settings import team_configs  # settings calibrate with a team run

    n = dataset.n_robots
    configs = team_configs(dataset, config)
    first = configs[0]
    state = MsckfState.team(
        np.stack([r.T_world_body[0] for r in dataset.robots]),
        0,
        np.eye(6) * first.initial_pose_std**2,
        first.debug,
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
    frames = [r.frames for r in dataset.robots]
    poses = [np.zeros((f, 4, 4)) for f in frames]
    covs = [np.zeros((f, 6, 6)) for f in frames]
    show = sys.stderr.isatty() if progress is None else progress
    begin = time.perf_counter()
    for t in tqdm(range(max(frames)), desc="frames", disable=not show, leave=False):
        running = [i for i in range(n) if t < frames[i]]
        for i in running:
            agents[i].step(t)
        for i in running:  # after every robot's update of this frame
            poses[i][t] = agents[i].state.current_pose
            covs[i][t] = agents[i].state.current_pose_cov()
    wall = time.perf_counter() - begin
    for a in agents:
        a.flush_odometry_health()
    full_map = state.full_map()  # in the state and retired, by id
    return TeamResult(
        poses=poses,
        pose_covs=covs,
        object_ids=[full_map[0] for _ in agents],
        objects=[full_map[1] for _ in agents],
        counters=[{**a.counters, "messages": 0, "bytes": 0} for a in agents],
        timings=[dict(a.timings) for a in agents],
        frame_times=[
            np.column_stack([np.zeros(f), np.array(a.frame_times).reshape(-1, 3)])
            for f, a in zip(frames, agents, strict=True)
        ],
        consensus=False,
        graph="centralised",
        loss=0.0,
        wall_seconds=wall,
        health={
            "team": SensorHealth.combine([a.health for a in agents]).summary(),
            "robots": [a.health.summary() for a in agents],
        },
        object_covs=[full_map[2] for _ in agents],
    )
