"""MCAP export of a run: standard ROS 2 schemas, readable by mcap-ros2 and rosbags."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from teamslam.cli import main
from teamslam.eval.estimates import load_estimates, save_estimates
from teamslam.eval.outputs import RUN_FILE, write_json
from teamslam.msckf import config_for, run_team
from teamslam.ros2 import messages as m
from teamslam.ros2.mcap_export import export_mcap
from teamslam.sim import lissajous_team

# published RIHS01 values: std_msgs/String from rmw_zenoh's design document (its key-expression
# examples), geometry_msgs/PoseStamped as ROS 2 Jazzy's rosidl generates it
STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
POSE_STAMPED_HASH = "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8"


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> tuple[Path, object, object]:
    team = lissajous_team(robots=2, steps=12, objects=40, seed=3)
    result = run_team(team, config_for(team, {"filter.window": 6}), consensus=True, progress=False)
    out = tmp_path_factory.mktemp("run")
    save_estimates(out / "estimates.npz", team, result)
    write_json(out / RUN_FILE, {"modes": ["consensus"], "complete": True})  # written last
    return out, team, result


def test_type_hashes_match_published_values():
    assert m.type_hash("std_msgs/msg/String") == STRING_HASH
    assert m.type_hash("geometry_msgs/msg/PoseStamped") == POSE_STAMPED_HASH
    assert m.dds_type_name("geometry_msgs/msg/PoseStamped") == (
        "geometry_msgs::msg::dds_::PoseStamped_"
    )


def test_ellipsoid_axes_closed_form():
    rng = np.random.default_rng(0)
    R = Rotation.random(random_state=rng).as_matrix()
    sigmas = np.array([0.1, 0.4, 2.0])
    cov = R @ np.diag(sigmas**2) @ R.T
    scale, quat = m.ellipsoid_axes(cov[None], n_sigma=3.0)
    np.testing.assert_allclose(scale[0], 6.0 * sigmas, rtol=1e-12)
    axes = Rotation.from_quat(quat[0]).as_matrix()
    # each ellipsoid axis is the matching principal direction (up to sign)
    np.testing.assert_allclose(np.abs(np.sum(axes * R, axis=0)), 1.0, atol=1e-10)


def test_estimates_round_trip(run_dir):
    out, team, result = run_dir
    meta, robots = load_estimates(out / "estimates.npz")
    assert meta["robots"] == 2
    for i, r in enumerate(robots):
        np.testing.assert_array_equal(r.poses, result.poses[i])
        np.testing.assert_array_equal(r.object_covs, result.object_covs[i])
        np.testing.assert_array_equal(r.stamps_ns, np.rint(team.robots[i].timestamps * 1e9))
        assert np.all(np.linalg.eigvalsh(r.object_covs) > 0)


def test_mcap_readable_by_mcap_ros2_with_the_published_values(run_dir, tmp_path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out, team, result = run_dir
    target = tmp_path / "run.mcap"
    summary = export_mcap(out, target, path_messages=5)
    topics: dict[str, list] = {}
    with target.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        schemas = reader.get_summary().schemas.values()
        assert {s.encoding for s in schemas} == {"ros2msg"}
        assert {s.name for s in schemas} == {
            "geometry_msgs/msg/PoseStamped",
            "nav_msgs/msg/Path",
            "visualization_msgs/msg/MarkerArray",
            "tf2_msgs/msg/TFMessage",
        }
        for _, channel, message, decoded in reader.iter_decoded_messages():
            assert channel.message_encoding == "cdr"
            topics.setdefault(channel.topic, []).append((message.log_time, decoded))
    assert sum(len(v) for v in topics.values()) == summary["messages"]
    frames = team.robots[0].frames
    for i in range(2):
        poses = topics[f"/robot_{i}/pose"]
        assert len(poses) == frames
        for k, (log_time, msg) in enumerate(poses):
            stamp = int(np.rint(team.robots[i].timestamps[k] * 1e9))
            assert log_time == stamp == msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            assert msg.header.frame_id == "world"
            p, q = msg.pose.position, msg.pose.orientation
            T = result.poses[i][k]
            assert (p.x, p.y, p.z) == tuple(T[:3, 3])
            R = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
            np.testing.assert_allclose(R, T[:3, :3], atol=1e-12)
        gt = topics[f"/ground_truth/robot_{i}/pose"]
        assert [msg.pose.position.x for _, msg in gt] == list(team.robots[i].T_world_body[:, 0, 3])
        paths = topics[f"/robot_{i}/path"]
        assert len(paths) <= 5 and len(paths[-1][1].poses) == frames
        ((_, markers),) = topics[f"/robot_{i}/objects"]
        n_obj = result.object_ids[i].size
        assert n_obj > 0 and len(markers.markers) == 2 * n_obj
        spheres = [mk for mk in markers.markers if mk.ns == "objects"]
        shells = [mk for mk in markers.markers if mk.ns == "objects_3sigma"]
        assert [mk.id for mk in spheres] == list(result.object_ids[i])
        scales, _ = m.ellipsoid_axes(result.object_covs[i])
        np.testing.assert_allclose(
            [[mk.scale.x, mk.scale.y, mk.scale.z] for mk in shells], scales, rtol=1e-12
        )
    tf = [msg for _, msg in topics["/tf"]]
    children = {t.child_frame_id for msg in tf for t in msg.transforms}
    assert children == {
        "robot_0/base_link",
        "robot_1/base_link",
        "robot_0/ground_truth",
        "robot_1/ground_truth",
    }


def test_mcap_readable_by_rosbags(run_dir, tmp_path):
    from rosbags.highlevel import AnyReader

    out, _, result = run_dir
    target = tmp_path / "run.mcap"
    export_mcap(out, target)
    with AnyReader([target]) as reader:
        connections = [c for c in reader.connections if c.topic == "/robot_1/pose"]
        assert connections[0].msgtype == "geometry_msgs/msg/PoseStamped"
        xs = [
            reader.deserialize(raw, conn.msgtype).pose.position.x
            for conn, _, raw in reader.messages(connections=connections)
        ]
    assert xs == list(result.poses[1][:, 0, 3])


def test_export_mcap_cli_errors(tmp_path, capsys):
    assert main(["export", "mcap", str(tmp_path), "--out", str(tmp_path / "x.mcap")]) == 2
    assert "not a run directory (no run.json" in capsys.readouterr().err
    write_json(tmp_path / RUN_FILE, {"modes": ["consensus"], "complete": True})
    assert main(["export", "mcap", str(tmp_path), "--out", str(tmp_path / "x.mcap")]) == 2
    assert "estimates.npz" in capsys.readouterr().err
    (tmp_path / "estimates.npz").write_bytes(b"not a zip")
    assert main(["export", "mcap", str(tmp_path), "--out", str(tmp_path / "x.mcap")]) == 2
    assert "not a readable estimates file" in capsys.readouterr().err
