"""Live ROS 2 topics over rmw_zenoh's layout, received by a plain Zenoh subscriber on loopback."""

from __future__ import annotations

import json
import os
import struct
import threading
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from teamslam.datasets import save_dataset
from teamslam.errors import InputError
from teamslam.ros2 import messages as m
from teamslam.ros2.rmw_zenoh import (
    Ros2Publisher,
    attachment,
    liveliness_key,
    parse_attachment,
    publisher_gid,
    topic_key,
)
from teamslam.runtime.agent_process import load_robot_result, run_agent
from teamslam.runtime.team_file import load_team_file, write_team_file
from teamslam.sim import lissajous_team

POSE_STAMPED_HASH = "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8"


def _port(offset: int) -> int:
    """Loopback ports 31000–32199 (other tests use lower ones), distinct per test (0–7)."""
    return 31000 + (os.getpid() % 150) * 8 + offset


def _decoder(msgtype: str):
    """A CDR decoder independent of the publishing side: mcap-ros2's, from the schema text."""
    from mcap.records import Schema
    from mcap_ros2.decoder import DecoderFactory

    text, _ = m.typestore().generate_msgdef(msgtype, ros_version=2)
    schema = Schema(id=1, name=msgtype, encoding="ros2msg", data=text.encode())
    return DecoderFactory().decoder_for("cdr", schema)


def test_key_expressions_and_attachment_layout():
    key = topic_key(0, "/chatter", "std_msgs/msg/String")
    # the design document's own example
    assert key == (
        "0/chatter/std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
    )
    token = liveliness_key(
        2,
        "8b20917502ee955ac4476e0266340d5c",
        0,
        "talker",
        10,
        "/chatter",
        "std_msgs/msg/String",
        qos="::,7:,:,:,,",
    )
    assert token == (
        "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
        "std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,7:,:,:,,"
    )
    gid = bytes(range(16))
    raw = attachment(42, 1_700_000_000_123_456_789, gid)
    assert raw == struct.pack("<qqB", 42, 1_700_000_000_123_456_789, 16) + gid
    assert parse_attachment(raw) == (42, 1_700_000_000_123_456_789, gid)
    with pytest.raises(InputError, match="33 bytes"):
        parse_attachment(raw[:-1])


@pytest.fixture(scope="module")
def one_robot_team(tmp_path_factory):
    directory = tmp_path_factory.mktemp("live")
    dataset = lissajous_team(robots=1, steps=10, objects=40, seed=2)
    save_dataset(dataset, directory / "data")
    team_path = write_team_file(
        directory / "team.yaml",
        f"live-{os.getpid()}",
        directory / "data",
        np.zeros((1, 1)),
        base_port=_port(2),
        settings={"filter.window": 6},
    )
    return dataset, load_team_file(team_path), directory


