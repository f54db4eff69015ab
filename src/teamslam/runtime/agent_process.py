"""One robot's distributed MSCKF as its own process (``teamslam agent``).

The agent runs Algorithm 1 over its slice of the team dataset and talks to its neighbours only
through a :class:`~teamslam.runtime.zenoh_transport.ZenohTransport`:

* **lock-step** — at frame ``t`` it sends its map ids to every neighbour, waits (up to the
  timeout) for theirs, answers each with the marginal of the objects they share, waits for the
  answers it expects (it knows which neighbours share objects from their ids), then averages.
  A neighbour that stays silent past the timeout is a link lost for that frame; after
  ``lost_after`` silent frames in a row it is reported lost and no longer waited for (it is
  waited for again as soon as it speaks).
* **async** — it never waits: it answers any ids request it has, and averages with each
  neighbour's newest marginal no older than ``max_age_steps``.

What is sent, what is accepted, the weights and the average are
:class:`~teamslam.msckf.protocol.ConsensusProtocol`, the object the in-process runner schedules
too; this driver adds only the waiting (lock-step or asynchronous), lost-neighbour bookkeeping,
checkpoints and result files.
Results (trajectory, covariances, map, counters, timings, transport figures) are written
atomically at the end; a checkpoint every ``checkpoint_every`` frames lets ``--resume`` continue.
"""

from __future__ import annotations

import json
import os
import time
from collections import defaultdict
from dataclasses import replace
from pathlib import Path

import numpy as np

from teamslam.datasets import SensorModel, TeamDataset, load_dataset
from teamslam.errors import InputError
from teamslam.msckf.agent import MsckfAgent
from teamslam.msckf.messages import CommonMarginalMessage, MapIdsMessage
from teamslam.msckf.protocol import ConsensusProtocol
from teamslam.msckf.settings import resolve_config
from teamslam.msckf.transport import Transport
from teamslam.runtime.team_file import TeamFile

__all__ = ["load_robot_result", "run_agent"]


def _atomic_savez(path: Path, **arrays) -> None:
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, path)


def _atomic_json(path: Path, payload: dict) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(payload, indent=1, sort_keys=True))
    os.replace(tmp, path)


def _save_checkpoint(path: Path, agent: MsckfAgent, poses, covs, t: int) -> None:
    _atomic_savez(
        path / "checkpoint.npz", poses=poses[: t + 1], covs=covs[: t + 1], **agent.snapshot()
    )
    _atomic_json(path / "checkpoint.json", {"frame": t})  # which frame the checkpoint holds


def _load_checkpoint(path: Path, agent: MsckfAgent, poses, covs) -> int:
    with np.load(path / "checkpoint.npz", allow_pickle=False) as c:
        snapshot = {k: c[k] for k in c.files}
    agent.restore(snapshot)
    t = agent.frame
    poses[: t + 1] = snapshot["poses"]
    covs[: t + 1] = snapshot["covs"]
    return t


def _own_sensor_model(dataset: TeamDataset, index: int) -> SensorModel | None:
    """The dataset's sensor model as it applies to its robot ``index`` alone."""
    model = dataset.sensor_model
    if model is None:
        return None
    return SensorModel(model.for_robot(index), origin=model.origin, note=model.note)


