"""Live ROS 2 topics in, on loopback: the rmw_zenoh subscriber and ``teamslam bag play``.

Each test opens its Zenoh sessions on free loopback ports and waits on events with deadlines
(no assertion on how long anything took)."""

from __future__ import annotations

import json
import socket
import threading
import time

import numpy as np
import pytest

pytest.importorskip("zenoh", reason="the network extra is not installed")
pytest.importorskip("rosbags", reason="the ros2 extra is not installed")

from teamslam.ros2 import messages as m
from teamslam.ros2.live import Received, Ros2Subscriber
from teamslam.ros2.rmw_zenoh import (
    attachment,
    open_session,
    parse_liveliness_key,
    topic_key,
)

POSE = "geometry_msgs/msg/PoseStamped"
ODOM = "nav_msgs/msg/Odometry"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def listening_config(port: int):
    """A peer that listens on ``port`` of loopback and connects nowhere."""
    import zenoh

    config = zenoh.Config()
    config.insert_json5("mode", json.dumps("peer"))
    config.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    config.insert_json5("connect/endpoints", "[]")
    config.insert_json5("scouting/multicast/enabled", "false")
    return config


def wait_until(condition, timeout: float = 20.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.02)
    return condition()


class Collector:
    """Received items and error lines, thread-safe."""

    def __init__(self) -> None:
        self.items: list[Received] = []
        self.errors: list[str] = []
        self.lock = threading.Lock()

    def __call__(self, item: Received) -> None:
        with self.lock:
            self.items.append(item)

    def error(self, text: str) -> None:
        with self.lock:
            self.errors.append(text)


def test_subscriber_decodes_refuses_and_announces():
    port = free_port()
    got = Collector()
    topics = {"/r/pose": POSE, "/r/odom": ODOM}
    sub = Ros2Subscriber(
        topics,
        got,
        node="live_test",
        domain_id=3,
        config=listening_config(port),
        on_error=got.error,
    )
    tokens: list[str] = []
    pub = open_session([f"tcp/127.0.0.1:{port}"], ["tcp/127.0.0.1:0"])
    try:
        pub.liveliness().declare_subscriber(
            "@ros2_lv/3/**", lambda s: tokens.append(str(s.key_expr)), history=True
        )
        key = topic_key(3, "/r/pose", POSE)
        gid = bytes(range(16))
        probe = pub.declare_publisher(key)
        assert wait_until(lambda: probe.matching_status.matching), "no link to the subscriber"
        wrong_hash = key.rsplit("/", 1)[0] + "/RIHS01_" + "ab" * 32
        good = m.pose_stamped(np.eye(4), 1_000_000_123)
        pub.put(key, m.serialize(good), attachment=attachment(1, 42, gid))
        pub.put(key, b"\x00\x01\x00\x00\x07", attachment=attachment(2, 43, gid))
        for seq in (3, 4):  # refused twice, named once
            pub.put(wrong_hash, m.serialize(good), attachment=attachment(seq, 44, gid))
        pub.put(key, m.serialize(good))  # no attachment
        pub.put(key, m.serialize(good), attachment=attachment(6, 45, gid))
        assert wait_until(lambda: sub.errors["/r/pose"] == 4 and sub.counts["/r/pose"] == 2)
        assert wait_until(lambda: sum("/MS/" in t for t in tokens) == 2)
    finally:
        pub.close()
        sub.close()
    assert sub.counts == {"/r/pose": 2, "/r/odom": 0}
    assert sub.errors == {"/r/pose": 4, "/r/odom": 0}
    first, last = got.items
    assert (first.topic, first.msgtype, first.stamp_ns) == ("/r/pose", POSE, 1_000_000_123)
    assert (first.sequence_number, first.source_ns, first.gid) == (1, 42, gid)
    assert last.sequence_number == 6
    assert first.message.__msgtype__ == POSE
    assert first.message.header.frame_id == "world"
    assert len(got.errors) == 3 and all("\n" not in e for e in got.errors)
    assert "sample 2 of publisher" in got.errors[0] and "not a geometry_msgs" in got.errors[0]
    assert "type hash RIHS01_abab" in got.errors[1]
    assert "without rmw_zenoh's attachment" in got.errors[2]
    announced = [parse_liveliness_key(t) for t in tokens if "/MS/" in t]
    assert {(a["topic"], a["type_hash"]) for a in announced} == {
        (t, m.type_hash(mt)) for t, mt in topics.items()
    }
    assert {a["node"] for a in announced} == {"live_test"}
    assert any(t.endswith("/NN/%/%/live_test") for t in tokens)


def test_subscriber_refuses_bad_settings():
    from teamslam.errors import InputError

    with pytest.raises(InputError, match="not one teamslam knows"):
        Ros2Subscriber({"/a": "foo_msgs/msg/Bar"}, print)
    with pytest.raises(InputError, match="absolute ROS 2 topic"):
        Ros2Subscriber({"a/b": POSE}, print)
    with pytest.raises(InputError, match="at least one topic"):
        Ros2Subscriber({}, print)
