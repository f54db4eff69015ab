"""Team bags: a team dataset from a ROS 2 bag, and a dataset as a ROS 2 bag.

Per robot: odometry (``nav_msgs/msg/Odometry``, whose covariance gives the odometry σ when
present), optional ground truth, and ``teamslam_msgs/msg/StereoObservations``. Frames are the
odometry messages; each observation message goes to the frame with the nearest stamp within the
tolerance, and streams that do not overlap raise :class:`~teamslam.errors.InputError` naming
robot, topics and time spans. Stamps are kept so that a bag → dataset → bag trip gives back the
same integer nanoseconds. Topic by topic: the docs' guide *ROS 2*.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from teamslam.datasets import (
    Calibration,
    FrameObservations,
    RobotSequence,
    SensorModel,
    SensorNoise,
    TeamDataset,
)
from teamslam.errors import InputError
from teamslam.eval.estimates import has_ground_truth, stamps_ns
from teamslam.geometry.camera import StereoCamera
from teamslam.ros2 import messages as m
from teamslam.textio import yaml_problem

__all__ = [
    "RobotTopics",
    "export_bag",
    "import_bag",
    "parse_robot_spec",
    "read_camera",
    "write_camera",
]

ODOMETRY = "nav_msgs/msg/Odometry"
POSE = "geometry_msgs/msg/PoseStamped"


@dataclass(frozen=True)
class RobotTopics:
    """One robot of a bag: its name, odometry topic and optional ground-truth topic."""

    name: str
    odometry: str
    ground_truth: str | None = None


def parse_robot_spec(text: str) -> RobotTopics:
    """``NAME:ODOM_TOPIC[:GT_TOPIC]`` → :class:`RobotTopics`."""
    parts = text.split(":")
    if len(parts) not in (2, 3) or not all(parts):
        raise InputError(f"--robot expects NAME:ODOM_TOPIC[:GT_TOPIC], got {text!r}")
    return RobotTopics(parts[0], parts[1], parts[2] if len(parts) == 3 else None)


def write_camera(calibration: Calibration, path: str | Path) -> Path:
    """Write the stereo calibration as JSON (also valid YAML): K, T_left_right, T_cam_body."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "K": calibration.camera.intrinsics.tolist(),
        "T_left_right": calibration.camera.T_left_right.tolist(),
        "T_cam_body": calibration.T_cam_body.tolist(),
        "image_size": list(calibration.image_size) if calibration.image_size else None,
    }
    path.write_text(json.dumps(payload, indent=2) + "\n")
    return path


