"""A live robot's Foxglove view (:mod:`teamslam.viz.foxglove`), read by a Foxglove WebSocket
client on loopback: what it receives, decoded with the schemas the server advertises, is the
robot's estimate; without a client nothing is built; the view changes no estimate."""

from __future__ import annotations

import base64
import json
import struct
import threading
import time
from collections import defaultdict

import numpy as np
import pytest

pytest.importorskip("foxglove", reason="the foxglove extra (foxglove-sdk) is not installed")
pytest.importorskip("rosbags", reason="the ros2 extra (rosbags) is not installed")
pytest.importorskip("websockets", reason="websockets (the test extra) is not installed")
pytest.importorskip("google.protobuf", reason="protobuf (the test extra) is not installed")

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from scipy.spatial.transform import Rotation
from websockets.sync.client import connect

from teamslam.errors import InputError, OutputError
from teamslam.live import LiveInputs, LiveRobot
from teamslam.viz.foxglove import TOPICS, CameraModel, FoxgloveView, parse_address
from test_runtime_live import (  # noqa: F401 - the bags are fixtures
    BOXES,
    INFO,
    LEFT,
    ODOM,
    RIGHT,
    TRUTH,
    Recorder,
    bag_messages,
    detection_bag,
    live_robot,
    observations_bag,
    offline_poses,
    one_robot_team,
)

pytestmark = pytest.mark.network

# the SDK's name of the Foxglove WebSocket protocol (``foxglove.websocket.v1`` on the wire)
SUBPROTOCOL = "foxglove.sdk.v1"
WAIT_S = 30.0  # the longest any wait below may take


class Client:
    """A Foxglove WebSocket client (subprotocol :data:`SUBPROTOCOL`): it reads the server's
    channels, subscribes to those asked for and decodes every message it receives (protobuf
    with the advertised file descriptors, JSON as JSON), in a thread of its own."""

    def __init__(self, url: str) -> None:
        self._connection = connect(url, subprotocols=[SUBPROTOCOL], open_timeout=WAIT_S)
        self.ws = self._connection.__enter__()
        self.channels: dict[int, dict] = {}
        self.messages: dict[str, list] = defaultdict(list)  # topic: [(log time, message)]
        self._subscriptions: dict[int, dict] = {}
        self._decoders: dict[int, object] = {}
        self._lock = threading.Lock()
        self.server_info = json.loads(self.ws.recv(timeout=WAIT_S))
        deadline = time.monotonic() + WAIT_S
        while len(self.channels) < len(TOPICS) and time.monotonic() < deadline:
            text = json.loads(self.ws.recv(timeout=WAIT_S))
            if text["op"] == "advertise":
                self.channels.update({c["id"]: c for c in text["channels"]})
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def channel(self, topic: str) -> dict:
        return next(c for c in self.channels.values() if c["topic"] == topic)

    def subscribe(self, topics) -> None:
        subscriptions = []
        for topic in topics:
            channel = self.channel(topic)
            sid = len(self._subscriptions) + 1
            self._subscriptions[sid] = channel
            self._decoders[sid] = _decoder(channel)
            subscriptions.append({"id": sid, "channelId": channel["id"]})
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))

    def _read(self) -> None:
        try:
            for frame in self.ws:
                if isinstance(frame, str) or frame[0] != 0x01:  # not message data
                    continue
                sid, log_time = struct.unpack_from("<IQ", frame, 1)
                message = self._decoders[sid](frame[13:])
                with self._lock:
                    self.messages[self._subscriptions[sid]["topic"]].append((log_time, message))
        except Exception:  # the connection closed
            return

    def received(self, topic: str) -> list:
        with self._lock:
            return list(self.messages[topic])

    def wait_for(self, topic: str, count: int) -> list:
        deadline = time.monotonic() + WAIT_S
        while len(self.received(topic)) < count and time.monotonic() < deadline:
            time.sleep(0.01)
        return self.received(topic)

    def close(self) -> None:
        self._connection.__exit__(None, None, None)
        self._reader.join(WAIT_S)


def _decoder(channel: dict):
    """The decoder of a channel's messages, from what the server advertised of it."""
    if channel["encoding"] == "json":
        return lambda data: json.loads(bytes(data))
    assert channel["encoding"] == "protobuf" and channel["schemaEncoding"] == "protobuf"
    files = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
    pool = descriptor_pool.DescriptorPool()
    for file in files.file:
        pool.Add(file)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))
    return lambda data: cls.FromString(bytes(data))


