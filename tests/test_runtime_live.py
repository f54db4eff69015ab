"""One robot on live inputs (:mod:`teamslam.live`), fed the messages of a bag without
Zenoh: the estimates equal the offline import's, and faults are named, counted and survived."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags", reason="the ros2 extra (rosbags) is not installed")

from teamslam.live import LiveInputs, LiveRobot
from teamslam.msckf.agent import MsckfAgent
from teamslam.msckf.configure import build_settings
from teamslam.msckf.team import RobotDriver
from teamslam.ros2 import messages as m
from teamslam.ros2.bags import RobotTopics, export_bag, import_bag
from teamslam.ros2.live import Received
from teamslam.runtime.agent_process import load_robot_result
from teamslam.runtime.team_file import RobotEntry, TeamFile
from teamslam.sim import lissajous_team

ODOM, OBS = "/robot_0/odom", "/robot_0/stereo_observations"
TRUTH = "/robot_0/ground_truth"


def bag_messages(bag: Path, topics: set[str]) -> list[Received]:
    """The bag's messages on ``topics`` in recorded order, as a subscriber hands them over."""
    highlevel = m.rosbags("highlevel")
    out = []
    with highlevel.AnyReader([bag], default_typestore=m.typestore()) as reader:
        conns = [c for c in reader.connections if c.topic in topics]
        for conn, _, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            stamp = m.stamp_ns(msg.header.stamp)
            out.append(Received(conn.topic, conn.msgtype, stamp, msg, time.monotonic_ns()))
    return out


def one_robot_team(**fields) -> TeamFile:
    return TeamFile(
        team="live", dataset=None, robots=[RobotEntry(0, "tcp/127.0.0.1:0", [])], **fields
    )


def offline_poses(sequence, calibration, config) -> np.ndarray:
    driver = RobotDriver(MsckfAgent(0, calibration, sequence, config), None, [], consensus=False)
    for t in range(sequence.frames):
        driver.frame(t)
    return driver.poses[: driver.done]


class Recorder:
    """A publisher that keeps what it was given."""

    def __init__(self) -> None:
        self.frames: list[int] = []
        self.poses: list[np.ndarray] = []

    def publish(self, t, poses, state) -> None:
        self.frames.append(t)
        self.poses.append(poses[t].copy())


@pytest.fixture(scope="module")
def observations_bag(tmp_path_factory):
    """A 2-robot team exported as a bag of odometry and observations, and robot 0 imported."""
    tmp = tmp_path_factory.mktemp("observations")
    team = lissajous_team(robots=2, steps=40, objects=60, seed=3)
    bag, camera = tmp / "team.mcap", tmp / "camera.json"
    export_bag(team, bag, camera=camera)
    dataset = import_bag(bag, [RobotTopics("robot_0", ODOM)], OBS, camera)
    config = build_settings(dataset, calibrate="never").config
    return bag, dataset, config


def live_robot(tmp_path, dataset, config, say=None, **inputs) -> LiveRobot:
    inputs = {"odometry": ODOM, "observations": OBS, "queue": 10_000, **inputs}
    return LiveRobot(
        one_robot_team(checkpoint_every=5),
        0,
        LiveInputs(**inputs),
        config,
        tmp_path,
        calibration=dataset.calibration,
        publisher=Recorder(),
        say=say,
    )


@pytest.mark.parametrize("start", ["odometry", "ground truth"])
def test_observations_played_live_give_the_offline_estimates(observations_bag, tmp_path, start):
    bag, dataset, config = observations_bag
    topics = {ODOM, OBS}
    if start == "ground truth":  # the robot starts at the truth's pose, as the import does
        dataset = import_bag(
            bag, [RobotTopics("robot_0", ODOM, TRUTH)], OBS, bag.parent / "camera.json"
        )
        topics.add(TRUTH)
    robot = live_robot(tmp_path, dataset, config, ground_truth=TRUTH if TRUTH in topics else None)
    for item in bag_messages(bag, topics):
        robot.feed(item)
    robot.finish()
    summary = robot.run()
    arrays, _ = load_robot_result(tmp_path, 0)
    expected = offline_poses(dataset.robots[0], dataset.calibration, config)
    assert arrays["poses"].shape == expected.shape == (41, 4, 4)
    assert np.array_equal(arrays["poses"], expected)
    assert np.array_equal(np.stack(robot.publisher.poses), expected)
    live = summary["live"]
    assert live["frames"] == 41 and not any(live["dropped"].values())
    assert len(robot.latency_ns) == 41 and live["latency_ms"]["p50"] > 0
    # the process's CPU time from the first frame to the last: some, and within what it used
    assert 0 < live["cpu_seconds"] <= time.process_time()


