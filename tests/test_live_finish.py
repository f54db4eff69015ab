"""Two live robots over Zenoh on loopback, in one process: a robot whose input ended says it is
done and stays until its slower neighbour is done, so its last messages reach it."""

from __future__ import annotations

import os
import threading
import time

import numpy as np
import pytest

pytest.importorskip("zenoh", reason="the network extra (zenoh) is not installed")
pytest.importorskip("rosbags", reason="the ros2 extra (rosbags) is not installed")

from teamslam.live import LiveInputs, LiveRobot
from teamslam.msckf.configure import build_settings
from teamslam.ros2.bags import RobotTopics, export_bag, import_bag
from teamslam.runtime.team_file import RobotEntry, TeamFile
from teamslam.runtime.zenoh_transport import ZenohTransport
from teamslam.sim import lissajous_team
from test_runtime_live import Recorder, bag_messages

pytestmark = pytest.mark.network


def _port(offset: int) -> int:
    """Loopback ports 12800–13199, distinct per test process (offsets 0–3), below the
    ephemeral range."""
    return 12800 + (os.getpid() % 100) * 4 + offset


class _Finishing:
    """A transport whose ``finish`` notes when it was called and when it returned."""

    def __init__(self, transport: ZenohTransport, events: list) -> None:
        self._transport = transport
        self._events = events

    def __getattr__(self, name):
        return getattr(self._transport, name)

    def finish(self, timeout: float) -> set[int]:
        robot = self._transport.robot
        self._events.append(("done", robot))
        waiting = self._transport.finish(timeout)
        self._events.append(("closing", robot))
        return waiting


def test_a_live_robot_stays_until_its_slower_neighbour_is_done(tmp_path):
    team_data = lissajous_team(robots=2, steps=30, objects=60, seed=3)
    bag, camera = tmp_path / "team.mcap", tmp_path / "camera.json"
    export_bag(team_data, bag, camera=camera)
    dataset = import_bag(
        bag, [RobotTopics("robot_0", "/robot_0/odom")], "/robot_0/stereo_observations", camera
    )
    config = build_settings(dataset, calibrate="never").config
    team = TeamFile(
        team="finish",
        dataset=None,
        robots=[
            RobotEntry(0, f"tcp/127.0.0.1:{_port(0)}", [1]),
            RobotEntry(1, f"tcp/127.0.0.1:{_port(1)}", [0]),
        ],
        sync="async",
        timeout_s=30.0,
        max_age_s=3600.0,  # every message of the run is recent enough: none expires
        checkpoint_every=0,
    )
    events: list[tuple[str, int]] = []
    transports = [ZenohTransport(team, i) for i in range(2)]
    robots = []
    for i in range(2):
        inputs = LiveInputs(
            f"/robot_{i}/odom", observations=f"/robot_{i}/stereo_observations", queue=10_000
        )
        robots.append(
            LiveRobot(
                team,
                i,
                inputs,
                config,
                tmp_path / "out",
                calibration=dataset.calibration,
                transport=_Finishing(transports[i], events),
                publisher=Recorder(),
            )
        )
    messages = [
        bag_messages(bag, {f"/robot_{i}/odom", f"/robot_{i}/stereo_observations"}) for i in range(2)
    ]
    # robot 0 has its whole input at once; robot 1's comes a frame at a time while robot 0
    # is long done with its own
    for item in messages[0]:
        robots[0].feed(item)
    robots[0].finish()
    last_frame_of_0 = threading.Event()
    robots[0].publisher.publish = _noting(robots[0].publisher.publish, 30, last_frame_of_0)
    summaries: dict[int, dict] = {}
    threads = [
        threading.Thread(target=lambda i=i: summaries.setdefault(i, robots[i].run()), daemon=True)
        for i in range(2)
    ]
    for thread in threads:
        thread.start()
    assert last_frame_of_0.wait(60), "robot 0 did not process its input"
    for item in messages[1]:
        robots[1].feed(item)
        if item.topic.endswith("stereo_observations"):
            time.sleep(0.01)
    robots[1].finish()
    for thread in threads:
        thread.join(90)
    assert not any(thread.is_alive() for thread in threads)
    assert summaries[0]["frames"] == summaries[1]["frames"] == 31
    # robot 0 said it was done before robot 1 and closed only once robot 1 was done too
    assert events.index(("done", 0)) < events.index(("done", 1)) < events.index(("closing", 0))
    # robot 1 heard robot 0's last exchange: robot 0 was heard at each of robot 1's frames
    assert transports[1].newest_step[0] == 30
    assert summaries[1]["lost_neighbours"] == []
    assert summaries[1]["counters"].get("links_lost", 0) == 0
    assert np.isfinite(robots[1].driver.poses[:31]).all()


def _noting(publish, frame: int, event: threading.Event):
    """``publish`` that sets ``event`` once frame ``frame`` is published."""

    def noted(t, poses, state) -> None:
        publish(t, poses, state)
        if t == frame:
            event.set()

    return noted
