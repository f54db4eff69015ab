"""One robot's distributed MSCKF as its own process (``teamslam agent``).

The agent runs :meth:`teamslam.msckf.team.RobotDriver.frame` over its slice of the team dataset
and talks to its neighbours only through a
:class:`~teamslam.runtime.zenoh_transport.ZenohTransport`, lock-step (wait up to the timeout
for each round; a silent neighbour is a link lost, and after ``lost_after`` frames reported
lost) or asynchronous (never wait; newest marginal no older than ``max_age_steps``). It adds
the robot's settings, checkpoints every ``checkpoint_every`` frames (``--resume`` continues)
and a one-robot :class:`~teamslam.msckf.team.TeamResult` written atomically at the end — or,
when the filter fails, with the frames done before the error is raised.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from teamslam.datasets import SensorModel, TeamDataset, load_dataset
from teamslam.errors import EstimationError, InputError, OutputError
from teamslam.msckf.agent import MsckfAgent
from teamslam.msckf.configure import build_settings
from teamslam.msckf.consensus.transport import Transport
from teamslam.msckf.filter.linearization import GroundTruth, linearization_policy
from teamslam.msckf.settings.sources import ConfigError
from teamslam.msckf.settings.values import MsckfConfig
from teamslam.msckf.team import (
    ARRAYS,
    Asynchronous,
    LockStep,
    RobotDriver,
    assemble_result,
    load_result,
    save_result,
    write_atomic,
)
from teamslam.runtime.team_file import TeamFile
from teamslam.textio import read_npz

__all__ = ["load_robot_result", "robot_setup", "run_agent"]


def _atomic_json(path: Path, payload: dict) -> None:
    text = json.dumps(payload, indent=1, sort_keys=True)
    write_atomic(path, lambda tmp: tmp.write_text(text))


def _save_checkpoint(path: Path, driver: RobotDriver, t: int, extra: dict | None = None) -> None:
    arrays = {"poses": driver.poses[: t + 1], "covs": driver.covs[: t + 1]}
    arrays.update(driver.agent.snapshot())
    if driver.lags is not None:  # the neighbours' lags learned: a resumed robot keeps its limits
        arrays.update({f"{LAGS}{k}": v for k, v in driver.lags.state_dict().items()})
    arrays.update(extra or {})
    write_atomic(path / "checkpoint.npz", lambda tmp: np.savez_compressed(tmp, **arrays))
    _atomic_json(path / "checkpoint.json", {"frame": t})  # which frame the checkpoint holds


#: the prefix of the learned message lags' arrays in a checkpoint
LAGS = "consensus_lags_"


def _restore_lags(driver: RobotDriver, snapshot: dict) -> None:
    """Give ``driver`` the message lags a checkpoint holds (older checkpoints: none)."""
    state = {k[len(LAGS) :]: v for k, v in snapshot.items() if k.startswith(LAGS)}
    if driver.lags is not None and state:
        driver.lags.load_state_dict(state)


def _load_checkpoint(path: Path, driver: RobotDriver) -> int:
    snapshot = read_npz(path / "checkpoint.npz")
    driver.agent.restore(snapshot)
    try:
        _restore_lags(driver, snapshot)
    except (KeyError, ValueError) as exc:
        raise InputError(f"{path / 'checkpoint.npz'}: {exc}") from None
    t = driver.agent.frame
    driver.restore(snapshot["poses"][: t + 1], snapshot["covs"][: t + 1])
    return t


def _own_sensor_model(dataset: TeamDataset, index: int) -> SensorModel | None:
    """The dataset's sensor model as it applies to its robot ``index`` alone."""
    model = dataset.sensor_model
    if model is None:
        return None
    return SensorModel(model.for_robot(index), origin=model.origin, note=model.note)