def test_a_full_queue_drops_the_oldest_frames_and_the_pose_stays_continuous(
    observations_bag, tmp_path
):
    bag, dataset, config = observations_bag
    robot = live_robot(tmp_path, dataset, config, queue=3)
    items = bag_messages(bag, {ODOM, OBS})
    for item in items:
        robot.feed(item)
    robot.finish()
    summary = robot.run()
    # the first frame and the newest two waited; the others were dropped, oldest first
    assert summary["live"]["dropped"]["queue"] == 41 - 3
    stamps = [i.stamp_ns for i in items if i.topic == OBS]
    assert robot.sequence.stamps_ns[:3].tolist() == stamps[-3:]
    # the increment spans the dropped frames: odometry alone from the first kept frame
    odometry = {i.stamp_ns: m.pose_matrix(i.message.pose.pose) for i in items if i.topic == ODOM}
    first, last = odometry[stamps[-3]], odometry[stamps[-1]]
    arrays, _ = load_robot_result(tmp_path, 0)
    span = np.linalg.inv(arrays["poses"][0]) @ arrays["poses"][-1]
    np.testing.assert_allclose(span[:3, 3], (np.linalg.inv(first) @ last)[:3, 3], atol=0.05)


def test_a_camera_that_stops_is_said_once_and_the_robot_continues_on_odometry(
    observations_bag, tmp_path
):
    bag, dataset, config = observations_bag
    said: list[str] = []
    robot = live_robot(tmp_path, dataset, config, say=said.append, camera_timeout_s=1.5)
    items = bag_messages(bag, {ODOM, OBS})
    stamps = sorted({i.stamp_ns for i in items if i.topic == OBS})
    gap = (stamps[10], stamps[25])  # no observation in between (a second apart)
    for item in items:
        if item.topic == OBS and gap[0] < item.stamp_ns < gap[1]:
            continue
        robot.feed(item)
    robot.finish()
    summary = robot.run()
    stops = [s for s in said if "continuing on odometry" in s]
    returns = [s for s in said if "camera input again" in s]
    assert len(stops) == 1 and len(returns) == 1, said
    live = summary["live"]
    # odometry frames from the first odometry stamp past the timeout (12 s) to the camera's
    # return (25 s: its odometry came first, its observations then count as a gap's overlap)
    assert live["camera_gaps"] == 1
    assert live["odometry_frames"] == 14
    assert live["dropped"]["camera_gap"] == 1
    assert live["frames"] == 41 - 14 - 1 + live["odometry_frames"]
    # a pose published at every frame, continuous through the gap
    poses = np.stack(robot.publisher.poses)
    assert len(poses) == live["frames"]
    steps = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
    assert steps.max() < 3 * np.median(steps)


def test_a_stamp_jumping_back_is_named_and_its_frame_refused(observations_bag, tmp_path):
    bag, dataset, config = observations_bag
    said: list[str] = []
    robot = live_robot(tmp_path, dataset, config, say=said.append)
    items = bag_messages(bag, {ODOM, OBS})
    observations = [i for i in items if i.topic == OBS]
    for item in items:
        robot.feed(item)
        if item is observations[20]:
            robot.feed(dataclasses.replace(observations[5], received_ns=time.monotonic_ns()))
    robot.finish()
    summary = robot.run()
    assert summary["live"]["refused_stamps"] == {OBS: 1}
    assert [s for s in said if "jumped back" in s and OBS in s]
    arrays, _ = load_robot_result(tmp_path, 0)
    expected = offline_poses(dataset.robots[0], dataset.calibration, config)
    assert np.array_equal(arrays["poses"], expected)


