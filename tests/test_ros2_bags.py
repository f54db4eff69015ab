"""Team bags in and out: the round trip, the schema we ship, stamps, and clear errors."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from teamslam.cli import main
from teamslam.datasets import load_dataset
from teamslam.errors import InputError
from teamslam.ros2 import messages as m
from teamslam.ros2.bags import (
    RobotTopics,
    _write_bag,
    export_bag,
    import_bag,
    parse_robot_spec,
)
from teamslam.sim import lissajous_team

OBS = "/{name}/stereo_observations"


def _robots(n: int, gt: bool = True) -> list[RobotTopics]:
    return [
        RobotTopics(f"robot_{i}", f"/robot_{i}/odom", f"/robot_{i}/ground_truth" if gt else None)
        for i in range(n)
    ]


def _raw(path: Path, suffix: str) -> list[tuple[str, int, bytes]]:
    from rosbags.rosbag2 import Reader

    with Reader(path) as reader:
        conns = [c for c in reader.connections if c.topic.endswith(suffix)]
        return [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages(connections=conns)]


@pytest.fixture(scope="module")
def team():
    data = lissajous_team(robots=2, steps=15, objects=40, seed=4)
    # stamps of a real recording: nanoseconds since the epoch, a non-integer period
    robots = [replace(r, timestamps=np.arange(r.frames) * 0.1 + 0.05) for r in data.robots]
    metadata = {**data.metadata, "ros2": {"stamp_origin_ns": 1_700_000_000_123_456_789}}
    return replace(data, robots=robots, metadata=metadata)


def test_round_trip(team, tmp_path):
    bag = tmp_path / "team.mcap"
    export_bag(team, bag, camera=tmp_path / "camera.json")
    back = import_bag(bag, _robots(2), OBS, tmp_path / "camera.json")
    assert back.metadata["ros2"]["stamp_origin_ns"] == 1_700_000_000_123_456_789 + 50_000_000
    cal, cal2 = team.calibration, back.calibration
    assert np.array_equal(cal.camera.intrinsics, cal2.camera.intrinsics)
    assert np.array_equal(cal.camera.T_left_right, cal2.camera.T_left_right)
    assert np.array_equal(cal.T_cam_body, cal2.T_cam_body)
    for a, b in zip(team.robots, back.robots, strict=True):
        # what the bag carries exactly is given back bit for bit
        for name in ("features", "objects"):
            x, y = getattr(a, name), getattr(b, name)
            assert np.array_equal(x.offsets, y.offsets)
            assert np.array_equal(x.ids, y.ids)
            assert np.array_equal(x.measurements, y.measurements)
        assert np.array_equal(
            np.rint(b.timestamps * 1e9), np.rint((a.timestamps - a.timestamps[0]) * 1e9)
        )
        # poses go through ROS quaternions: equal to rounding
        np.testing.assert_allclose(b.T_world_body, a.T_world_body, rtol=0, atol=1e-12)
        np.testing.assert_allclose(b.odometry, a.odometry, rtol=0, atol=1e-12)
    want = team.sensor_model.for_robot(0).odometry_std
    for i in range(2):
        np.testing.assert_allclose(back.sensor_model.for_robot(i).odometry_std, want, rtol=1e-9)
    assert back.metadata["ground_truth"] is True


def test_bag_dataset_bag_is_bit_exact(team, tmp_path):
    first = tmp_path / "first.mcap"
    export_bag(team, first, camera=tmp_path / "camera.json")
    dataset = import_bag(first, _robots(2), OBS, tmp_path / "camera.json")
    second = tmp_path / "second.mcap"
    export_bag(dataset, second)
    a, b = _raw(first, "stereo_observations"), _raw(second, "stereo_observations")
    assert len(a) == 2 * team.robots[0].frames
    assert a == b  # same topics, same log times (ns), same CDR bytes


def test_schema_carries_the_shipped_msg(team, tmp_path):
    from mcap.reader import make_reader

    bag = tmp_path / "team.mcap"
    export_bag(team, bag)
    with bag.open("rb") as f:
        schemas = {s.name: s for s in make_reader(f).get_summary().schemas.values()}
    schema = schemas[m.OBSERVATIONS_TYPE]
    assert schema.encoding == "ros2msg"
    text = schema.data.decode()
    assert text.startswith(m.observations_msgdef().rstrip("\n"))
    assert "MSG: std_msgs/Header" in text
    # a reader that knows nothing of teamslam builds the type from the bag alone
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    with AnyReader([bag], default_typestore=get_typestore(Stores.EMPTY)) as reader:
        conn = next(c for c in reader.connections if c.topic == "/robot_1/stereo_observations")
        _, _, raw = next(iter(reader.messages(connections=[conn])))
        msg = reader.deserialize(raw, conn.msgtype)
    ids, z = team.robots[1].objects.frame(0)
    fids, _ = team.robots[1].features.frame(0)
    assert list(msg.ids) == list(fids) + list(ids)
    assert list(msg.u_left[len(fids) :]) == list(z[:, 0])


def test_without_ground_truth_dead_reckons(team, tmp_path):
    bag = tmp_path / "team.mcap"
    export_bag(team, bag, camera=tmp_path / "camera.json")
    back = import_bag(bag, _robots(2, gt=False), OBS, tmp_path / "camera.json")
    assert back.metadata["ground_truth"] is False
    r = back.robots[0]
    chained = r.T_world_body[0] @ r.odometry[0] @ r.odometry[1]
    np.testing.assert_allclose(r.T_world_body[2], chained, atol=1e-12)


def test_streams_that_do_not_overlap(team, tmp_path):
    from rosbags.highlevel import AnyReader

    bag = tmp_path / "team.mcap"
    export_bag(team, bag, camera=tmp_path / "camera.json")
    records = []
    with AnyReader([bag], default_typestore=m.typestore()) as reader:
        for conn, t, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic.endswith("stereo_observations"):
                t += 3_600 * 10**9  # an hour later: a camera clock on another time base
                msg.header.stamp = m.time_msg(t)
            records.append((t, conn.topic, conn.msgtype, m.serialize(msg, conn.msgtype)))
    shifted = tmp_path / "shifted.mcap"
    _write_bag(records, shifted)
    with pytest.raises(InputError, match=r"robot_0: observations on /robot_0/stereo_obs.*overlap"):
        import_bag(shifted, _robots(2), OBS, tmp_path / "camera.json")
    with pytest.raises(InputError, match=r"no topic /robot_0/odometry \(the bag has"):
        import_bag(
            bag, [RobotTopics("robot_0", "/robot_0/odometry")], OBS, tmp_path / "camera.json"
        )
    with pytest.raises(InputError, match="expected nav_msgs/msg/Odometry"):
        import_bag(
            bag, [RobotTopics("robot_0", "/robot_0/ground_truth")], OBS, tmp_path / "camera.json"
        )
    with pytest.raises(InputError, match="NAME:ODOM_TOPIC"):
        parse_robot_spec("robot_0")


def test_cli_export_and_import(team, tmp_path, capsys):
    from teamslam.datasets import save_dataset

    save_dataset(team, tmp_path / "data")
    bag, camera = tmp_path / "team.mcap", tmp_path / "camera.json"
    assert (
        main(
            [
                "data",
                "export-bag",
                str(tmp_path / "data"),
                "--out",
                str(bag),
                "--camera",
                str(camera),
            ]
        )
        == 0
    )
    args = [
        "data",
        "import-bag",
        str(bag),
        "--observations",
        OBS,
        "--camera",
        str(camera),
        "--out",
        str(tmp_path / "back"),
    ]
    for i in range(2):
        args += ["--robot", f"robot_{i}:/robot_{i}/odom:/robot_{i}/ground_truth"]
    assert main(args) == 0
    back = load_dataset(tmp_path / "back")
    assert np.array_equal(back.robots[1].objects.ids, team.robots[1].objects.ids)
    assert main([*args[:-2], "--tolerance", "-1", "--out", str(tmp_path / "x")]) == 2
    assert "--tolerance" in capsys.readouterr().err
