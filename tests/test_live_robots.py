"""Three live robots on loopback (``teamslam agent --live``, one process each) follow a bag
played by ``teamslam bag play`` and publish their poses; lock-step, their estimates equal the
offline ``team launch`` of the same data bit for bit."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import yaml

pytest.importorskip("zenoh", reason="the network extra (zenoh) is not installed")
pytest.importorskip("rosbags", reason="the ros2 extra (rosbags) is not installed")

from teamslam.datasets import save_dataset
from teamslam.ros2.bags import RobotTopics, export_bag, import_bag
from teamslam.runtime.team_file import write_team_file
from teamslam.sim import lissajous_team

pytestmark = pytest.mark.network

DOMAIN = 23


def _port(offset: int) -> int:
    """Loopback ports 12000–12799, distinct per test process (offsets 0–7), below the
    ephemeral range (32768–60999 on Linux) where a listener on port 0 or an outgoing
    connection may hold one of them."""
    return 12000 + (os.getpid() % 100) * 8 + offset


def _teamslam(*args: str) -> list[str]:
    return [sys.executable, "-m", "teamslam", *args]


@pytest.fixture(scope="module")
def live_team(tmp_path_factory):
    """A 3-robot team's bag (odometry and observations), its import as the team's dataset and
    a lock-step team file whose ``ros2.inputs`` name the bag's topics."""
    tmp = tmp_path_factory.mktemp("live_team")
    team = lissajous_team(robots=3, steps=12, objects=60, seed=5)
    bag = tmp / "team.mcap"
    export_bag(team, bag, camera=tmp / "camera.json")
    robots = [RobotTopics(f"robot_{i}", f"/robot_{i}/odom") for i in range(3)]
    save_dataset(
        import_bag(bag, robots, "/{name}/stereo_observations", tmp / "camera.json"), tmp / "dataset"
    )
    path = write_team_file(
        tmp / "team.yaml", "live", tmp / "dataset", ~np.eye(3, dtype=bool), base_port=_port(0)
    )
    data = yaml.safe_load(path.read_text())
    data["timeout_s"] = 20.0
    # every noise level given: no calibration, the same settings offline and live
    data["settings"] = {"filter": {"feature_std": 1.0, "object_std": 2.0}}
    data["ros2"] = {
        "domain_id": DOMAIN,
        "connect": [f"tcp/127.0.0.1:{_port(4)}", f"tcp/127.0.0.1:{_port(5)}"],
        "listen": ["tcp/127.0.0.1:0"],
        "inputs": {
            "odometry": "/robot_{id}/odom",
            "observations": "/robot_{id}/stereo_observations",
        },
    }
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return tmp, bag, path


def test_three_live_robots_follow_a_played_bag_as_the_offline_team_does(live_team):
    import zenoh

    tmp, bag, team_file = live_team
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    offline = subprocess.run(
        _teamslam("team", "launch", str(team_file), "--out", str(tmp / "offline")),
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
    )
    assert offline.returncode == 0, offline.stderr
    # the poses the live robots publish, heard by a session of the test
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps("peer"))
    config.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{_port(5)}"]))
    config.insert_json5("scouting/multicast/enabled", "false")
    poses: dict[str, int] = {}
    lock = threading.Lock()

    def on_pose(sample) -> None:
        robot = str(sample.key_expr).split("/")[1]
        with lock:
            poses[robot] = poses.get(robot, 0) + 1

    with zenoh.open(config) as session:
        session.declare_subscriber(f"{DOMAIN}/*/pose/**", on_pose)
        robots = [
            subprocess.Popen(
                _teamslam(
                    "agent",
                    "--live",
                    "--team",
                    str(team_file),
                    "--robot",
                    str(i),
                    "--out",
                    str(tmp / "live"),
                    # the robot ends on the bag's frame count, not on a quiet spell: a loaded
                    # machine may deliver the last messages seconds after the player is gone
                    "--frames",
                    "13",
                    # a queue the whole bag fits in: a loaded machine may run a robot slower than
                    # the player, and a lock-step robot must drop nothing to equal the offline run
                    "--queue",
                    "13",
                    "--idle-timeout",
                    "60",
                ),
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
                env=env,
            )
            for i in range(3)
        ]
        try:
            topics = [f"/robot_{i}/{t}" for i in range(3) for t in ("odom", "stereo_observations")]
            play = subprocess.run(
                _teamslam(
                    "bag",
                    "play",
                    str(bag),
                    "--rate",
                    "4",
                    "--domain-id",
                    str(DOMAIN),
                    "--listen",
                    f"tcp/127.0.0.1:{_port(4)}",
                    "--wait-subscribers",
                    "3",
                    "--wait-timeout",
                    "60",
                    "--topics",
                    *topics,
                ),
                capture_output=True,
                text=True,
                timeout=120,
                env=env,
            )
            assert play.returncode == 0, play.stderr
            outputs = [r.communicate(timeout=120) for r in robots]
        finally:
            for r in robots:
                if r.poll() is None:
                    r.kill()
                    r.communicate()
        for r, (out, err) in zip(robots, outputs, strict=True):
            assert r.returncode == 0, err
            summary = json.loads(out.strip().splitlines()[-1])
            assert summary["frames"] == 13 and not any(summary["dropped"].values()), (summary, err)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            with lock:
                if all(poses.get(f"robot_{i}", 0) == 13 for i in range(3)):
                    break
            time.sleep(0.05)
    assert poses == {f"robot_{i}": 13 for i in range(3)}
    for i in range(3):
        with (
            np.load(tmp / "offline" / f"robot_{i}" / "result.npz") as a,
            np.load(tmp / "live" / f"robot_{i}" / "result.npz") as b,
        ):
            for key in a.files:
                if "frame_times" not in key:
                    assert np.array_equal(a[key], b[key]), (i, key)
        live = json.loads((tmp / "live" / f"robot_{i}" / "result.json").read_text())
        stats = live["extra"]["per_robot"][0]["live"]
        assert stats["frames"] == 13 and stats["latency_ms"]["p50"] > 0
