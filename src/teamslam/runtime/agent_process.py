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

Weights are the Metropolis–Hastings weights of the neighbour graph for the neighbours heard,
the rest of the row on the robot itself; with every link up they equal the in-process runner's.
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
from teamslam.msckf.agent import MsckfAgent
from teamslam.msckf.consensus import (
    common_marginal_message,
    consensus_average,
    map_ids_message,
    validate_marginal,
)
from teamslam.msckf.settings import resolve_config
from teamslam.runtime.team_file import TeamFile
from teamslam.runtime.transport import CommonMarginalMessage, MapIdsMessage

__all__ = ["load_robot_result", "run_agent"]


def _atomic_savez(path: Path, **arrays) -> None:
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, path)


def _atomic_json(path: Path, payload: dict) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(payload, indent=1, sort_keys=True))
    os.replace(tmp, path)


def _flatten_history(history: dict[int, list[tuple[int, np.ndarray]]]) -> dict[str, np.ndarray]:
    ids, frames, zs = [], [], []
    for key, obs in history.items():
        for f, z in obs:
            ids.append(key)
            frames.append(f)
            zs.append(z)
    return {
        "ids": np.array(ids, dtype=np.int64),
        "frames": np.array(frames, dtype=np.int64),
        "z": np.array(zs, dtype=float).reshape(-1, 4),
    }


def _restore_history(ids, frames, zs) -> dict[int, list[tuple[int, np.ndarray]]]:
    out: dict[int, list] = defaultdict(list)
    for i, f, z in zip(ids.tolist(), frames.tolist(), zs, strict=True):
        out[i].append((f, z.copy()))
    return out


def _save_checkpoint(path: Path, agent: MsckfAgent, poses, covs, t: int) -> None:
    s = agent.state
    tracks = _flatten_history(agent.tracks)
    objects = _flatten_history(agent.object_history)
    _atomic_savez(
        path / "checkpoint.npz",
        frame=np.array(t),
        poses=poses[: t + 1],
        covs=covs[: t + 1],
        window_poses=s.poses,
        window_frames=s.frames,
        object_ids=s.object_ids,
        objects=s.objects,
        cov=s.cov,
        frame_times=np.array(agent.frame_times).reshape(-1, 3),
        track_ids=tracks["ids"],
        track_frames=tracks["frames"],
        track_z=tracks["z"],
        objhist_ids=objects["ids"],
        objhist_frames=objects["frames"],
        objhist_z=objects["z"],
    )
    _atomic_json(
        path / "checkpoint.json",
        {"frame": t, "counters": dict(agent.counters), "timings": dict(agent.timings)},
    )


def _load_checkpoint(path: Path, agent: MsckfAgent, poses, covs) -> int:
    with np.load(path / "checkpoint.npz", allow_pickle=False) as c:
        t = int(c["frame"])
        poses[: t + 1] = c["poses"]
        covs[: t + 1] = c["covs"]
        s = agent.state
        s.poses, s.frames = c["window_poses"].copy(), c["window_frames"].copy()
        s.pose_fe, s.robots = s.poses.copy(), np.zeros(len(s.frames), np.int64)  # FE restarts
        s.object_ids, s.objects, s.cov = (
            c["object_ids"].copy(),
            c["objects"].copy(),
            c["cov"].copy(),
        )
        s.object_fe = s.objects.copy()
        agent.frame_times = [tuple(r) for r in c["frame_times"]]
        agent.tracks = _restore_history(c["track_ids"], c["track_frames"], c["track_z"])
        agent.object_history = _restore_history(
            c["objhist_ids"], c["objhist_frames"], c["objhist_z"]
        )
    meta = json.loads((path / "checkpoint.json").read_text())
    agent.counters = defaultdict(int, meta["counters"])
    agent.timings = defaultdict(float, meta["timings"])
    agent.frame = t
    return t


def _own_sensor_model(dataset: TeamDataset, index: int) -> SensorModel | None:
    """The dataset's sensor model as it applies to its robot ``index`` alone."""
    model = dataset.sensor_model
    if model is None:
        return None
    return SensorModel(model.for_robot(index), origin=model.origin, note=model.note)


def _weights(team: TeamFile, robot: int) -> dict[int, float]:
    degree = team.adjacency().sum(axis=1)
    return {j: 1.0 / (1.0 + max(degree[robot], degree[j])) for j in team.robots[robot].neighbours}


