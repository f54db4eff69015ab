"""The team runner: N distributed-MSCKF agents over a team dataset, in lock-step.

At each frame, every robot still running first takes part in consensus over the links that
survive this frame's loss, then processes the frame
(:meth:`~teamslam.msckf.agent.MsckfAgent.step`). The consensus protocol — messages, checks,
weights, the average — is :class:`~teamslam.msckf.protocol.ConsensusProtocol`, the same object
the robot processes run; this runner only schedules its two rounds over an in-memory
:class:`~teamslam.msckf.transport.MemoryNetwork` whose links follow the loss draws. The weights
are therefore the Metropolis–Hastings weights of the surviving links among the robots still
running. The filtered estimate of frame ``k`` (after its update) is what is recorded.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from teamslam.datasets.model import TeamDataset
from teamslam.errors import InputError
from teamslam.graph import CommunicationGraph, EdgeLoss, complete
from teamslam.msckf.agent import MsckfAgent
from teamslam.msckf.config import MsckfConfig
from teamslam.msckf.health import SensorHealth
from teamslam.msckf.linearization import GroundTruth
from teamslam.msckf.messages import CommonMarginalMessage, MapIdsMessage
from teamslam.msckf.protocol import ConsensusProtocol
from teamslam.msckf.transport import MemoryNetwork

__all__ = ["TeamResult", "run_team"]


@dataclass
class TeamResult:
    """Per-robot estimates and what it cost.

    Attributes
    ----------
    poses
        Per robot ``(N_i + 1, 4, 4)`` filtered ``T_world_body`` of every frame.
    pose_covs
        Per robot ``(N_i + 1, 6, 6)`` covariance of that pose (right perturbation).
    object_ids, objects
        Per robot the final map: ids and ``(m, 3)`` positions.
    object_covs
        Per robot ``(m, 3, 3)`` marginal covariances of those positions (empty when unknown).
    counters
        Per robot counts (updates, rejected measurements, objects initialised, …) plus
        ``messages`` and ``bytes`` sent.
    timings
        Per robot seconds per stage (``consensus``, ``propagation``, ``update``,
        ``initialisation``).
    frame_times
        Per robot ``(N_i + 1, 4)`` seconds of each frame in those four stages.
    consensus
        Whether consensus ran.
    health
        Sensor health (:meth:`~teamslam.msckf.health.SensorHealth.summary`): ``team`` over
        every robot, ``robots`` per robot.
    """

    poses: list[np.ndarray]
    pose_covs: list[np.ndarray]
    object_ids: list[np.ndarray]
    objects: list[np.ndarray]
    counters: list[dict[str, int]]
    timings: list[dict[str, float]]
    frame_times: list[np.ndarray]
    consensus: bool
    graph: str
    loss: float
    wall_seconds: float = 0.0
    extra: dict = field(default_factory=dict)
    health: dict = field(default_factory=dict)
    object_covs: list[np.ndarray] = field(default_factory=list)


def run_team(
    dataset: TeamDataset,
    config: MsckfConfig | Sequence[MsckfConfig] | None = None,
    graph: CommunicationGraph | None = None,
    consensus: bool = True,
    loss: float = 0.0,
    seed: int = 0,
    progress: bool | None = None,
) -> TeamResult:
    """Run the distributed MSCKF (or separate MSCKFs) over a team dataset.

    Parameters
    ----------
    dataset
        The team's data.
    config
        Filter settings, one for the team or one per robot (default:
        :func:`~teamslam.msckf.settings.resolve_config` — the dataset's sensor model, or a
        calibration from the data when it has none).
    graph
        Communication graph (default: complete).
    consensus
        ``False`` runs each robot's filter alone ("separate").
    loss
        Per-frame probability that a link is down.
    seed
        Seed of the link-loss draws.
    progress
        Show a progress bar (default: when standard error is a terminal).
    """
    from teamslam.msckf.settings import team_configs  # settings calibrate with a team run

    n = dataset.n_robots
    configs = team_configs(dataset, config)
    graph = graph or complete(n)
    if graph.n != n:
        raise InputError(f"graph has {graph.n} robots, dataset has {n}")
    agents = [
        MsckfAgent(i, dataset.calibration, r, c, truth=GroundTruth(r.T_world_body, dataset))
        for i, (r, c) in enumerate(zip(dataset.robots, configs, strict=True))
    ]
    edge_loss = EdgeLoss(graph, loss, seed)
    links: dict[int, np.ndarray] = {}
    network = MemoryNetwork(n, links=links.__getitem__)
    endpoints = [network.endpoint(i) for i in range(n)]
    neighbours = [np.flatnonzero(graph.adjacency[i]) for i in range(n)]
    protocols = [ConsensusProtocol(agents[i], neighbours[i]) for i in range(n)]
    frames = [r.frames for r in dataset.robots]
    poses = [np.zeros((f, 4, 4)) for f in frames]
    covs = [np.zeros((f, 6, 6)) for f in frames]
    consensus_times = [np.zeros(f) for f in frames]
    show = sys.stderr.isatty() if progress is None else progress
    begin = time.perf_counter()
    for t in tqdm(range(max(frames)), desc="frames", disable=not show, leave=False):
        running = [i for i in range(n) if t < frames[i]]
        active, _ = edge_loss.step()
        if consensus and t > 0:
            mask = np.zeros(n, dtype=bool)
            mask[running] = True
            links.clear()
            links[t] = active & mask[:, None] & mask[None, :]
            for i in running:
                for message in protocols[i].requests(t, np.flatnonzero(links[t][i])):
                    endpoints[i].send(message)
            # every robot answers only once all requests are out, so the rounds never mix
            for i in running:
                heard = endpoints[i].collect(t, MapIdsMessage, set(neighbours[i]), 0.0)
                for reply in protocols[i].answer(heard):
                    endpoints[i].send(reply)
            for i in running:
                heard = endpoints[i].collect(t, CommonMarginalMessage, set(neighbours[i]), 0.0)
                protocols[i].average(heard)
                consensus_times[i][t] = protocols[i].spent
        for i in running:
            agents[i].step(t)
            poses[i][t] = agents[i].state.current_pose
            covs[i][t] = agents[i].state.current_pose_cov()
    wall = time.perf_counter() - begin
    for a in agents:
        a.flush_odometry_health()
    counters = []
    for i, a in enumerate(agents):
        c = dict(a.counters)
        c["messages"] = int(endpoints[i].messages_sent)
        c["bytes"] = int(endpoints[i].bytes_sent)
        counters.append(c)
    maps = [a.state.full_map() for a in agents]  # in the state and retired, by id
    return TeamResult(
        poses=poses,
        pose_covs=covs,
        object_ids=[m[0] for m in maps],
        objects=[m[1] for m in maps],
        object_covs=[m[2] for m in maps],
        counters=counters,
        timings=[dict(a.timings) for a in agents],
        frame_times=[
            np.column_stack([c, np.array(a.frame_times).reshape(-1, 3)])
            for c, a in zip(consensus_times, agents, strict=True)
        ],
        consensus=consensus,
        graph=graph.name,
        loss=loss,
        wall_seconds=wall,
        health={
            "team": SensorHealth.combine([a.health for a in agents]).summary(),
            "robots": [a.health.summary() for a in agents],
        },
    )