def test_a_malformed_observation_message_is_counted_and_named(observations_bag, tmp_path):
    bag, dataset, config = observations_bag
    said: list[str] = []
    robot = live_robot(tmp_path, dataset, config, say=said.append)
    items = bag_messages(bag, {ODOM, OBS})
    observations = [i for i in items if i.topic == OBS]
    bad = observations[7]
    broken = dataclasses.replace(bad.message, kinds=np.zeros(3, np.uint8))
    for item in items:
        robot.feed(dataclasses.replace(item, message=broken) if item is bad else item)
    robot.finish()
    summary = robot.run()
    assert summary["live"]["dropped"]["frontend"] == 1
    assert summary["live"]["frames"] == 40
    assert [s for s in said if "different lengths" in s and str(bad.stamp_ns) in s]


def test_a_restarted_robot_resumes_from_its_checkpoint(observations_bag, tmp_path):
    bag, dataset, config = observations_bag
    items = bag_messages(bag, {ODOM, OBS})
    first = live_robot(tmp_path, dataset, config)
    for item in items:
        first.feed(item)
    first.finish()
    first.run(frames=12)  # stopped after frame 11; its checkpoint holds frames 0..9
    stamps = [i.stamp_ns for i in items if i.topic == OBS]
    again = live_robot(tmp_path, dataset, config)
    assert again.resume() == 10
    # the restarted robot hears the topics from frame 10 on (and the odometry of frame 9)
    for item in items:
        if item.stamp_ns >= stamps[9]:
            again.feed(item)
    again.finish()
    summary = again.run()
    assert summary["frames"] == 41
    arrays, _ = load_robot_result(tmp_path, 0)
    expected = offline_poses(dataset.robots[0], dataset.calibration, config)
    assert np.array_equal(arrays["poses"], expected)


LEFT, RIGHT = "/robot_0/left/image_raw", "/robot_0/right/image_raw"
INFO = ("/robot_0/left/camera_info", "/robot_0/right/camera_info")


@pytest.fixture(scope="module")
def image_bag(tmp_path_factory):
    """A rendered robot's stereo images as a bag, and the offline import of it."""
    pytest.importorskip("cv2", reason="the images extra (OpenCV) is not installed")
    from teamslam.datasets.images import rendered_team_inputs
    from teamslam.ros2.image_bags import ImageTopics, dataset_from_bag, images_to_bag
    from teamslam.sim.render import RenderConfig, render_team

    tmp = tmp_path_factory.mktemp("images")
    config = {"image_size": (320, 240), "focal": 210.0, "marker_size": 0.9, "steps": 12}
    render_team(RenderConfig(**config, robots=2), tmp / "rendered")
    inputs = rendered_team_inputs(tmp / "rendered", boxes=False)
    bag = tmp / "images.mcap"
    images_to_bag(
        inputs["left_dirs"][:1],
        inputs["right_dirs"][:1],
        inputs["camera"],
        inputs["timestamps"][:1],
        bag,
        odometry=inputs["odometry"][:1],
        ground_truth=inputs["ground_truth"][:1],
        robot_names=["robot_0"],
    )
    dataset = dataset_from_bag(bag, [ImageTopics.default("robot_0")], progress=False)
    settings = build_settings(dataset, calibrate="never").config
    return bag, dataset, settings


def image_robot(tmp_path, config, say=None, checkpoint_every=0) -> LiveRobot:
    inputs = LiveInputs(
        ODOM, left=LEFT, right=RIGHT, camera_info=INFO, queue=10_000, ground_truth=TRUTH
    )
    team = one_robot_team(checkpoint_every=checkpoint_every)
    return LiveRobot(team, 0, inputs, config, tmp_path, publisher=Recorder(), say=say)


def test_images_played_live_give_the_offline_estimates(image_bag, tmp_path):
    bag, dataset, config = image_bag
    robot = image_robot(tmp_path, config)
    for item in bag_messages(bag, {ODOM, LEFT, RIGHT, TRUTH, *INFO}):
        robot.feed(item)
    robot.finish()
    summary = robot.run()
    assert summary["live"]["frames"] == 13
    assert not np.array_equal(robot.sequence.T_world_body[0], np.eye(4))  # the truth's start
    arrays, _ = load_robot_result(tmp_path, 0)
    expected = offline_poses(dataset.robots[0], dataset.calibration, config)
    assert np.array_equal(arrays["poses"], expected)


