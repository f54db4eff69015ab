"""Stereo image bags (ROS 2, MCAP): a team's images written to a bag and read back into a dataset.

The bag side of :mod:`teamslam.datasets.images`: per robot ``sensor_msgs/Image`` (or
``CompressedImage``) left and right topics, optional ``CameraInfo``, odometry and ground-truth
poses; the measurements come from the same per-robot core as the image folders, so a bag and
the folders it was written from give the same dataset.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from teamslam.datasets.images import (
    _per_robot,
    _poses_at,
    _robot_sequence,
    _team,
    image_pairs,
    read_image,
    read_timestamps,
)
from teamslam.datasets.model import TeamDataset
from teamslam.errors import InputError
from teamslam.frontend._cv import require_cv2
from teamslam.frontend.camera import StereoRig, load_camera
from teamslam.frontend.config import FrontendConfig
from teamslam.frontend.detections import read_detections
from teamslam.ros2.detection_bags import detection_records, read_detection_topic

__all__ = ["ImageTopics", "dataset_from_bag", "image_topics", "images_to_bag"]

# ----------------------------------------------------------------------------- ROS 2 bags
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
ODOMETRY = "nav_msgs/msg/Odometry"
POSE = "geometry_msgs/msg/PoseStamped"


@dataclass(frozen=True)
class ImageTopics:
    """One robot's topics in an image bag.

    Attributes
    ----------
    name
        The robot's name.
    left, right
        ``sensor_msgs/Image`` or ``CompressedImage`` topics, paired by header stamp.
    camera_info
        ``(left, right)`` ``sensor_msgs/CameraInfo`` topics (the first message of each), or
        ``None`` when a camera file is given.
    odometry, ground_truth
        ``nav_msgs/Odometry`` and ``geometry_msgs/PoseStamped`` topics (optional),
        interpolated at the image stamps.
    detections
        A ``vision_msgs/msg/Detection2DArray`` topic of boxes in the left images (optional;
        matched to the images by header stamp): the objects are then these boxes, without ids.
    """

    name: str
    left: str
    right: str
    camera_info: tuple[str, str] | None = None
    odometry: str | None = None
    ground_truth: str | None = None
    detections: str | None = None

    @classmethod
    def default(cls, name: str) -> ImageTopics:
        """The topics :func:`images_to_bag` writes for robot ``name``."""
        return cls(
            name,
            f"/{name}/left/image_raw",
            f"/{name}/right/image_raw",
            (f"/{name}/left/camera_info", f"/{name}/right/camera_info"),
            f"/{name}/odom",
            f"/{name}/ground_truth",
        )


def _camera_info_msg(store, stamp: int, frame: str, rig: StereoRig, right: bool):
    from teamslam.ros2 import messages as m

    t = store.types
    cam = rig.camera
    K_rect = cam.intrinsics
    P = np.zeros((3, 4))
    P[:, :3] = K_rect
    if right:
        P[0, 3] = -cam.fx_baseline
    K = rig.K_right if right else rig.K_left
    D = rig.distortion_right if right else rig.distortion_left
    R = rig.R_rect_right if right else rig.R_rect_left
    w, h = rig.image_size
    return t[CAMERA_INFO](
        header=m.header(stamp, frame),
        height=h,
        width=w,
        distortion_model="plumb_bob",
        d=np.asarray(D, float),
        k=np.asarray(K, float).ravel(),
        r=np.asarray(R, float).ravel(),
        p=P.ravel(),
        binning_x=0,
        binning_y=0,
        roi=t["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        ),
    )


def images_to_bag(
    left_dirs: Sequence[str | Path],
    right_dirs: Sequence[str | Path],
    camera: str | Path,
    timestamps: Sequence[str | Path],
    out: str | Path,
    odometry: Sequence[str | Path | None] | None = None,
    ground_truth: Sequence[str | Path | None] | None = None,
    robot_names: Sequence[str] | None = None,
    progress: bool = False,
    detections: Sequence[str | Path | None] | None = None,
) -> dict:
    """Write image folders as a ROS 2 bag (MCAP): per robot the topics of
    :meth:`ImageTopics.default` — ``mono8`` Images, CameraInfo (ROS rectification semantics)
    with every pair, Odometry and PoseStamped at the image stamps; with ``detections`` (per
    robot a YOLO folder or COCO JSON of its left images) also ``/NAME/detections``, the boxes
    as ``vision_msgs/msg/Detection2DArray``.

    Returns
    -------
    dict
        ``path``, ``messages`` and ``bytes`` of the bag.
    """
    from tqdm import tqdm

    from teamslam.ros2 import messages as m

    store = m.typestore()
    t = store.types
    rig = load_camera(camera)
    n = len(left_dirs)
    names = list(robot_names) if robot_names is not None else [f"robot_{i}" for i in range(n)]
    odo_files = _per_robot(odometry, n, "odometry files")
    gt_files = _per_robot(ground_truth, n, "ground-truth files")
    det_sources = _per_robot(detections, n, "detection sources")
    records = []
    bar = tqdm(desc="bag", disable=not progress)
    try:
        for i in range(n):
            pairs = image_pairs(left_dirs[i], right_dirs[i])
            stamps = read_timestamps(timestamps[i])
            if len(stamps) != len(pairs):
                raise InputError(f"{timestamps[i]}: {len(stamps)} stamps for {len(pairs)} pairs")
            if np.any(stamps < 0):
                raise InputError(f"{timestamps[i]}: ROS stamps cannot be negative")
            ns = np.rint(stamps * 1e9).astype(np.int64)
            topics = ImageTopics.default(names[i])
            odo = None if odo_files[i] is None else _poses_at(Path(odo_files[i]), stamps, 0, "odom")
            gt = None if gt_files[i] is None else _poses_at(Path(gt_files[i]), stamps, 0, "truth")
            for k, (lp, rp) in enumerate(pairs):
                s = int(ns[k])
                for topic, path, frame in (
                    (topics.left, lp, f"{names[i]}/left_camera"),
                    (topics.right, rp, f"{names[i]}/right_camera"),
                ):
                    img = read_image(path, rig.image_size)
                    msg = t[IMAGE](
                        header=m.header(s, frame),
                        height=img.shape[0],
                        width=img.shape[1],
                        encoding="mono8",
                        is_bigendian=0,
                        step=img.shape[1],
                        data=img.ravel(),
                    )
                    records.append((s, topic, IMAGE, m.serialize(msg, IMAGE)))
                # with every pair, as camera drivers publish it: a live robot that starts
                # after the bag gets its rig from the next pair
                for right, topic in zip((False, True), topics.camera_info, strict=True):
                    info = _camera_info_msg(store, s, f"{names[i]}/left_camera", rig, right)
                    records.append((s, topic, CAMERA_INFO, m.serialize(info, CAMERA_INFO)))
                if odo is not None:
                    pose = m.pose_stamped(odo[k], s, f"{names[i]}/odom")
                    msg = t[ODOMETRY](
                        header=pose.header,
                        child_frame_id=f"{names[i]}/base_link",
                        pose=t["geometry_msgs/msg/PoseWithCovariance"](
                            pose=pose.pose, covariance=np.zeros(36)
                        ),
                        twist=t["geometry_msgs/msg/TwistWithCovariance"](
                            twist=t["geometry_msgs/msg/Twist"](
                                linear=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                                angular=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                            ),
                            covariance=np.zeros(36),
                        ),
                    )
                    records.append((s, topics.odometry, ODOMETRY, m.serialize(msg, ODOMETRY)))
                if gt is not None:
                    pose = m.pose_stamped(gt[k], s, "world")
                    records.append((s, topics.ground_truth, POSE, m.serialize(pose, POSE)))
                bar.update()
            if det_sources[i] is not None:
                read = read_detections(det_sources[i], [lp.name for lp, _ in pairs], rig.image_size)
                records += detection_records(
                    f"/{names[i]}/detections", ns, read.images, frame_id=f"{names[i]}/left_camera"
                )
    finally:  # closed before any error is printed
        bar.close()
    out = Path(out)
    counts = m.write_mcap_records(records, out)
    return {"path": str(out), "messages": sum(counts.values()), "bytes": out.stat().st_size}


def _decode(msg, topic: str, stamp: int) -> np.ndarray:
    cv2 = require_cv2()
    where = f"{topic} at stamp {stamp} ns"
    if msg.__msgtype__ == COMPRESSED:
        img = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise InputError(f"{where}: cannot decode the compressed image")
        return img
    h, w, step, enc = int(msg.height), int(msg.width), int(msg.step), msg.encoding
    data = np.asarray(msg.data, dtype=np.uint8)
    channels = {"mono8": 1, "8UC1": 1, "bgr8": 3, "rgb8": 3, "bgra8": 4, "rgba8": 4, "mono16": 2}
    if enc not in channels:
        raise InputError(f"{where}: unsupported image encoding {enc!r}")
    if data.size != h * step or step < w * channels[enc]:
        raise InputError(f"{where}: {data.size} bytes for {h} rows of step {step}")
    rows = data.reshape(h, step)[:, : w * channels[enc]]
    if enc == "mono16":
        big = bool(msg.is_bigendian)
        return (rows.copy().view(">u2" if big else "<u2") // 257).astype(np.uint8)
    if channels[enc] == 1:
        return np.ascontiguousarray(rows)
    img = rows.reshape(h, w, channels[enc])
    code = {
        "bgr8": cv2.COLOR_BGR2GRAY,
        "rgb8": cv2.COLOR_RGB2GRAY,
        "bgra8": cv2.COLOR_BGRA2GRAY,
        "rgba8": cv2.COLOR_RGBA2GRAY,
    }[enc]
    return cv2.cvtColor(np.ascontiguousarray(img), code)


def _pose(msg) -> np.ndarray:
    pose = msg.pose.pose if msg.__msgtype__ == ODOMETRY else msg.pose
    T = np.eye(4)
    q = pose.orientation
    T[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    T[:3, 3] = [pose.position.x, pose.position.y, pose.position.z]
    return T


def _interpolate(t: np.ndarray, poses: np.ndarray, q: np.ndarray, what: str) -> np.ndarray:
    tol = 1e-9
    outside = np.flatnonzero((q < t[0] - tol) | (q > t[-1] + tol))
    if outside.size:
        raise InputError(
            f"{what}: image stamp {float(q[outside[0]])!r} s lies outside its span "
            f"[{float(t[0])!r}, {float(t[-1])!r}]"
        )
    q = np.clip(q, t[0], t[-1])
    out = np.tile(np.eye(4), (len(q), 1, 1))
    for axis in range(3):
        out[:, axis, 3] = np.interp(q, t, poses[:, axis, 3])
    out[:, :3, :3] = (
        Slerp(t, Rotation.from_matrix(poses[:, :3, :3]))(q).as_matrix()
        if len(t) > 1
        else poses[0, :3, :3]
    )
    return out


def dataset_from_bag(
    bag: str | Path,
    robots: Sequence[ImageTopics],
    camera: str | Path | None = None,
    *,
    markers: str | Path | None = None,
    config: FrontendConfig | None = None,
    name: str = "image-bag",
    progress: bool = True,
) -> TeamDataset:
    """Run the stereo front-end over a ROS 2 bag's stereo image topics.

    Parameters
    ----------
    bag
        The bag (a rosbag2 directory or an MCAP / sqlite3 file).
    robots
        Per robot its topics (:class:`ImageTopics`).
    camera
        A camera file (:func:`teamslam.frontend.load_camera`); without one, the first robot's
        ``camera_info`` topics give the rig.
    markers, config, name, progress
        As for :func:`dataset_from_images`.

    Returns
    -------
    TeamDataset
        The same measurements as :func:`dataset_from_images` on the same images.
    """
    from tqdm import tqdm

    from teamslam.frontend.camera import rig_from_camera_info
    from teamslam.ros2 import messages as m

    highlevel = m.rosbags("highlevel", "reading a ROS 2 bag of images")
    AnyReader, AnyReaderError = highlevel.AnyReader, highlevel.AnyReaderError

    bag = Path(bag)
    if not bag.exists():
        raise InputError(f"{bag}: no such bag")
    if not robots:
        raise InputError("dataset_from_bag needs at least one robot's topics")
    wanted: set[str] = set()
    for r in robots:
        wanted |= {r.left, r.right}
        wanted |= set(r.camera_info or ())
        wanted |= {x for x in (r.odometry, r.ground_truth) if x}
    data: dict[str, list] = {topic: [] for topic in wanted}
    try:
        with AnyReader([bag], default_typestore=m.typestore()) as reader:
            available = {c.topic for c in reader.connections}
            missing = sorted(wanted - available)
            if missing:
                raise InputError(
                    f"{bag}: no topic {', '.join(missing)} "
                    f"(the bag has {', '.join(sorted(available)) or 'no topics'})"
                )
            conns = [c for c in reader.connections if c.topic in wanted]
            for conn, _, raw in reader.messages(connections=conns):
                msg = reader.deserialize(raw, conn.msgtype)
                data[conn.topic].append((m.stamp_ns(msg.header.stamp), msg))
    except AnyReaderError as exc:
        raise InputError(f"{bag}: cannot read the bag ({exc})") from None
    config = config or FrontendConfig()
    if camera is not None:
        rig = load_camera(camera)
    else:
        if robots[0].camera_info is None:
            raise InputError("give a camera file or the camera_info topics")
        left_info, right_info = (data[t] for t in robots[0].camera_info)
        if not left_info or not right_info:
            raise InputError(f"{bag}: camera_info topics {robots[0].camera_info} are empty")
        rig = rig_from_camera_info(left_info[0][1], right_info[0][1])
    for r in robots:
        for topic in (r.left, r.right):
            stamps = np.array([s for s, _ in data[topic]], np.int64)
            bad = np.flatnonzero(np.diff(stamps) <= 0)
            if bad.size:
                k = int(bad[0]) + 1
                raise InputError(
                    f"{topic}: stamp {stamps[k]} ns is not after {stamps[k - 1]} ns (message {k})"
                )
    bar = tqdm(
        total=sum(len(data[r.left]) for r in robots), desc="bag images", disable=not progress
    )
    try:
        out, info, next_id = [], [], 0
        boxes_given = any(r.detections for r in robots)
        if boxes_given and not all(r.detections for r in robots):
            raise InputError("detection topics for some robots and not others: give each robot one")
        for r in robots:
            left_stamps = np.array([s for s, _ in data[r.left]], np.int64)
            right_by_stamp = dict(data[r.right])
            missing = [s for s in left_stamps.tolist() if s not in right_by_stamp]
            if missing:
                raise InputError(f"{r.right}: no image with the stamp {missing[0]} ns of {r.left}")
            if not left_stamps.size:
                raise InputError(f"{r.left}: no images")
            seconds = left_stamps / 1e9
            poses = {}
            for kind, topic in (("odometry", r.odometry), ("ground truth", r.ground_truth)):
                if topic is None:
                    poses[kind] = None
                    continue
                items = sorted(data[topic], key=lambda item: item[0])
                if not items:
                    raise InputError(f"{topic}: no messages")
                t = np.array([s for s, _ in items], np.float64) / 1e9
                p = np.stack([_pose(msg) for _, msg in items])
                poses[kind] = _interpolate(t, p, seconds, topic)
            images = (
                (
                    _check_size(_decode(msg, r.left, s), rig, r.left, s),
                    _check_size(_decode(right_by_stamp[s], r.right, s), rig, r.right, s),
                    f"{r.left} at stamp {s} ns",
                )
                for s, msg in data[r.left]
            )
            boxes = None
            if r.detections:
                read = read_detection_topic(bag, r.detections, left_stamps, rig.image_size)
                boxes = {"left": read, "right": None, "truth": None, "source": r.detections}
            robot, record, next_id = _robot_sequence(
                images,
                rig,
                config,
                next_id,
                poses["odometry"],
                poses["ground truth"],
                seconds,
                bar,
                boxes,
            )
            record.update({"name": r.name, "left": r.left, "right": r.right})
            if r.odometry:
                record["odometry"] = f"topic {r.odometry}"
            if r.ground_truth:
                record["ground_truth"] = f"topic {r.ground_truth}"
            out.append(robot)
            info.append(record)
    finally:  # closed before any error is printed
        bar.close()
    source = {"bag": str(bag), "camera": str(camera) if camera else "camera_info topics"}
    return _team(out, info, rig, config, markers, name, source, boxes=boxes_given)


def _check_size(img: np.ndarray, rig: StereoRig, topic: str, stamp: int) -> np.ndarray:
    w, h = rig.image_size
    if img.shape != (h, w):
        raise InputError(
            f"{topic} at stamp {stamp} ns: image is {img.shape[1]}×{img.shape[0]}, "
            f"the camera says {w}×{h}"
        )
    return img


def image_topics(
    robot: str,
    images: str,
    camera_info: str | None = None,
    odometry: str | None = None,
    detections: str | None = None,
) -> ImageTopics:
    """One robot's :class:`ImageTopics` from command-line templates.

    Parameters
    ----------
    robot
        ``NAME[:ODOM_TOPIC[:GT_TOPIC]]``.
    images
        ``LEFT_TOPIC,RIGHT_TOPIC``, ``{name}`` replaced by the robot's name.
    camera_info
        ``LEFT_TOPIC,RIGHT_TOPIC`` of ``sensor_msgs/CameraInfo`` (``{name}`` replaced), or
        ``None``.
    odometry
        An odometry topic template used when ``robot`` names none.
    detections
        A ``Detection2DArray`` topic template (``{name}`` replaced), or ``None``.
    """
    parts = robot.split(":")
    if not 1 <= len(parts) <= 3 or not all(parts):
        raise InputError(f"--robot expects NAME[:ODOM_TOPIC[:GT_TOPIC]], got {robot!r}")
    name = parts[0]

    def pair(text: str, flag: str) -> tuple[str, str]:
        items = [s.strip().replace("{name}", name) for s in text.split(",")]
        if len(items) != 2 or not all(items):
            raise InputError(f"{flag} expects LEFT_TOPIC,RIGHT_TOPIC, got {text!r}")
        return items[0], items[1]

    left, right = pair(images, "--images")
    info = None if camera_info is None else pair(camera_info, "--camera-info")
    odo = parts[1] if len(parts) > 1 else odometry
    if odo is not None:
        odo = odo.replace("{name}", name)
    return ImageTopics(
        name,
        left,
        right,
        info,
        odo,
        parts[2].replace("{name}", name) if len(parts) > 2 else None,
        None if detections is None else detections.replace("{name}", name),
    )