def read_camera(path: str | Path) -> Calibration:
    """Read a calibration file written by :func:`write_camera` (JSON or YAML)."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise InputError(f"{path}: cannot read the camera file ({exc.strerror or exc})") from None
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: camera file is not valid YAML: {yaml_problem(exc)}") from None
    if not isinstance(data, dict) or not {"K", "T_left_right", "T_cam_body"} <= set(data):
        raise InputError(f"{path}: a camera file needs K, T_left_right and T_cam_body")
    try:
        size = data.get("image_size")
        return Calibration(
            StereoCamera(np.array(data["K"], float), np.array(data["T_left_right"], float)),
            np.array(data["T_cam_body"], float),
            tuple(int(v) for v in size) if size else None,
        )
    except (TypeError, ValueError) as exc:
        raise InputError(f"{path}: {exc}") from None


# ----------------------------------------------------------------------------- export
def _odometry_msg(T, stamp, cov, parent, child):
    t = m.typestore().types
    covariance = np.zeros(36) if cov is None else np.asarray(cov, float).reshape(36)
    return t[ODOMETRY](
        header=m.header(stamp, parent),
        child_frame_id=child,
        pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=m.pose_msg(T), covariance=covariance),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](
                linear=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                angular=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
            ),
            covariance=np.zeros(36),
        ),
    )


def _observations_msg(stamp, frame_id, features, objects):
    fid, fz = features
    oid, oz = objects
    z = np.concatenate([fz, oz]).reshape(-1, 4)
    return m.typestore().types[m.OBSERVATIONS_TYPE](
        header=m.header(stamp, frame_id),
        ids=np.concatenate([fid, oid]).astype(np.int64),
        kinds=np.concatenate(
            [
                np.full(fid.size, m.KIND_FEATURE, np.uint8),
                np.full(oid.size, m.KIND_OBJECT, np.uint8),
            ]
        ),
        u_left=np.ascontiguousarray(z[:, 0]),
        v_left=np.ascontiguousarray(z[:, 1]),
        u_right=np.ascontiguousarray(z[:, 2]),
        v_right=np.ascontiguousarray(z[:, 3]),
    )


def _write_bag(records, out: Path) -> dict:
    """Write ``(stamp, topic, msgtype, cdr bytes)`` records as one MCAP file (rosbag2 MCAP)."""
    counts = m.write_mcap_records(records, out)
    return {"path": str(out), "messages": sum(counts.values()), "bytes": out.stat().st_size}


def export_bag(
    dataset: TeamDataset, out: str | Path, camera: str | Path | None = None, period: float = 1.0
) -> dict:
    """Write ``dataset`` as an MCAP bag in the layout :func:`import_bag` reads.

    Per robot ``robot_<i>``: ``/robot_<i>/odom`` (Odometry, dead-reckoned from the first
    ground-truth pose, covariance growing by the sensor model's odometry σ² per step when it
    has one), ``/robot_<i>/ground_truth`` (PoseStamped, when the dataset has ground truth) and
    ``/robot_<i>/stereo_observations``; stamps from the dataset's timestamps (or frame index ×
    ``period``) plus ``metadata["ros2"]["stamp_origin_ns"]`` when the dataset came from a bag.
    ``camera`` also writes the calibration file :func:`import_bag` needs.
    """
    m.rosbags("rosbag2", "writing a ROS 2 bag")
    begin = time.perf_counter()
    out = Path(out)
    origin = int(dataset.metadata.get("ros2", {}).get("stamp_origin_ns", 0))
    gt = has_ground_truth(dataset)
    records = []
    for i, robot in enumerate(dataset.robots):
        name = f"robot_{i}"
        stamps = origin + stamps_ns(robot.timestamps, robot.frames, period)
        noise = dataset.sensor_model.for_robot(i) if dataset.sensor_model else None
        var = None if noise is None or noise.odometry_std is None else np.square(noise.odometry_std)
        T = robot.T_world_body[0].copy()
        for k in range(robot.frames):
            if k:
                T = T @ robot.odometry[k - 1]
            s = int(stamps[k])
            cov = None if var is None else np.diag(k * var)
            odom = _odometry_msg(T, s, cov, f"{name}/odom", f"{name}/base_link")
            records.append((s, f"/{name}/odom", ODOMETRY, m.serialize(odom, ODOMETRY)))
            if gt:
                pose = m.pose_stamped(robot.T_world_body[k], s, "world")
                records.append((s, f"/{name}/ground_truth", POSE, m.serialize(pose, POSE)))
            obs = _observations_msg(
                s, f"{name}/left_camera", robot.features.frame(k), robot.objects.frame(k)
            )
            records.append(
                (s, f"/{name}/stereo_observations", m.OBSERVATIONS_TYPE, m.serialize(obs))
            )
    summary = _write_bag(records, out)
    if camera is not None:
        write_camera(dataset.calibration, camera)
    summary["seconds"] = time.perf_counter() - begin
    return summary


# ----------------------------------------------------------------------------- import
def _read_topics(bag: Path, topics: set[str]) -> dict[str, list[tuple[int, object]]]:
    """``{topic: [(header stamp ns, message)]}`` for the topics asked for, sorted by stamp."""
    highlevel = m.rosbags("highlevel", "reading a ROS 2 bag")
    AnyReader, AnyReaderError = highlevel.AnyReader, highlevel.AnyReaderError

    if not bag.exists():
        raise InputError(f"{bag}: no such bag")
    try:
        with AnyReader([bag], default_typestore=m.typestore()) as reader:
            available = {c.topic: c.msgtype for c in reader.connections}
            missing = sorted(topics - set(available))
            if missing:
                raise InputError(
                    f"{bag}: no topic {', '.join(missing)} (the bag has "
                    f"{', '.join(sorted(available)) or 'no topics'})"
                )
            out: dict[str, list] = {t: [] for t in topics}
            connections = [c for c in reader.connections if c.topic in topics]
            for conn, _, raw in reader.messages(connections=connections):
                msg = reader.deserialize(raw, conn.msgtype)
                out[conn.topic].append((m.stamp_ns(msg.header.stamp), msg))
    except AnyReaderError as exc:
        raise InputError(f"{bag}: cannot read the bag ({exc})") from None
    for topic, items in out.items():
        items.sort(key=lambda item: item[0])
        stamps = np.array([s for s, _ in items], dtype=np.int64)
        if stamps.size > 1 and np.any(np.diff(stamps) == 0):
            k = int(np.flatnonzero(np.diff(stamps) == 0)[0])
            raise InputError(f"{topic}: two messages with the same stamp {stamps[k]} ns")
    return out


def _check_type(topic: str, items, allowed: tuple[str, ...]) -> None:
    if items and items[0][1].__msgtype__ not in allowed:
        raise InputError(
            f"{topic}: messages of type {items[0][1].__msgtype__}, expected {' or '.join(allowed)}"
        )


def _span(stamps: np.ndarray, origin: int) -> str:
    return f"{(stamps[0] - origin) / 1e9:.3f}..{(stamps[-1] - origin) / 1e9:.3f} s"


def _associate(
    frame_stamps: np.ndarray, stamps: np.ndarray, tolerance_ns: float
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest frame of every stamp and whether it lies within the tolerance."""
    right = np.clip(np.searchsorted(frame_stamps, stamps), 0, frame_stamps.size - 1)
    left = np.clip(right - 1, 0, frame_stamps.size - 1)
    pick = np.where(
        np.abs(frame_stamps[left] - stamps) <= np.abs(frame_stamps[right] - stamps), left, right
    )
    return pick, np.abs(frame_stamps[pick] - stamps) <= tolerance_ns