def robot_setup(
    team: TeamFile, robot: int, calibrate: str = "auto"
) -> tuple[TeamDataset, int, MsckfConfig]:
    """Robot ``robot``'s dataset, its index there and its filter settings.

    The team file's settings win over the dataset's sensor model; noise levels neither gives
    are calibrated from this robot's own data (``calibrate="never"``: not, e.g. to check the
    settings before launching).

    Raises
    ------
    InputError
        The dataset has no such robot, or the settings are wrong (a
        :class:`~teamslam.msckf.settings.sources.ConfigError`): a configuration error.
    """
    dataset_path, index = team.dataset_of(robot)
    dataset = load_dataset(dataset_path)
    if not 0 <= index < dataset.n_robots:
        raise InputError(f"robot {robot}: dataset {dataset_path} has no robot {index}")
    # the robot's own data (identity truth of per-robot object ids: its rows, as robot 0)
    identity = dataset.object_identity[dataset.object_identity[:, 0] == index].copy()
    identity[:, 0] = 0
    own = replace(
        dataset,
        robots=[dataset.robots[index]],
        sensor_model=_own_sensor_model(dataset, index),
        object_identity=identity,
    )
    config = build_settings(own, file=team.settings, calibrate=calibrate).config
    # an imported bag may have no ground truth (its metadata says so)
    has_truth = bool(dataset.metadata.get("ground_truth", True))
    if linearization_policy(config.filter.linearization).needs_truth and not has_truth:
        raise ConfigError(
            f"robot {robot}: filter.linearization={config.filter.linearization} needs ground "
            f"truth, and {dataset_path} has none"
        )
    return dataset, index, config


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

    Raises
    ------
    InputError
        A configuration error (before anything runs).
    EstimationError
        The filter failed (naming robot and frame); the result of the frames done is written
        first (``complete: false``).
    """
    from teamslam.runtime.zenoh_transport import ZenohTransport

    dataset, index, config = robot_setup(team, robot)  # a configuration error: nothing written
    out = Path(out) / f"robot_{robot}"
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot write {out}: {exc.strerror or exc}") from exc
    sequence = dataset.robots[index]
    # the ideal linearisation linearises at the truth: this robot's and the team's map
    agent = MsckfAgent(
        robot,
        dataset.calibration,
        sequence,
        config,
        truth=GroundTruth(sequence.T_world_body, dataset),
    )
    transport = transport or ZenohTransport(team, robot)
    neighbours = team.robots[robot].neighbours
    wait = LockStep(team.timeout_s) if team.sync == "lockstep" else Asynchronous(team.max_age_steps)
    driver = RobotDriver(agent, transport, neighbours, wait, lost_after, consensus=bool(neighbours))
    frames = sequence.frames
    start = 0
    if resume and (out / "checkpoint.npz").exists():
        start = _load_checkpoint(out, driver) + 1
    step_latency = []
    _atomic_json(out / "progress.json", {"frame": start - 1, "frames": frames, "pid": os.getpid()})
    try:
        # a first run waits for every neighbour; a resumed robot only for its links to form
        transport.wait_for_peers(len(neighbours), team.timeout_s if start == 0 else 1.0)
        for t in range(start, frames):
            step_begin = time.perf_counter()
            driver.frame(t)
            if publisher is not None:
                publisher.publish(t, driver.poses[: t + 1], agent.state)
            step_latency.append(time.perf_counter() - step_begin)
            if team.checkpoint_every and (t + 1) % team.checkpoint_every == 0:
                _save_checkpoint(out, driver, t)
            if t % 5 == 0 or t == frames - 1:
                _atomic_json(
                    out / "progress.json", {"frame": t, "frames": frames, "pid": os.getpid()}
                )
        # a session's transport waits until its neighbours have our last messages (a memory
        # network delivers them at once and has nothing to wait for)
        transport.finish(team.timeout_s)
    except EstimationError:
        _save(out, driver, transport, robot, team, step_latency, complete=False)
        raise
    finally:
        transport.close()
    return _save(out, driver, transport, robot, team, step_latency, complete=True)


def _latency_ms(seconds) -> dict:
    seconds = np.asarray(seconds, dtype=float)
    return {
        "median": float(np.median(seconds) * 1e3) if seconds.size else None,
        "p95": float(np.percentile(seconds, 95) * 1e3) if seconds.size else None,
    }


def _save(
    out, driver, transport, robot, team, step_latency, complete: bool, extra: dict | None = None
) -> dict:
    """Write the robot's result (a one-robot :class:`TeamResult`); its summary (with
    ``extra``)."""
    result = assemble_result(
        [driver],
        f"team file {team.team}",
        team.message_loss,
        robots=[robot],
        complete=complete,
        consensus=True,
    )
    counters = result.counters[0]
    network = transport.statistics()
    counters["injected_drops"] = int(network.get("injected_drops", 0))
    counters["rejected_wire"] = int(network.get("rejected_wire", 0))
    frames = driver.frames
    summary = {
        "robot": robot,
        "frames": frames,
        "counters": counters,
        "timings": result.timings[0],
        "health": result.sensor_health[0],
        **driver.summary(),
        "bytes_per_step": counters["bytes"] / max(frames - 1, 1),
        "message_latency_ms": _latency_ms(network.get("latencies", [])),
        "step_latency_ms": _latency_ms(step_latency),
        **(extra or {}),
    }
    result.extra["per_robot"] = [summary]
    save_result(result, out)
    return summary


def load_robot_result(out: Path, robot: int) -> tuple[dict, dict]:
    """``(arrays, summary)`` of robot ``robot`` written by :func:`run_agent`: ``poses``,
    ``covs``, ``object_ids``, ``objects``, ``object_covs``, ``frame_times``."""
    result = load_result(Path(out) / f"robot_{robot}")
    arrays = {name: getattr(result, name)[0] for name in ARRAYS if getattr(result, name)}
    arrays["covs"] = arrays.pop("pose_covs")
    return arrays, result.extra["per_robot"][0]