def test_robot_process_publishes_decodable_ros2_samples(one_robot_team):
    import zenoh

    dataset, team, directory = one_robot_team
    domain = 7
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps("peer"))
    config.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{_port(0)}"]))
    config.insert_json5("scouting/multicast/enabled", "false")
    samples: list[tuple[str, bytes, bytes | None]] = []
    tokens: list[tuple[str, str]] = []
    lock = threading.Lock()

    def on_sample(sample):
        with lock:
            att = sample.attachment.to_bytes() if sample.attachment is not None else None
            samples.append((str(sample.key_expr), sample.payload.to_bytes(), att))

    def on_token(sample):
        with lock:
            kind = "PUT" if sample.kind == zenoh.SampleKind.PUT else "DELETE"
            tokens.append((str(sample.key_expr), kind))

    frames = dataset.robots[0].frames
    stamps = np.rint(dataset.robots[0].timestamps * 1e9).astype(np.int64)
    with zenoh.open(config) as session:
        session.declare_subscriber(f"{domain}/**", on_sample)
        session.liveliness().declare_subscriber(f"@ros2_lv/{domain}/**", on_token, history=True)
        publisher = Ros2Publisher(
            0,
            stamps,
            domain_id=domain,
            connect=[f"tcp/127.0.0.1:{_port(0)}"],
            listen=[f"tcp/127.0.0.1:{_port(1)}"],
            path_every=1,
            objects_every=1,
        )
        try:
            assert publisher.wait_for_subscribers(10.0), "no Zenoh link to the test subscriber"
            began = time.time_ns()
            run_agent(team, 0, directory / "out", publisher=publisher)
            ended = time.time_ns()
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline:
                with lock:
                    if (
                        sum(k.startswith(f"{domain}/robot_0/pose/") for k, _, _ in samples)
                        >= frames
                    ):
                        break
                time.sleep(0.05)
            keys = publisher.keys
            gids = {name: publisher.gid(name) for name in keys}
        finally:
            publisher.close()
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:
            with lock:
                if sum(kind == "DELETE" for _, kind in tokens) >= 5:
                    break
            time.sleep(0.05)
    arrays, _ = load_robot_result(directory / "out", 0)

    assert keys["pose"] == (
        f"{domain}/robot_0/pose/geometry_msgs::msg::dds_::PoseStamped_/{POSE_STAMPED_HASH}"
    )
    by_topic: dict[str, list] = {}
    for key, payload, att in samples:
        assert payload[:4] == b"\x00\x01\x00\x00", "CDR little-endian encapsulation header"
        assert att is not None and len(att) == 33
        by_topic.setdefault(key, []).append((payload, parse_attachment(att)))
    assert set(by_topic) == set(keys.values())

    # pose: one sample per frame, the filter's poses and the dataset's stamps
    decode_pose = _decoder("geometry_msgs/msg/PoseStamped")
    poses = by_topic[keys["pose"]]
    assert len(poses) == frames
    for k, (payload, (seq, source_ns, gid)) in enumerate(poses):
        msg = decode_pose(payload)
        assert seq == k + 1
        assert began <= source_ns <= ended
        assert gid == gids["pose"]
        assert msg.header.frame_id == "world"
        assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == stamps[k]
        p = msg.pose.position
        assert (p.x, p.y, p.z) == tuple(arrays["poses"][k][:3, 3])
        q = msg.pose.orientation
        R = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
        np.testing.assert_allclose(R, arrays["poses"][k][:3, :3], atol=1e-12)

    # tf: world → the robot's base every frame, the pose's transform
    transforms = [_decoder("tf2_msgs/msg/TFMessage")(p) for p, _ in by_topic[keys["tf"]]]
    assert len(transforms) == frames
    for k, msg in enumerate(transforms):
        (tf,) = msg.transforms
        assert (tf.header.frame_id, tf.child_frame_id) == ("world", "robot_0/base_link")
        assert tf.header.stamp.sec * 10**9 + tf.header.stamp.nanosec == stamps[k]
        v = tf.transform.translation
        assert (v.x, v.y, v.z) == tuple(arrays["poses"][k][:3, 3])

    # path: the whole trajectory at the last frame
    last_path = _decoder("nav_msgs/msg/Path")(by_topic[keys["path"]][-1][0])
    assert [ps.pose.position.z for ps in last_path.poses] == list(arrays["poses"][:, 2, 3])

    # objects: the final map, a sphere and a 3σ ellipsoid per object
    markers = _decoder("visualization_msgs/msg/MarkerArray")(by_topic[keys["objects"]][-1][0])
    spheres = [mk for mk in markers.markers if mk.ns == "objects"]
    assert [mk.id for mk in spheres] == list(arrays["object_ids"])
    assert [mk.pose.position.x for mk in spheres] == list(arrays["objects"][:, 0])
    assert len(markers.markers) == 2 * len(spheres) > 0

    # liveliness: a node and four publishers, whose GIDs are the hashes of their tokens
    put = [key for key, kind in tokens if kind == "PUT"]
    assert sum("/NN/%/%/teamslam_robot_0" in key for key in put) == 1
    publishers = [key for key in put if "/MP/" in key]
    assert len(publishers) == 4
    for name, topic in (("pose", "%robot_0%pose"), ("path", "%robot_0%path")):
        (token,) = [key for key in publishers if f"/{topic}/" in key]
        assert token.startswith(f"@ros2_lv/{domain}/")
        assert token.endswith("/::,10:,:,:,,")
        assert publisher_gid(token) == gids[name]
    assert sum(kind == "DELETE" for _, kind in tokens) == 5, "tokens withdrawn on close"