def _wait_subscribed(view: FoxgloveView, names) -> None:
    deadline = time.monotonic() + WAIT_S
    while not all(view.subscribed(n) for n in names) and time.monotonic() < deadline:
        time.sleep(0.01)
    assert all(view.subscribed(n) for n in names)


def _matrix(pose) -> np.ndarray:
    T = np.eye(4)
    q = pose.orientation
    T[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    T[:3, 3] = [pose.position.x, pose.position.y, pose.position.z]
    return T


def _transform(link) -> np.ndarray:
    """``T_parent_child`` of a FrameTransform."""
    T = np.eye(4)
    q, t = link.rotation, link.translation
    T[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    T[:3, 3] = [t.x, t.y, t.z]
    return T


def _stamp(timestamp) -> int:
    return timestamp.seconds * 1_000_000_000 + timestamp.nanos


def test_a_client_receives_each_frames_pose_path_map_and_latency(observations_bag, tmp_path):  # noqa: F811
    bag, dataset, config = observations_bag
    view = FoxgloveView(0, "127.0.0.1", 0)
    client = Client(view.url)
    try:
        assert client.server_info["op"] == "serverInfo"
        names = ("pose", "path", "objects", "tf", "latency")
        client.subscribe(view.topics[n] for n in names)
        _wait_subscribed(view, names)
        robot = live_robot(tmp_path, dataset, config)
        robot.view = view
        for item in bag_messages(bag, {ODOM, "/robot_0/stereo_observations"}):
            robot.feed(item)
        robot.finish()
        robot.run()
        frames = robot.sequence.frames
        poses = client.wait_for(view.topics["pose"], frames)
        latency = client.wait_for(view.topics["latency"], frames)
        tf = client.wait_for("/tf", frames)
        maps = client.wait_for(view.topics["objects"], frames)
        paths = client.wait_for(view.topics["path"], len(range(0, frames, view.path_every)))
    finally:
        client.close()
        view.close()
    estimate = robot.driver.poses[:frames]
    stamps = robot.sequence.stamps_ns[:frames]
    # the estimates are those of a robot without a view
    assert np.array_equal(estimate, offline_poses(dataset.robots[0], dataset.calibration, config))
    assert len(poses) == frames == 41
    for t, (log_time, message) in enumerate(poses):
        assert message.frame_id == "world" and _stamp(message.timestamp) == stamps[t] == log_time
        T = _matrix(message.pose)
        assert np.array_equal(T[:3, 3], estimate[t][:3, 3])  # float64 on the wire
        assert np.allclose(T[:3, :3], estimate[t][:3, :3], atol=1e-12)
    for t, (_, message) in enumerate(tf):
        (link,) = message.transforms
        assert (link.parent_frame_id, link.child_frame_id) == ("world", "robot_0/base_link")
        assert np.array_equal([link.translation.x, link.translation.y, link.translation.z],
                              estimate[t][:3, 3])  # fmt: skip
    assert [m["frame"] for _, m in latency] == list(range(frames))
    assert np.array_equal([m["latency_ms"] for _, m in latency], np.array(robot.latency_ns) / 1e6)
    # the path every path_every frames: the poses so far
    assert view.path_every == 10 and len(paths) == 5
    for k, (_, message) in enumerate(paths):
        assert len(message.poses) == 10 * k + 1
        assert np.array_equal([[p.position.x, p.position.y, p.position.z] for p in message.poses],
                              estimate[: 10 * k + 1, :3, 3])  # fmt: skip
    # the last map message holds the robot's map: every object at its mean, by id
    ids, means, covs = robot.driver.agent.state.full_map()
    assert ids.size > 10
    entities = maps[-1][1].entities
    assert [int(e.id) for e in entities] == ids.tolist()
    for entity, mean, cov in zip(entities, means, covs, strict=True):
        (sphere,) = entity.spheres
        position = sphere.pose.position
        assert np.array_equal([position.x, position.y, position.z], mean)
        diameters = sorted([sphere.size.x, sphere.size.y, sphere.size.z])
        assert np.allclose(diameters, 6.0 * np.sqrt(np.linalg.eigvalsh(cov)), rtol=1e-9)
    assert view.logged["image"] == view.logged["boxes"] == 0  # observations: no image


def test_without_a_client_nothing_is_built_and_the_estimates_are_unchanged(
    observations_bag,  # noqa: F811
    tmp_path,
):
    bag, dataset, config = observations_bag
    view = FoxgloveView(0, "127.0.0.1", 0)
    try:
        robot = live_robot(tmp_path, dataset, config)
        robot.view = view
        for item in bag_messages(bag, {ODOM, "/robot_0/stereo_observations"}):
            robot.feed(item)
        robot.finish()
        robot.run()
    finally:
        view.close()
    assert robot.sequence.frames == 41
    assert not any(view.logged.values()), view.logged
    expected = offline_poses(dataset.robots[0], dataset.calibration, config)
    assert np.array_equal(np.stack(robot.publisher.poses), expected)


def test_an_image_robot_shows_its_left_image_and_the_tracked_boxes(detection_bag, tmp_path):  # noqa: F811
    cv2 = pytest.importorskip("cv2")
    bag, dataset, config = detection_bag
    inputs = LiveInputs(
        ODOM, left=LEFT, right=RIGHT, camera_info=INFO, queue=10_000, ground_truth=TRUTH,
        detections=BOXES,
    )  # fmt: skip
    view = FoxgloveView(0, "127.0.0.1", 0)
    client = Client(view.url)
    robot = LiveRobot(one_robot_team(checkpoint_every=0), 0, inputs, config, tmp_path,
                      publisher=Recorder(), view=view)  # fmt: skip
    names = ("image", "boxes", "tf", "objects", "calibration")
    shown = {}
    try:
        client.subscribe(view.topics[n] for n in names)
        _wait_subscribed(view, names)
        items = bag_messages(bag, {ODOM, LEFT, RIGHT, TRUTH, BOXES, *INFO})
        for item in items:
            robot.feed(item)
        robot.finish()
        robot.run()
        frames = robot.sequence.frames
        for n in names:
            shown[n] = client.wait_for(view.topics[n], frames)
    finally:
        client.close()
        view.close()
    offline = dataset.robots[0]
    assert frames == offline.frames
    assert np.array_equal(
        robot.driver.poses[:frames], offline_poses(offline, dataset.calibration, config)
    )
    assert len(shown["image"]) == len(shown["boxes"]) == frames
    # the left images, as the bag has them (JPEG: close, not equal)
    lefts = [i.message for i in items if i.topic == LEFT]
    width, height = dataset.calibration.image_size
    for (_, message), raw in zip(shown["image"], lefts, strict=True):
        assert message.format == "jpeg" and message.frame_id == "robot_0/camera_left"
        decoded = cv2.imdecode(np.frombuffer(message.data, np.uint8), cv2.IMREAD_GRAYSCALE)
        source = np.asarray(raw.data, np.uint8).reshape(height, width)
        assert decoded.shape == source.shape
        assert np.abs(decoded.astype(int) - source).mean() < 3.0
    # one outline per detection of each frame, as the offline import measured them
    per_frame = np.diff(offline.detections.offsets)
    assert [len(m.points) for _, m in shown["boxes"]] == per_frame.tolist()
    assert per_frame.sum() > 20
    # the last frame's boxes name the ids the tracker gave them
    ids = robot.driver.agent.detection_ids
    texts = [t.text.split()[0] for t in shown["boxes"][-1][1].texts]
    assert [t for t in texts if t.isdigit() and int(t) >= 10**9] == [str(i) for i in ids if i >= 0]
    # the camera hangs below the robot in /tf; the map's objects carry the classes voted for
    links = shown["tf"][-1][1].transforms
    assert [(x.parent_frame_id, x.child_frame_id) for x in links] == [
        ("world", "robot_0/base_link"),
        ("robot_0/base_link", "robot_0/camera_left"),
    ]
    # each image comes with the left camera's calibration, the rig's
    rig = robot.rig
    assert len(shown["calibration"]) == frames
    calibration = shown["calibration"][-1][1]
    assert calibration.frame_id == "robot_0/camera_left"
    assert (calibration.width, calibration.height) == (width, height)
    assert np.allclose(np.reshape(calibration.K, (3, 3)), rig.K_left)
    assert np.allclose(np.reshape(calibration.R, (3, 3)), rig.R_rect_left)
    assert np.allclose(np.reshape(calibration.P, (3, 4)), rig.P_rect_left)
    assert calibration.distortion_model == "plumb_bob" and len(calibration.D) == 5
    # with it and /tf, the app draws the tracked objects inside the boxes the tracker named
    # them by (an estimate: most, not all)
    T_world_body, T_body_cam = (_transform(x) for x in links)
    T_cam_world = np.linalg.inv(T_world_body @ T_body_cam)
    map_ids, positions, _ = robot.driver.agent.state.full_map()
    at = dict(zip(map_ids.tolist(), np.asarray(positions).reshape(-1, 3), strict=True))
    inside = []  # per named box: its object's projection falls inside it
    for outline, oid in zip(shown["boxes"][-1][1].points, ids, strict=True):
        if oid not in at:
            continue
        corners = np.array([(p.x, p.y) for p in outline.points])
        (x0, y0), (x1, y1) = corners.min(axis=0), corners.max(axis=0)
        p_cam = T_cam_world[:3, :3] @ at[oid] + T_cam_world[:3, 3]
        uv, _ = cv2.projectPoints(
            p_cam[None], np.zeros(3), np.zeros(3), np.reshape(calibration.K, (3, 3)),
            np.asarray(calibration.D),
        )  # fmt: skip
        u, v = uv.ravel()
        inside.append(x0 <= u <= x1 and y0 <= v <= y1)
    # a wrong frame (the camera's pose inverted, the body's for the camera's) puts none inside
    assert len(inside) >= 3 and np.mean(inside) >= 0.75, inside
    entities = shown["objects"][-1][1].entities
    assert [int(e.id) for e in entities] == map_ids.tolist() and map_ids.size
    labels = robot.driver.agent.tracker.labels_of(map_ids)
    assert (labels >= 0).any()
    for entity, label in zip(entities, labels, strict=True):
        classes = [kv.value for kv in entity.metadata if kv.key == "class"]
        assert classes == ([] if label < 0 else [str(label)])


def test_a_taken_port_is_one_line_and_addresses_parse():
    view = FoxgloveView(0, "127.0.0.1", 0)
    try:
        with pytest.raises(OutputError, match=rf"127\.0\.0\.1:{view.port}: .*in use"):
            FoxgloveView(1, "127.0.0.1", view.port)
    finally:
        view.close()
    assert parse_address("8765") == ("127.0.0.1", 8765)
    assert parse_address("0.0.0.0:9000") == ("0.0.0.0", 9000)
    assert parse_address("[::1]:9000") == ("::1", 9000)


@pytest.fixture(scope="module")
def one_robot(tmp_path_factory):
    """A one-robot team file over a small simulated dataset (the robot talks to nobody)."""
    import os

    from teamslam.datasets import save_dataset
    from teamslam.runtime.team_file import load_team_file, write_team_file
    from teamslam.sim import lissajous_team

    tmp = tmp_path_factory.mktemp("offline")
    dataset = save_dataset(lissajous_team(robots=1, steps=30, seed=2), tmp / "team1")
    port = 13200 + (os.getpid() % 100) * 4  # loopback below the ephemeral range, per process
    path = write_team_file(tmp / "team.yaml", "view", dataset, np.zeros((1, 1), bool), port)
    return path, load_team_file(path)


def test_a_robot_over_a_dataset_feeds_the_view_as_its_publisher(one_robot, tmp_path):
    from teamslam.datasets import load_dataset
    from teamslam.eval.estimates import stamps_ns
    from teamslam.msckf.consensus.transport import MemoryNetwork
    from teamslam.runtime.agent_process import load_robot_result, run_agent

    _, team = one_robot
    dataset_path, _ = team.dataset_of(0)
    sequence = load_dataset(dataset_path).robots[0]
    view = FoxgloveView(0, "127.0.0.1", 0, stamps_ns(sequence.timestamps, sequence.frames, 1.0))
    client = Client(view.url)
    try:
        client.subscribe([view.topics["pose"], view.topics["objects"]])
        _wait_subscribed(view, ("pose", "objects"))
        run_agent(
            team, 0, tmp_path / "with", transport=MemoryNetwork(1).endpoint(0), publisher=view
        )
        poses = client.wait_for(view.topics["pose"], sequence.frames)
        maps = client.wait_for(view.topics["objects"], sequence.frames)
    finally:
        client.close()
        view.close()
    run_agent(team, 0, tmp_path / "without", transport=MemoryNetwork(1).endpoint(0))
    with_view, _ = load_robot_result(tmp_path / "with", 0)
    without, _ = load_robot_result(tmp_path / "without", 0)
    assert np.array_equal(with_view["poses"], without["poses"])
    assert len(poses) == len(maps) == sequence.frames == 31
    for t, (_, message) in enumerate(poses):
        assert np.array_equal(_matrix(message.pose)[:3, 3], with_view["poses"][t][:3, 3])
    assert len(maps[-1][1].entities) > 10


def test_teamslam_agent_foxglove_says_where_and_runs_as_without(one_robot, tmp_path):
    import subprocess
    import sys

    from teamslam.runtime.agent_process import load_robot_result

    path, _ = one_robot
    argv = [sys.executable, "-m", "teamslam", "agent", "--team", str(path), "--robot", "0"]
    results = {}
    for name, extra in (("with", ["--foxglove", "127.0.0.1:0"]), ("without", [])):
        done = subprocess.run(
            [*argv, "--out", str(tmp_path / name), *extra],
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert done.returncode == 0, done.stderr
        results[name] = load_robot_result(tmp_path / name, 0)[0]["poses"]
        said = "robot 0: Foxglove view at ws://127.0.0.1:" in done.stderr
        assert said == (name == "with"), done.stderr
    assert np.array_equal(results["with"], results["without"])


def _free_ports(count: int) -> int:
    """A loopback port with ``count`` free ports from it."""
    import socket

    for _ in range(100):
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            base = s.getsockname()[1]
        if base + count > 65536:
            continue
        taken = []
        try:
            for k in range(count):
                t = socket.socket()
                taken.append(t)
                t.bind(("127.0.0.1", base + k))
            return base
        except OSError:
            continue
        finally:
            for t in taken:
                t.close()
    raise RuntimeError("no free loopback ports")


def test_team_launch_foxglove_puts_robot_i_on_base_port_plus_i(tmp_path):
    """``teamslam team launch --foxglove HOST:BASE``: robot i serves its view on BASE + i (said
    by the command and in the robot's log), the estimates those of the run without it; a base
    whose robots' ports go past 65535 is one line, exit 2."""
    import os
    import subprocess
    import sys

    from teamslam.datasets import save_dataset
    from teamslam.runtime.agent_process import load_robot_result
    from teamslam.runtime.team_file import write_team_file
    from teamslam.sim import lissajous_team

    dataset = save_dataset(lissajous_team(robots=2, steps=20, seed=3), tmp_path / "team2")
    port = 13600 + (os.getpid() % 100) * 4  # the robots' Zenoh ports (as above)
    team = write_team_file(tmp_path / "team.yaml", "views", dataset, ~np.eye(2, dtype=bool), port)
    argv = [sys.executable, "-m", "teamslam", "team", "launch", str(team)]
    base = _free_ports(2)
    runs = {}
    for name, extra in (("with", ["--foxglove", f"127.0.0.1:{base}"]), ("without", [])):
        done = subprocess.run(
            [*argv, "--out", str(tmp_path / name), *extra],
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert done.returncode == 0, done.stderr
        runs[name] = [load_robot_result(tmp_path / name, r)[0]["poses"] for r in (0, 1)]
        for r in (0, 1):
            said = f"robot {r}: Foxglove view at ws://127.0.0.1:{base + r}"
            assert (said in done.stdout) == (name == "with"), done.stdout
            log = (tmp_path / name / f"robot_{r}.log").read_text()
            assert (said in log) == (name == "with"), log
    for with_view, without in zip(runs["with"], runs["without"], strict=True):
        assert np.array_equal(with_view, without)
    done = subprocess.run(
        [*argv, "--out", str(tmp_path / "bad"), "--foxglove", "65535"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and "past 65535" in done.stderr, done.stderr
    assert not (tmp_path / "bad").exists()


def test_the_camera_calibration_names_foxgloves_distortion_model_or_refuses_in_one_line():
    K, R, P = np.diag([500.0, 500.0, 1.0]), np.eye(3), np.hstack([np.eye(3), np.zeros((3, 1))])

    def model(d):
        return CameraModel((640, 480), K, np.asarray(d, float), R, P).distortion_model()

    assert model([]) == ("plumb_bob", [0.0] * 5)
    assert model([0.1, -0.2, 0.001, 0.002]) == ("plumb_bob", [0.1, -0.2, 0.001, 0.002, 0.0])
    assert model([0.1, -0.2, 0.001, 0.002, 0.03]) == ("plumb_bob", [0.1, -0.2, 0.001, 0.002, 0.03])
    eight = [0.1, -0.2, 0.001, 0.002, 0.03, 0.4, 0.05, 0.006]
    assert model(eight) == ("rational_polynomial", eight)
    assert model([*eight, 0, 0, 0, 0, 0, 0]) == ("rational_polynomial", eight)  # 14, no prism
    assert model([0.1, -0.2, 0.001, 0.002, 0.03, 0, 0, 0, 0, 0, 0, 0]) == (
        "plumb_bob", [0.1, -0.2, 0.001, 0.002, 0.03]
    )  # fmt: skip
    with pytest.raises(InputError, match="coefficient 9 is not zero"):
        model([*eight, 0.01, 0, 0, 0])  # a thin prism term: no Foxglove model
