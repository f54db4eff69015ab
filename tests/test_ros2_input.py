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
        if item.stamp_ns == 13:  # a robot failing on one message
            raise ValueError("cannot use\nstamp 13")
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
        pub.put(key, m.serialize(m.pose_stamped(np.eye(4), 13)), attachment=attachment(7, 46, gid))
        assert wait_until(lambda: sub.errors["/r/pose"] == 5 and sub.counts["/r/pose"] == 3)
        assert wait_until(lambda: sum("/MS/" in t for t in tokens) == 2)
    finally:
        pub.close()
        sub.close()
    assert sub.counts == {"/r/pose": 3, "/r/odom": 0}
    assert sub.errors == {"/r/pose": 5, "/r/odom": 0}
    first, last = got.items
    assert (first.topic, first.msgtype, first.stamp_ns) == ("/r/pose", POSE, 1_000_000_123)
    assert (first.sequence_number, first.source_ns, first.gid) == (1, 42, gid)
    assert last.sequence_number == 6
    assert first.message.__msgtype__ == POSE
    assert first.message.header.frame_id == "world"
    assert len(got.errors) == 4 and all("\n" not in e for e in got.errors)
    assert "sample 2 of publisher" in got.errors[0] and "not a geometry_msgs" in got.errors[0]
    assert "type hash RIHS01_abab" in got.errors[1]
    assert "without rmw_zenoh's attachment" in got.errors[2]
    assert got.errors[3] == (
        "/r/pose: the callback failed on stamp 13 ns: ValueError: cannot use stamp 13"
    )
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


# ------------------------------------------------------------------------------ bag play
@pytest.fixture(scope="module")
def rendered_bag(tmp_path_factory):
    """A rendered 2-robot team's ``images.mcap`` (4 stereo frames, 96×72)."""
    pytest.importorskip("cv2", reason="the images extra (OpenCV) is not installed")
    from teamslam.api import simulate_images

    out = tmp_path_factory.mktemp("play") / "team"
    simulate_images(out, robots=2, steps=3, seed=5, progress=False, image_size=(96, 72))
    return out / "images.mcap"


def _recorded(bag) -> dict[str, list[tuple[int, object]]]:
    """Per topic its ``(log time, message)`` in order, as the bag reader gives them."""
    from rosbags.highlevel import AnyReader

    out: dict[str, list] = {}
    with AnyReader([bag], default_typestore=m.typestore()) as reader:
        for conn, log_ns, raw in reader.messages():
            out.setdefault(conn.topic, []).append((log_ns, reader.deserialize(raw, conn.msgtype)))
    return out


def assert_same_message(a, b, where: str = "") -> None:
    """Field by field, arrays compared element for element."""
    assert type(a).__name__ == type(b).__name__, where
    if hasattr(a, "__dataclass_fields__"):
        for name in a.__dataclass_fields__:
            assert_same_message(getattr(a, name), getattr(b, name), f"{where}.{name}")
    elif isinstance(a, np.ndarray):
        assert a.dtype == b.dtype, where
        np.testing.assert_array_equal(a, b, err_msg=where)
    elif isinstance(a, list):
        assert len(a) == len(b), where
        for k, (x, y) in enumerate(zip(a, b, strict=True)):
            assert_same_message(x, y, f"{where}[{k}]")
    else:
        assert a == b, where


def test_rendered_bag_holds_what_a_live_robot_needs(rendered_bag):
    from teamslam.ros2.bag_play import bag_topics

    topics = bag_topics(rendered_bag)
    for r in (0, 1):
        assert topics[f"/robot_{r}/left/image_raw"] == ("sensor_msgs/msg/Image", 4)
        assert topics[f"/robot_{r}/right/image_raw"] == ("sensor_msgs/msg/Image", 4)
        # with every pair, so a robot that starts late still gets its rig
        assert topics[f"/robot_{r}/left/camera_info"] == ("sensor_msgs/msg/CameraInfo", 4)
        assert topics[f"/robot_{r}/right/camera_info"] == ("sensor_msgs/msg/CameraInfo", 4)
        assert topics[f"/robot_{r}/odom"] == ("nav_msgs/msg/Odometry", 4)
        assert topics[f"/robot_{r}/ground_truth"] == ("geometry_msgs/msg/PoseStamped", 4)
    assert len(topics) == 12