def test_a_publisher_without_stamps_takes_each_frames_stamp():
    """A live robot's sequence grows while it runs: its publisher is given each frame's stamp
    (the frames of a resumed robot before its first one too)."""
    import zenoh

    config = zenoh.Config()
    config.insert_json5("mode", json.dumps("peer"))
    config.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{_port(7)}"]))
    config.insert_json5("scouting/multicast/enabled", "false")
    got: list[tuple[str, bytes]] = []
    lock = threading.Lock()

    def on_sample(sample):
        with lock:
            got.append((str(sample.key_expr), sample.payload.to_bytes()))

    class Map:  # a state with an empty map
        def full_map(self):
            return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3, 3))

    poses = np.tile(np.eye(4), (4, 1, 1))
    poses[:, 0, 3] = [0.0, 1.0, 2.0, 3.0]
    stamps = [5_000_000_000, 5_100_000_000, 5_300_000_000, 5_400_000_000]
    with zenoh.open(config) as session:
        session.declare_subscriber("9/**", on_sample)
        publisher = Ros2Publisher(
            3, None, domain_id=9, connect=[f"tcp/127.0.0.1:{_port(7)}"], path_every=2
        )
        try:
            assert publisher.wait_for_subscribers(10.0), "no Zenoh link to the test subscriber"
            with pytest.raises(ValueError, match="stamp"):
                publisher.publish(0, poses[:1], Map())
            publisher.stamp(0, stamps[0])  # frame 0 was done before a restart
            for k in (1, 2, 3):
                publisher.publish(k, poses[: k + 1], Map(), stamp_ns=stamps[k])
            assert publisher.stamps_ns.tolist() == stamps
            keys = publisher.keys
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline:
                with lock:
                    if sum(k == keys["tf"] for k, _ in got) >= 3:
                        break
                time.sleep(0.05)
        finally:
            publisher.close()
    with lock:
        by_topic = {name: [p for k, p in got if k == key] for name, key in keys.items()}

    def stamp(header) -> int:
        return header.stamp.sec * 10**9 + header.stamp.nanosec

    pose = _decoder("geometry_msgs/msg/PoseStamped")
    assert [stamp(pose(p).header) for p in by_topic["pose"]] == stamps[1:]
    tf = [_decoder("tf2_msgs/msg/TFMessage")(p).transforms[0] for p in by_topic["tf"]]
    assert [(stamp(t.header), t.child_frame_id) for t in tf] == [
        (s, "robot_3/base_link") for s in stamps[1:]
    ]
    assert [t.transform.translation.x for t in tf] == [1.0, 2.0, 3.0]
    # paths at frames 1 and 3 (every 2 frames), from frame 0 on
    paths = [_decoder("nav_msgs/msg/Path")(p).poses for p in by_topic["path"]]
    assert [[stamp(ps.header) for ps in path] for path in paths] == [stamps[:2], stamps]


def test_agent_command_with_a_ros2_team_file(one_robot_team, tmp_path):
    """``teamslam agent`` with a team file's ``ros2`` section publishes every frame."""
    import zenoh

    from teamslam.cli import main

    dataset, _, directory = one_robot_team
    text = (directory / "team.yaml").read_text()
    text = text.replace(f"live-{os.getpid()}", f"cli-{os.getpid()}")
    text = text.replace(f"127.0.0.1:{_port(2)}", f"127.0.0.1:{_port(5)}")
    ros2 = {
        "domain_id": 5,
        "connect": [f"tcp/127.0.0.1:{_port(4)}"],
        "listen": [f"tcp/127.0.0.1:{_port(6)}"],
        "wait_s": 10.0,
    }
    team_path = tmp_path / "team.yaml"
    team_path.write_text(text + f"ros2: {json.dumps(ros2)}\n")
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps("peer"))
    config.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{_port(4)}"]))
    config.insert_json5("scouting/multicast/enabled", "false")
    got: list[tuple[str, bytes]] = []
    frames = dataset.robots[0].frames
    with zenoh.open(config) as session:
        session.declare_subscriber(
            "5/**", lambda s: got.append((str(s.key_expr), s.attachment.to_bytes()))
        )
        assert (
            main(
                ["agent", "--team", str(team_path), "--robot", "0", "--out", str(tmp_path / "out")]
            )
            == 0
        )
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and sum("/pose/" in k for k, _ in got) < frames:
            time.sleep(0.05)
    pose_key = topic_key(5, "/robot_0/pose", "geometry_msgs/msg/PoseStamped")
    seqs = [parse_attachment(a)[0] for k, a in got if k == pose_key]
    assert seqs == list(range(1, frames + 1)), "every frame, none lost before the link formed"


def test_ros2_settings_are_checked():
    from teamslam.cli import build_parser
    from teamslam.ros2.rmw_zenoh import ros2_settings

    args = build_parser().parse_args(
        ["agent", "--team", "t.yaml", "--robot", "0", "--ros2", "--domain-id", "3"]
    )
    assert args.ros2 and args.domain_id == 3
    with pytest.raises(SystemExit):
        build_parser().parse_args(
            ["agent", "--team", "t.yaml", "--robot", "0", "--domain-id", "300"]
        )
    assert ros2_settings({"domain_id": 4}, domain_id=None)["domain_id"] == 4
    assert ros2_settings({"domain_id": 4}, domain_id=9)["domain_id"] == 9
    for bad, reason in (
        ({"domain": 1}, "unknown setting"),
        ({"domain_id": 233}, "domain_id"),
        ({"connect": "tcp/localhost:7447"}, "list of Zenoh endpoints"),
        ({"period": 0}, "period"),
        ({"path_every": 0}, "path_every"),
    ):
        with pytest.raises(InputError, match=reason):
            ros2_settings(bad)


def test_publisher_key_for_path_type():
    assert topic_key(0, "/robot_1/path", "nav_msgs/msg/Path").startswith(
        "0/robot_1/path/nav_msgs::msg::dds_::Path_/RIHS01_"
    )