def _odometry_std(covs: np.ndarray) -> tuple[float, ...] | None:
    diag = np.diagonal(covs, axis1=1, axis2=2)
    if not np.any(diag > 0):
        return None
    steps = np.diff(diag, axis=0)
    if (
        steps.size
        and np.all(steps >= -1e-12 * np.abs(diag[1:]))
        and np.all(np.median(steps, axis=0) > 0)
    ):
        var = np.median(steps, axis=0)  # dead reckoning: the covariance grows by σ² per step
    else:
        var = np.median(diag, axis=0)  # a per-message covariance
    if not np.all(var > 0):
        return None
    return tuple(float(v) for v in np.sqrt(var))


def import_bag(
    bag: str | Path,
    robots: list[RobotTopics],
    observations: str,
    camera: str | Path | Calibration,
    tolerance: float | None = None,
) -> TeamDataset:
    """A :class:`~teamslam.datasets.TeamDataset` from a ROS 2 bag (see the module docstring).

    Parameters
    ----------
    bag
        rosbag2 directory, or an ``.mcap`` / ``.db3`` file.
    robots
        The team's robots in order.
    observations
        Observation topic template; ``{name}`` is replaced by each robot's name.
    camera
        Calibration file (:func:`read_camera`) or a :class:`Calibration`.
    tolerance
        Largest stamp difference in seconds between an observation (or ground-truth) message
        and its frame (default: half the smallest median odometry period).
    """
    m.rosbags("highlevel", "reading a ROS 2 bag")
    bag = Path(bag)
    if not robots:
        raise InputError("import-bag needs at least one --robot")
    if len({r.name for r in robots}) != len(robots):
        raise InputError("robot names must be distinct")
    if "{name}" not in observations and len(robots) > 1:
        raise InputError(f"--observations {observations!r} must contain {{name}} for a team")
    calibration = camera if isinstance(camera, Calibration) else read_camera(camera)
    obs_topics = [observations.format(name=r.name) for r in robots]
    wanted = {r.odometry for r in robots} | set(obs_topics)
    wanted |= {r.ground_truth for r in robots if r.ground_truth}
    data = _read_topics(bag, wanted)
    for r, obs_topic in zip(robots, obs_topics, strict=True):
        _check_type(r.odometry, data[r.odometry], (ODOMETRY,))
        _check_type(obs_topic, data[obs_topic], (m.OBSERVATIONS_TYPE,))
        if r.ground_truth:
            _check_type(r.ground_truth, data[r.ground_truth], (POSE, ODOMETRY))
        if len(data[r.odometry]) < 2:
            raise InputError(f"{r.odometry}: robot {r.name} needs at least two odometry messages")
    odom_stamps = [np.array([s for s, _ in data[r.odometry]], np.int64) for r in robots]
    origin = int(min(s[0] for s in odom_stamps))
    if tolerance is None:
        tolerance_ns = 0.5 * min(float(np.median(np.diff(s))) for s in odom_stamps)
    else:
        if not (np.isfinite(tolerance) and tolerance >= 0):
            raise InputError(f"--tolerance must be a number of seconds ≥ 0, got {tolerance}")
        tolerance_ns = tolerance * 1e9
    sequences, dropped, odometry_std = [], {}, []
    for r, obs_topic, frame_stamps in zip(robots, obs_topics, odom_stamps, strict=True):
        odom = [msg for _, msg in data[r.odometry]]
        T_odom = np.stack([m.pose_matrix(msg.pose.pose) for msg in odom])
        covs = np.stack([np.asarray(msg.pose.covariance, float).reshape(6, 6) for msg in odom])
        odometry = np.linalg.inv(T_odom[:-1]) @ T_odom[1:]
        odometry_std.append(_odometry_std(covs))
        n = frame_stamps.size
        # observations: nearest frame within the tolerance, the nearest message per frame
        items = data[obs_topic]
        stamps = np.array([s for s, _ in items], np.int64)
        if stamps.size and (
            stamps[-1] < frame_stamps[0] - tolerance_ns
            or stamps[0] > frame_stamps[-1] + tolerance_ns
        ):
            raise InputError(
                f"robot {r.name}: observations on {obs_topic} span {_span(stamps, origin)} and "
                f"odometry on {r.odometry} spans {_span(frame_stamps, origin)}: the streams do "
                "not overlap"
            )
        frame_of, ok = (
            _associate(frame_stamps, stamps, tolerance_ns)
            if stamps.size
            else (np.zeros(0, int), np.zeros(0, bool))
        )
        if stamps.size and not ok.any():
            raise InputError(
                f"robot {r.name}: no observation on {obs_topic} lies within "
                f"{tolerance_ns / 1e9:g} s of an odometry stamp (raise --tolerance?)"
            )
        chosen: dict[int, int] = {}
        for idx in np.flatnonzero(ok):
            f = int(frame_of[idx])
            if f not in chosen or abs(stamps[idx] - frame_stamps[f]) < abs(
                stamps[chosen[f]] - frame_stamps[f]
            ):
                chosen[f] = int(idx)
        dropped[r.name] = int(stamps.size - len(chosen))
        per_kind: dict[int, list] = {m.KIND_FEATURE: [], m.KIND_OBJECT: []}
        for f in range(n):
            if f in chosen:
                msg = items[chosen[f]][1]
                ids = np.asarray(msg.ids, np.int64)
                kinds = np.asarray(msg.kinds)
                cols = [np.asarray(getattr(msg, c), float) for c in m.OBSERVATION_COLUMNS]
                if any(c.size != ids.size for c in cols) or kinds.size != ids.size:
                    raise InputError(
                        f"{obs_topic}: message at {(items[chosen[f]][0] - origin) / 1e9:.3f} s "
                        "has fields of different lengths"
                    )
                if np.any((kinds != m.KIND_FEATURE) & (kinds != m.KIND_OBJECT)):
                    raise InputError(f"{obs_topic}: unknown observation kind {set(kinds.tolist())}")
                z = np.column_stack(cols)
            else:
                ids, kinds, z = np.zeros(0, np.int64), np.zeros(0, np.uint8), np.zeros((0, 4))
            for kind, frames in per_kind.items():
                sel = kinds == kind
                frames.append((ids[sel], z[sel]))
        try:
            features = FrameObservations.from_frames(per_kind[m.KIND_FEATURE])
            objects = FrameObservations.from_frames(per_kind[m.KIND_OBJECT])
        except ValueError as exc:
            raise InputError(f"{obs_topic}: {exc}") from None
        # ground truth: one message within the tolerance of every frame
        if r.ground_truth:
            gt_items = data[r.ground_truth]
            gt_stamps = np.array([s for s, _ in gt_items], np.int64)
            if not gt_stamps.size:
                raise InputError(f"{r.ground_truth}: no messages")
            pick, ok = _associate(gt_stamps, frame_stamps, tolerance_ns)
            if not ok.all():
                k = int(np.flatnonzero(~ok)[0])
                raise InputError(
                    f"robot {r.name}: no ground truth on {r.ground_truth} within "
                    f"{tolerance_ns / 1e9:g} s of frame {k} at "
                    f"{(frame_stamps[k] - origin) / 1e9:.3f} s (ground truth spans "
                    f"{_span(gt_stamps, origin)})"
                )
            poses = [gt_items[j][1] for j in pick]
            T_world_body = np.stack(
                [
                    m.pose_matrix(p.pose.pose if hasattr(p, "child_frame_id") else p.pose)
                    for p in poses
                ]
            )
        else:
            T_world_body = T_odom
        sequences.append(
            RobotSequence(
                T_world_body=T_world_body,
                odometry=odometry,
                features=features,
                objects=objects,
                timestamps=(frame_stamps - origin) / 1e9,
            )
        )
    has_gt = all(r.ground_truth for r in robots)
    sensor_model = None
    if any(s is not None for s in odometry_std):
        sensor_model = SensorModel(
            SensorNoise(),
            robots={
                i: SensorNoise(odometry_std=s) for i, s in enumerate(odometry_std) if s is not None
            },
            origin="user",
            note="odometry σ from the bag's odometry covariances",
        )
    metadata = {
        "source": "ROS 2 bag",
        "bag": bag.name,
        "ground_truth": has_gt,
        "ros2": {
            "stamp_origin_ns": origin,
            "robots": [r.name for r in robots],
            "observation_messages_dropped": dropped,
            "tolerance_s": tolerance_ns / 1e9,
        },
    }
    return TeamDataset(
        name=bag.stem,
        calibration=calibration,
        robots=sequences,
        object_ids=np.zeros(0, np.int64),
        object_positions=np.zeros((0, 3)),
        metadata=metadata,
        sensor_model=sensor_model,
    )