def test_bag_play_delivers_every_message_once_in_order(rendered_bag):
    from teamslam.ros2.bag_play import bag_topics, play_bag

    port = free_port()
    recorded = _recorded(rendered_bag)
    topics = {t: mt for t, (mt, _) in bag_topics(rendered_bag).items()}
    got = Collector()
    import zenoh

    session = zenoh.open(listening_config(port))
    publishers: list[str] = []
    session.liveliness().declare_subscriber(
        "@ros2_lv/4/**", lambda s: publishers.append(str(s.key_expr)), history=True
    )
    sub = Ros2Subscriber(topics, got, domain_id=4, session=session, on_error=got.error)
    try:
        result = play_bag(
            rendered_bag,
            rate=0,
            domain_id=4,
            connect=[f"tcp/127.0.0.1:{port}"],
            listen=["tcp/127.0.0.1:0"],
            wait_subscribers=1,
            wait_timeout=20,
        )
        expected = {t: len(v) for t, v in recorded.items()}
        assert result.counts == expected and result.passes == 1 and not result.stopped
        assert wait_until(lambda: sub.counts == expected)
    finally:
        sub.close()
        session.close()
    assert got.errors == [] and sub.errors == dict.fromkeys(topics, 0)
    for topic, items in recorded.items():
        received = [x for x in got.items if x.topic == topic]
        assert [x.sequence_number for x in received] == list(range(1, len(items) + 1))
        assert {x.gid for x in received} == {result.gids[topic]}
        assert [x.source_ns for x in received] == [log_ns for log_ns, _ in items]
        for x, (log_ns, msg) in zip(received, items, strict=True):
            assert x.msgtype == topics[topic]
            assert x.stamp_ns == m.stamp_ns(msg.header.stamp) == log_ns
            assert_same_message(x.message, msg, f"{topic} at {log_ns}")
    # a node and a publisher per topic announced, as `ros2 topic list` reads them
    announced = [parse_liveliness_key(k) for k in publishers if "/MP/" in k]
    assert {a["topic"] for a in announced if a["node"] == "teamslam_bag_player"} == set(topics)
    assert any(k.endswith("/NN/%/%/teamslam_bag_player") for k in publishers)


def test_publisher_restart_and_a_topic_that_stops(rendered_bag):
    """The player restarted (a new session: new GIDs, sequence numbers from 1 again) keeps the
    subscriber receiving; a topic the restarted player no longer plays simply stops."""
    from teamslam.ros2.bag_play import bag_topics, play_bag

    port = free_port()
    topics = {t: mt for t, (mt, _) in bag_topics(rendered_bag).items() if "/robot_0/" in t}
    got = Collector()
    sub = Ros2Subscriber(topics, got, config=listening_config(port), on_error=got.error)
    common = {
        "rate": 0,
        "connect": [f"tcp/127.0.0.1:{port}"],
        "listen": ["tcp/127.0.0.1:0"],
        "wait_subscribers": 1,
        "wait_timeout": 20,
    }
    left, right = "/robot_0/left/image_raw", "/robot_0/right/image_raw"
    try:
        first = play_bag(rendered_bag, topics=list(topics), **common)
        assert wait_until(lambda: sub.counts == first.counts)
        second = play_bag(rendered_bag, topics=[t for t in topics if t != right], **common)
        assert wait_until(lambda: sub.counts[left] == 8)
        assert wait_until(lambda: sum(sub.counts.values()) == 2 * sum(first.counts.values()) - 4)
    finally:
        sub.close()
    assert got.errors == [] and sub.errors == dict.fromkeys(topics, 0)
    assert sub.counts[right] == 4, "the right images stopped with the first player"
    received = [x for x in got.items if x.topic == left]
    assert first.gids[left] != second.gids[left]
    assert [(x.gid, x.sequence_number) for x in received] == [
        (first.gids[left], k) for k in range(1, 5)
    ] + [(second.gids[left], k) for k in range(1, 5)]


def test_bag_play_schedule():
    from teamslam.errors import InputError
    from teamslam.ros2.bag_play import publish_time

    t0, start = 1_700_000_000_000_000_000, 5_000
    assert publish_time(t0, t0, start, 1.0) == start
    assert publish_time(t0 + 100_000_000, t0, start, 1.0) == start + 100_000_000
    assert publish_time(t0 + 100_000_000, t0, start, 0.25) == start + 400_000_000
    assert publish_time(t0 + 100_000_000, t0, start, 2.0) == start + 50_000_000
    assert publish_time(t0 + 1, t0, start, 3.0) == start  # rounded to the nanosecond
    assert publish_time(t0 + 2, t0, start, 3.0) == start + 1
    assert publish_time(t0 + 10**12, t0, start, 0.0) == start, "rate 0: no waiting"
    with pytest.raises(InputError, match="rate"):
        publish_time(t0, t0, start, -1.0)


def test_bag_play_waits_for_subscribers_then_gives_up(rendered_bag):
    from teamslam.errors import InputError
    from teamslam.ros2.bag_play import play_bag

    port = free_port()
    import zenoh

    with zenoh.open(listening_config(port)):  # a peer, but no subscriber
        with pytest.raises(InputError, match=r"waited 0.5 s for 1 subscribing node\(s\)"):
            play_bag(
                rendered_bag,
                rate=0,
                connect=[f"tcp/127.0.0.1:{port}"],
                listen=["tcp/127.0.0.1:0"],
                wait_subscribers=1,
                wait_timeout=0.5,
            )