def test_a_restarted_image_robot_resumes_its_feature_tracks_bit_for_bit(image_bag, tmp_path):
    """An image robot stopped after a checkpoint and restarted from it continues the front-end's
    feature tracks (ids, positions, templates, the last image) where the checkpoint left them:
    the same estimate as the uninterrupted run, bit for bit."""
    bag, dataset, config = image_bag
    items = bag_messages(bag, {ODOM, LEFT, RIGHT, TRUTH, *INFO})
    first = image_robot(tmp_path, config, checkpoint_every=5)
    for item in items:
        first.feed(item)
    first.finish()
    first.run(frames=8)  # stopped after frame 7; its checkpoint holds frames 0..4
    tracks = first.frontend.tracker.ids
    with np.load(tmp_path / "robot_0" / "checkpoint.npz") as checkpoint:
        held = checkpoint["live_frontend_tracker_ids"]
        assert checkpoint["live_frontend_tracker_previous"].shape == (240, 320)
    assert held.size > 20 and np.isin(held, tracks).any()  # tracks that outlived frame 4
    stamps = [i.stamp_ns for i in items if i.topic == LEFT]
    again = image_robot(tmp_path, config, checkpoint_every=5)
    assert again.resume() == 5
    assert np.array_equal(again.frontend.tracker.ids, held)
    for item in items:  # the topics from frame 5 on (and what is stamped as frame 4)
        if item.stamp_ns >= stamps[4]:
            again.feed(item)
    again.finish()
    summary = again.run()
    assert summary["frames"] == 13
    arrays, _ = load_robot_result(tmp_path, 0)
    expected = offline_poses(dataset.robots[0], dataset.calibration, config)
    assert np.array_equal(arrays["poses"], expected)


@pytest.fixture(scope="module")
def detection_bag(tmp_path_factory):
    """A rendered robot's stereo images and a simulated detector's boxes (a
    ``Detection2DArray`` per left image) as a bag, and the offline import of it."""
    pytest.importorskip("cv2", reason="the images extra (OpenCV) is not installed")
    from teamslam.datasets.images import rendered_team_inputs
    from teamslam.ros2.image_bags import ImageTopics, dataset_from_bag, images_to_bag
    from teamslam.sim.detector import DetectorConfig
    from teamslam.sim.render import RenderConfig, render_team

    tmp = tmp_path_factory.mktemp("detections")
    config = RenderConfig(
        image_size=(320, 240),
        focal=210.0,
        layout="street",
        objects="shapes",
        robots=1,
        steps=16,
        markers_per_wall=0,
    )
    render_team(config, tmp / "rendered", detector=DetectorConfig())
    inputs = rendered_team_inputs(tmp / "rendered")
    bag = tmp / "boxes.mcap"
    images_to_bag(
        inputs["left_dirs"],
        inputs["right_dirs"],
        inputs["camera"],
        inputs["timestamps"],
        bag,
        odometry=inputs["odometry"],
        ground_truth=inputs["ground_truth"],
        robot_names=["robot_0"],
        detections=inputs["detections"],
    )
    topics = dataclasses.replace(ImageTopics.default("robot_0"), detections=BOXES)
    dataset = dataset_from_bag(bag, [topics], progress=False)
    settings = build_settings(dataset, calibrate="never").config
    return bag, dataset, settings


BOXES = "/robot_0/detections"