def run_agent(
    team: TeamFile, robot: int, out: Path, resume: bool = False, lost_after: int = 3, transport=None
) -> dict:
    """Run robot ``robot`` of ``team`` to the end of its sequence; returns its summary."""
    from teamslam.runtime.zenoh_transport import ZenohTransport

    out = Path(out) / f"robot_{robot}"
    out.mkdir(parents=True, exist_ok=True)
    dataset_path, index = team.dataset_of(robot)
    dataset = load_dataset(dataset_path)
    if not 0 <= index < dataset.n_robots:
        raise ValueError(f"robot {robot}: dataset {dataset_path} has no robot {index}")
    sequence = dataset.robots[index]
    # the team file's settings win over the dataset's sensor model; noise levels neither gives
    # are calibrated from this robot's own data
    own = replace(dataset, robots=[sequence], sensor_model=_own_sensor_model(dataset, index))
    config = resolve_config(own, file_values=team.filter).config
    agent = MsckfAgent(robot, dataset.calibration, sequence, config)
    frames = sequence.frames
    poses = np.zeros((frames, 4, 4))
    covs = np.zeros((frames, 6, 6))
    start = 0
    if resume and (out / "checkpoint.npz").exists():
        start = _load_checkpoint(out, agent, poses, covs) + 1
    transport = transport or ZenohTransport(team, robot)
    weights = _weights(team, robot)
    neighbours = set(team.robots[robot].neighbours)
    silent = dict.fromkeys(neighbours, 0)
    lost_reported: set[int] = set()
    consensus_times = np.zeros(frames)
    step_latency = []
    lost_steps: list[int] = []
    _atomic_json(out / "progress.json", {"frame": start - 1, "frames": frames, "pid": os.getpid()})
    try:
        if hasattr(transport, "wait_for_peers"):
            # a first run waits for every neighbour; a resumed robot only for its links to form
            transport.wait_for_peers(len(neighbours), team.timeout_s if start == 0 else 1.0)
        for t in range(start, frames):
            step_begin = time.perf_counter()
            if t > 0 and neighbours:
                began = time.perf_counter()
                waiting = {j for j in neighbours if silent[j] < lost_after}
                for j in sorted(neighbours):
                    transport.send(map_ids_message(agent.state, robot, j, t))
                if team.sync == "lockstep":
                    requests = transport.collect(t, MapIdsMessage, waiting, team.timeout_s)
                else:
                    requests = transport.newest(MapIdsMessage, neighbours, team.max_age_steps, t)
                heard_from = {m.sender for m in requests}
                for j in neighbours:
                    silent[j] = 0 if j in heard_from else silent[j] + 1
                    if silent[j] >= lost_after and j not in lost_reported:
                        lost_reported.add(j)
                        agent.counters["neighbours_lost"] += 1
                expected = set()
                for m in requests:
                    reply = common_marginal_message(agent.state, robot, m.sender, t, m.ids)
                    if reply is not None:
                        transport.send(reply)
                    if np.intersect1d(m.ids, agent.state.object_ids).size:
                        expected.add(m.sender)
                if team.sync == "lockstep":
                    replies = transport.collect(t, CommonMarginalMessage, expected, team.timeout_s)
                else:
                    replies = transport.newest(
                        CommonMarginalMessage, neighbours, team.max_age_steps, t
                    )
                if neighbours - heard_from:
                    agent.counters["links_lost"] += len(neighbours - heard_from)
                    lost_steps.append(t)
                self_weight = 1.0 - sum(weights[j] for j in heard_from)
                heard = []
                for m in replies:
                    problem = validate_marginal(agent.state, m)
                    if problem:
                        agent.reject("messages", reason=problem)
                        continue
                    heard.append((weights[m.sender], m))
                agent.counters["objects_averaged"] += consensus_average(
                    agent.state, self_weight, heard
                )
                consensus_times[t] = time.perf_counter() - began
                agent.timings["consensus"] += consensus_times[t]
            agent.step(t)
            poses[t] = agent.state.current_pose
            covs[t] = agent.state.current_pose_cov()
            step_latency.append(time.perf_counter() - step_begin)
            if team.checkpoint_every and (t + 1) % team.checkpoint_every == 0:
                _save_checkpoint(out, agent, poses, covs, t)
            if t % 5 == 0 or t == frames - 1:
                _atomic_json(
                    out / "progress.json", {"frame": t, "frames": frames, "pid": os.getpid()}
                )
    finally:
        if hasattr(transport, "close"):
            transport.close()
    agent.flush_odometry_health()
    frame_times = np.column_stack([consensus_times, np.array(agent.frame_times).reshape(-1, 3)])
    _atomic_savez(
        out / "result.npz",
        poses=poses,
        covs=covs,
        object_ids=agent.state.object_ids,
        objects=agent.state.objects,
        frame_times=frame_times,
    )
    counters = dict(agent.counters)
    counters["messages"] = int(getattr(transport, "messages_sent", 0))
    counters["bytes"] = int(getattr(transport, "bytes_sent", 0))
    counters["injected_drops"] = int(getattr(transport, "injected_drops", 0))
    counters["rejected_wire"] = int(sum(getattr(transport, "rejected", {}).values()))
    latencies = np.asarray(getattr(transport, "latencies", []), dtype=float)
    summary = {
        "robot": robot,
        "frames": frames,
        "counters": counters,
        "timings": dict(agent.timings),
        "health": agent.health.to_json(),
        "lost_neighbours": sorted(lost_reported),
        "steps_with_lost_links": lost_steps,
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