def test_bag_play_loops_until_stopped(rendered_bag):
    """A loop plays the bag again (stamps going back at each pass, sequence numbers going on)
    until stopped from another thread — here by the subscriber, after two passes and one more
    message."""
    from teamslam.ros2.bag_play import play_bag

    topic = "/robot_0/odom"
    per_pass = len(_recorded(rendered_bag)[topic])
    stop = threading.Event()
    got = Collector()

    def on_item(item):
        got(item)
        if len(got.items) == 2 * per_pass + 1:
            stop.set()

    port = free_port()
    sub = Ros2Subscriber({topic: ODOM}, on_item, config=listening_config(port))
    try:
        result = play_bag(
            rendered_bag,
            rate=0,
            loop=True,
            topics=[topic],
            connect=[f"tcp/127.0.0.1:{port}"],
            listen=["tcp/127.0.0.1:0"],
            wait_subscribers=1,
            wait_timeout=20,
            stop=stop,
        )
        assert wait_until(lambda: sub.counts[topic] == result.counts[topic])
    finally:
        sub.close()
    assert result.stopped and result.passes >= 2
    assert result.counts[topic] > 2 * per_pass
    seqs = [x.sequence_number for x in got.items]
    assert seqs == list(range(1, len(seqs) + 1))
    stamps = [x.stamp_ns for x in got.items]
    assert stamps[per_pass : 2 * per_pass] == stamps[:per_pass]


#: how the process that starts ``teamslam bag play`` leaves SIGINT to it (exec keeps both an
#: ignored disposition and the signal mask): as a terminal does; ignored, as a shell without job
#: control does to a background job (``make test &``) or a launcher to its children; blocked
START_SIGINT = {
    "default": "",
    "ignored": "signal.signal(signal.SIGINT, signal.SIG_IGN); ",
    "blocked": "signal.pthread_sigmask(signal.SIG_BLOCK, [signal.SIGINT]); ",
}


@pytest.mark.parametrize("start", sorted(START_SIGINT))
def test_ctrl_c_stops_bag_play_cleanly(rendered_bag, start):
    """SIGINT to ``teamslam bag play --loop``: the counts, then exit status 130, no traceback —
    also when the command was started with SIGINT ignored or blocked (it would play forever)."""
    import os
    import signal
    import subprocess
    import sys

    from teamslam.ros2.bag_play import bag_topics

    port = free_port()
    starter = (
        f"import os, signal, sys; {START_SIGINT[start]}"
        "os.execv(sys.executable, [sys.executable, '-m', 'teamslam', *sys.argv[1:]])"
    )
    argv = [sys.executable, "-c", starter, "bag", "play", str(rendered_bag), "--loop"]
    argv += ["--connect", f"tcp/127.0.0.1:{port}", "--listen", "tcp/127.0.0.1:0"]
    proc = subprocess.Popen(
        argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=os.environ.copy()
    )
    try:
        first = proc.stdout.readline()
        topics = len(bag_topics(rendered_bag))
        assert first.startswith(f"playing {topics} topic(s)"), first + proc.stderr.read()
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    assert "stopped after" in out and "/robot_0/odom:" in out


def test_bag_play_command_errors(tmp_path, capsys):
    from teamslam.cli import main

    (tmp_path / "bad.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 64)
    for argv, message in (
        (["bag", "play", str(tmp_path / "none.mcap")], "no such bag"),
        (["bag", "play", str(tmp_path / "bad.mcap")], "cannot read the bag"),
    ):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1
    with pytest.raises(SystemExit) as exc:
        main(["bag", "play", "x.mcap", "--rate", "-1"])
    assert exc.value.code == 2


def test_bag_play_command(rendered_bag, capsys):
    import zenoh

    from teamslam.cli import main
    from teamslam.ros2.bag_play import bag_topics

    port = free_port()
    with zenoh.open(listening_config(port)):
        argv = ["bag", "play", str(rendered_bag), "--as-fast-as-possible", "--domain-id", "9"]
        argv += ["--topics", "/robot_1/odom", "/robot_1/left/image_raw"]
        argv += ["--connect", f"tcp/127.0.0.1:{port}", "--listen", "tcp/127.0.0.1:0"]
        assert main(argv) == 0
    out = capsys.readouterr().out
    counts = bag_topics(rendered_bag)
    n = counts["/robot_1/odom"][1] + counts["/robot_1/left/image_raw"][1]
    assert "playing 2 topic(s)" in out and "as fast as possible, domain 9" in out
    assert f"/robot_1/odom: {counts['/robot_1/odom'][1]} message(s)" in out
    assert f"published {n} message(s) in 1 pass(es)" in out