def run_agent(
    team: TeamFile,
    robot: int,
    out: Path,
    resume: bool = False,
    lost_after: int = 3,
    transport: Transport | None = None,
    publisher=None,
) -> dict:
    """Run robot ``robot`` of ``team`` to the end of its sequence; returns its summary.

    Parameters
    ----------
    team
        The team file.
    robot
        This robot's id.
    out
        Output directory (``robot_<id>/`` is written inside it).
    resume
        Continue from the last checkpoint if there is one.
    lost_after
        Silent frames in a row after which a neighbour is reported lost and no longer awaited.
    transport
        The endpoint to talk through (default: a Zenoh session from the team file).
    publisher
        Optional; gets ``publish(t, poses[: t + 1], state)`` after every frame, e.g. a
        :class:`~teamslam.ros2.rmw_zenoh.Ros2Publisher`.
    """
    from teamslam.runtime.zenoh_transport import ZenohTransport

    out = Path(out) / f"robot_{robot}"
    out.mkdir(parents=True, exist_ok=True)
    dataset_path, index = team.dataset_of(robot)
    dataset = load_dataset(dataset_path)
    if not 0 <= index < dataset.n_robots:
        raise InputError(f"robot {robot}: dataset {dataset_path} has no robot {index}")
    sequence = dataset.robots[index]
    # the team file's settings win over the dataset's sensor model; noise levels neither gives
    # are calibrated from this robot's own data
    own = replace(dataset, robots=[sequence], sensor_model=_own_sensor_model(dataset, index))
    config = resolve_config(own, file_values=team.filter_settings).config
    agent = MsckfAgent(robot, dataset.calibration, sequence, config)
    frames = sequence.frames
    poses = np.zeros((frames, 4, 4))
    covs = np.zeros((frames, 6, 6))
    start = 0
    if resume and (out / "checkpoint.npz").exists():
        start = _load_checkpoint(out, agent, poses, covs) + 1
    transport = transport or ZenohTransport(team, robot)
    neighbours = set(team.robots[robot].neighbours)
    lockstep = team.sync == "lockstep"
    protocol = ConsensusProtocol(agent, neighbours, max_age=0 if lockstep else team.max_age_steps)
    silent = dict.fromkeys(neighbours, 0)
    lost_reported: set[int] = set()
    consensus_times = np.zeros(frames)
    step_latency = []
    lost_steps: list[int] = []
    averaged_with: dict[int, list[int]] = defaultdict(list)
    _atomic_json(out / "progress.json", {"frame": start - 1, "frames": frames, "pid": os.getpid()})
    try:
        # a first run waits for every neighbour; a resumed robot only for its links to form
        transport.wait_for_peers(len(neighbours), team.timeout_s if start == 0 else 1.0)
        for t in range(start, frames):
            step_begin = time.perf_counter()
            if t > 0 and neighbours:
                waiting = {j for j in neighbours if silent[j] < lost_after}
                for message in protocol.requests(t):
                    transport.send(message)
                if lockstep:
                    requests = transport.collect(
                        t, MapIdsMessage, waiting, team.timeout_s, also=neighbours - waiting
                    )
                else:
                    requests = transport.newest(MapIdsMessage, neighbours, team.max_age_steps, t)
                for reply in protocol.answer(requests):
                    transport.send(reply)
                for j in neighbours:
                    silent[j] = 0 if j in protocol.heard else silent[j] + 1
                    if silent[j] >= lost_after and j not in lost_reported:
                        lost_reported.add(j)
                        agent.counters["neighbours_lost"] += 1
                if lockstep:
                    replies = transport.collect(
                        t, CommonMarginalMessage, protocol.expected, team.timeout_s
                    )
                else:
                    replies = transport.newest(
                        CommonMarginalMessage, neighbours, team.max_age_steps, t
                    )
                if neighbours - protocol.heard:
                    agent.counters["links_lost"] += len(neighbours - protocol.heard)
                    lost_steps.append(t)
                protocol.average(replies)
                for j in protocol.averaged_with:
                    averaged_with[j].append(t)
                consensus_times[t] = protocol.spent
            agent.step(t)
            poses[t] = agent.state.current_pose
            covs[t] = agent.state.current_pose_cov()
            if publisher is not None:
                publisher.publish(t, poses[: t + 1], agent.state)
            step_latency.append(time.perf_counter() - step_begin)
            if team.checkpoint_every and (t + 1) % team.checkpoint_every == 0:
                _save_checkpoint(out, agent, poses, covs, t)
            if t % 5 == 0 or t == frames - 1:
                _atomic_json(
                    out / "progress.json", {"frame": t, "frames": frames, "pid": os.getpid()}
                )
    finally:
        transport.close()
    agent.flush_odometry_health()
    frame_times = np.column_stack([consensus_times, np.array(agent.frame_times).reshape(-1, 3)])
    full_map = agent.state.full_map()  # in the state and retired, by id
    _atomic_savez(
        out / "result.npz",
        poses=poses,
        covs=covs,
        object_ids=full_map[0],
        objects=full_map[1],
        frame_times=frame_times,
    )
    counters = dict(agent.counters)
    network = transport.statistics()
    counters["messages"] = int(transport.messages_sent)
    counters["bytes"] = int(transport.bytes_sent)
    counters["injected_drops"] = int(network.get("injected_drops", 0))
    counters["rejected_wire"] = int(network.get("rejected_wire", 0))
    latencies = np.asarray(network.get("latencies", []), dtype=float)
    summary = {
        "robot": robot,
        "frames": frames,
        "counters": counters,
        "timings": dict(agent.timings),
        "health": agent.health.to_json(),
        "lost_neighbours": sorted(lost_reported),
        "steps_with_lost_links": lost_steps,
        "averaged_with": {str(j): steps for j, steps in sorted(averaged_with.items())},
        "bytes_per_step": counters["bytes"] / max(frames - 1, 1),
        "message_latency_ms": {
            "median": float(np.median(latencies) * 1e3) if latencies.size else None,
            "p95": float(np.percentile(latencies, 95) * 1e3) if latencies.size else None,
        },
        "step_latency_ms": {
            "median": float(np.median(step_latency) * 1e3) if step_latency else None,
            "p95": float(np.percentile(step_latency, 95) * 1e3) if step_latency else None,
        },
    }
    _atomic_json(out / "result.json", summary)
    return summary


def load_robot_result(out: Path, robot: int) -> tuple[dict, dict]:
    """``(arrays, summary)`` written by :func:`run_agent`."""
    base = Path(out) / f"robot_{robot}"
    with np.load(base / "result.npz", allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    return arrays, json.loads((base / "result.json").read_text())