def test_detections_played_live_give_the_offline_estimates(detection_bag, tmp_path):
    """``agent --live --detections TOPIC``: each pair with the boxes of its stamp, measured
    and tracked as after ``data import-bag --images … --detections TOPIC``."""
    bag, dataset, config = detection_bag
    offline = dataset.robots[0].detections
    assert offline is not None and offline.measurements.shape[0] > 20  # boxes to track
    inputs = LiveInputs(
        ODOM,
        left=LEFT,
        right=RIGHT,
        camera_info=INFO,
        queue=10_000,
        ground_truth=TRUTH,
        detections=BOXES,
    )
    team = one_robot_team(checkpoint_every=0)
    robot = LiveRobot(team, 0, inputs, config, tmp_path, publisher=Recorder())
    items = bag_messages(bag, {ODOM, LEFT, RIGHT, TRUTH, BOXES, *INFO})
    # a detector answers after its image: each message of boxes comes after the next pair
    boxes = [i for i in items if i.topic == BOXES]
    others = [i for i in items if i.topic != BOXES]
    pairs = [k for k, i in enumerate(others) if i.topic == RIGHT]
    order = []
    for k, item in enumerate(others):
        order.append(item)
        if k in pairs[1:]:
            order.append(boxes.pop(0))
    order += boxes
    for item in order:
        robot.feed(item)
    robot.finish()
    summary = robot.run()
    frames = dataset.robots[0].frames
    assert summary["live"]["frames"] == frames
    assert robot.driver.agent.tracker is not None
    expected_driver_poses = offline_poses(dataset.robots[0], dataset.calibration, config)
    arrays, _ = load_robot_result(tmp_path, 0)
    assert np.array_equal(arrays["poses"], expected_driver_poses)
    assert summary["tracking_hypotheses"] == offline_hypotheses(dataset, config)


def offline_hypotheses(dataset, config) -> list[int]:
    sequence = dataset.robots[0]
    driver = RobotDriver(MsckfAgent(0, dataset.calibration, sequence, config), None, [], False)
    for t in range(sequence.frames):
        driver.frame(t)
    return driver.tracking()


def test_a_wrongly_encoded_image_is_counted_and_named(image_bag, tmp_path):
    bag, _, config = image_bag
    said: list[str] = []
    robot = image_robot(tmp_path, config, say=said.append)
    items = bag_messages(bag, {ODOM, LEFT, RIGHT, TRUTH, *INFO})
    bad = [i for i in items if i.topic == RIGHT][4]
    for item in items:
        if item is bad:
            item = dataclasses.replace(
                item, message=dataclasses.replace(item.message, encoding="yuv422")
            )
        robot.feed(item)
    robot.finish()
    summary = robot.run()
    assert summary["live"]["dropped"]["frontend"] == 1
    assert summary["live"]["frames"] == 12
    assert [s for s in said if "yuv422" in s and RIGHT in s]


def test_a_stage_over_the_realtime_budget_is_said_once_by_name(observations_bag, tmp_path):
    bag, dataset, config = observations_bag
    said: list[str] = []
    robot = live_robot(tmp_path, dataset, config, say=said.append)
    robot.budget_ms = 1e-6  # every stage overruns it
    for item in bag_messages(bag, {ODOM, OBS}):
        robot.feed(item)
    robot.finish()
    summary = robot.run()
    for stage in ("frontend", "filter", "publish"):
        lines = [s for s in said if s.startswith(f"robot 0: {stage} took")]
        assert len(lines) == 1 and "real-time budget" in lines[0], said
        assert summary["live"]["budget_overruns"][stage] == 41


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--odometry", "/robot_0/odom"], "--odometry needs --live"),
        (["--live", "--foxglove", "localhost:http"], "expected [HOST:]PORT"),
        (["--live", "--foxglove", "70000"], "a port in 0..65535, got '70000'"),
        (["--live"], "give the odometry topic"),
        (["--live", "--odometry", "/robot_0/odom"], "need a camera file"),
        (["--live", "--odometry", "robot 0"], "not an absolute ROS 2 topic name"),
        (["--live", "--odometry", "/o", "--left", "/l", "--right", "/r"], "camera_info"),
        (
            [
                "--live",
                "--odometry",
                "/o",
                "--observations",
                "/s",
                "--camera",
                "c",
                "--detections",
                "/d",
            ],
            "need images",
        ),
    ],
)
def test_bad_live_arguments_give_one_line_and_exit_2(tmp_path, args, message):
    import subprocess
    import sys

    from teamslam.runtime.team_file import write_team_file

    team = write_team_file(tmp_path / "team.yaml", "t", tmp_path, np.zeros((1, 1), bool))
    text = team.read_text().replace(f"dataset: {tmp_path.resolve()}\n", "")
    team.write_text(text)
    argv = [sys.executable, "-m", "teamslam", "agent", "--team", str(team), "--robot", "0"]
    done = subprocess.run(
        [*argv, "--out", str(tmp_path / "out"), *args], capture_output=True, text=True
    )
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], done.stderr


def test_an_increment_over_dropped_frames_carries_their_steps_noise(observations_bag, tmp_path):
    bag, dataset, config = observations_bag
    robot = live_robot(tmp_path, dataset, config, queue=3)
    items = bag_messages(bag, {ODOM, OBS})
    first = min(i.stamp_ns for i in items)
    for item in items:
        if item.stamp_ns == first:
            robot.feed(item)
    robot.run(frames=1)  # frame 0 done; then the robot falls behind by 37 frames
    for item in items:
        if item.stamp_ns > first:
            robot.feed(item)
    robot.finish()
    summary = robot.run()
    assert summary["live"]["dropped"]["queue"] == 37
    # frames 0, 38, 39, 40: the first increment spans 38 frames, and has 38 steps' noise
    assert robot.sequence.odometry_spans.tolist() == [38.0, 1.0, 1.0]


def test_the_robot_starts_at_the_truth_of_the_first_frame_it_processes(observations_bag, tmp_path):
    bag, dataset, config = observations_bag
    robot = live_robot(tmp_path, dataset, config, queue=3, ground_truth=TRUTH)
    items = bag_messages(bag, {ODOM, OBS, TRUTH})
    for item in items:
        robot.feed(item)
    robot.finish()
    robot.run()
    # frames 0..37 were dropped before the filter started: it starts at frame 38's truth
    first = robot.sequence.stamps_ns[0]
    truth = [
        m.pose_matrix(i.message.pose) for i in items if i.topic == TRUTH and i.stamp_ns == first
    ]
    assert first == sorted(i.stamp_ns for i in items if i.topic == OBS)[-3]
    assert np.array_equal(robot.sequence.T_world_body[0], truth[0])


def test_live_class_labels_are_those_of_a_whole_topic_or_refused():
    from teamslam.errors import InputError
    from teamslam.ros2.detection_bags import LiveClassTable, class_table

    for ids in (["3", "0", "3", "12"], ["car", "person", "car", "bike"]):
        table = LiveClassTable()
        assert [table.label(i, "here") for i in ids] == [class_table(ids)[i] for i in ids]
    table = LiveClassTable()
    table.label("car", "here")
    with pytest.raises(InputError, match="here: class id '7' mixes numbers and names"):
        table.label("7", "here")
    # a checkpoint's table: a resumed robot gives every name seen before the same label, and
    # numbers the names it sees next on from them
    for ids in (["car", "person"], ["3", "12"]):
        table = LiveClassTable()
        labels = [table.label(i, "here") for i in ids]
        again = LiveClassTable.from_state(table.state_dict())
        assert [again.label(i, "here") for i in reversed(ids)] == labels[::-1]
    again = LiveClassTable.from_state(
        LiveClassTable.from_state({"names": np.array(["car", "person"])}).state_dict()
    )
    assert again.label("bike", "here") == 2 and again.label("car", "here") == 0


def test_a_live_robot_s_detections_read_as_a_dataset_s_do():
    """The tracker and the association read a live robot's detections as a dataset's: per
    frame its boxes, and the classes and sizes of the frames kept (the association's summaries
    carry each object's class where the detections have classes; live boxes always do)."""
    from teamslam.live import LiveSequence

    sequence = LiveSequence(np.eye(4), detections=True)
    boxes = sequence.detections
    assert boxes.classes.size == 0 and boxes.sizes.shape == (0, 2)
    z = np.array([[300.0, 200.0, 280.0, 200.0], [100.0, 50.0, 90.0, 50.0]])
    boxes.add(0, z, np.array([2, 0]), np.ones((2, 3)), np.array([[20.0, 30.0], [8.0, 9.0]]))
    boxes.add(1, z[:1], np.array([2]), np.ones((1, 3)), np.array([[21.0, 31.0]]))
    np.testing.assert_array_equal(boxes.frame(1)[1], [2])
    np.testing.assert_array_equal(boxes.classes, [2, 0, 2])
    assert boxes.classes.dtype == np.int64 and boxes.sizes.shape == (3, 2)
