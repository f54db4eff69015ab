"""The rendered room: exact ray casting, markers that read correctly, deterministic images,
image effects, and the folders a rendered team is written as."""

from __future__ import annotations

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2", reason="the images extra (OpenCV) is not installed")

from teamslam.datasets.trajectory import read_tum  # noqa: E402
from teamslam.errors import InputError  # noqa: E402
from teamslam.frontend import load_camera  # noqa: E402
from teamslam.sim.render import (  # noqa: E402
    RenderConfig,
    TexturedRoom,
    render_stereo,
    render_team,
    robot_paths,
)

SMALL = {"image_size": (160, 120), "focal": 105.0, "steps": 3, "robots": 2}


@pytest.fixture(scope="module")
def team():
    return render_team(RenderConfig(**SMALL))


def test_cast_points_lie_on_the_room_and_project_back(team):
    rng = np.random.default_rng(0)
    uv = rng.uniform([0, 0], [159, 119], (200, 2))
    p = team.points_behind(1, 2, uv)
    size = np.array(team.config.room)
    # every point is inside the room and on one of its six planes
    assert np.all(p >= -1e-9) and np.all(p <= size + 1e-9)
    on_plane = np.isclose(p, 0.0, atol=1e-9) | np.isclose(p, size, atol=1e-9)
    assert on_plane.any(axis=1).all()
    z = team.project(1, 2, p)
    np.testing.assert_allclose(z[:, :2], uv, atol=1e-8)
    # right image: same row, positive disparity (rectified rig)
    np.testing.assert_allclose(z[:, 3], z[:, 1], atol=1e-8)
    assert np.all(z[:, 0] - z[:, 2] > 0)


def test_markers_hang_on_walls_and_read_unmirrored():
    config = RenderConfig(image_size=(640, 480), focal=420.0, steps=1, robots=1)
    room = TexturedRoom(config)
    X, Y, _ = config.room
    c = room.marker_centres
    on_wall = np.isclose(c[:, 0], 0) | np.isclose(c[:, 0], X) | np.isclose(c[:, 1], 0)
    on_wall |= np.isclose(c[:, 1], Y)
    assert on_wall.all()
    assert np.unique(room.marker_ids).size == room.marker_ids.size
    # look straight at marker 0 from 2.5 m: ArUco finds its id, its corners where projected
    n = np.array([1.0, 0.0, 0.0])  # marker 0 is on the wall x = 0, facing +x
    eye = c[0] + 2.5 * n
    z_cam = -n
    x_cam = np.cross(z_cam, [0.0, 0.0, -1.0])  # optical y points down
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x_cam, np.cross(z_cam, x_cam), z_cam])
    T[:3, 3] = eye
    K = config.camera().intrinsics
    img = (255 * room.render(T, K, config.image_size)).astype(np.uint8)
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_250))
    corners, ids, _ = detector.detectMarkers(img)
    assert ids is not None and 0 in ids.ravel()
    found = corners[list(ids.ravel()).index(0)].reshape(4, 2)
    T_cam_world = np.linalg.inv(T)
    p = room.marker_corners[0] @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    truth = p[:, :2] / p[:, 2:] * K[0, 0] + K[:2, 2]
    np.testing.assert_allclose(found, truth, atol=1.0)


def test_rendering_is_deterministic_and_the_right_camera_differs_in_gain(team):
    a = render_stereo(team.room, team.T_world_cam(0, 1), np.random.default_rng(5))
    b = render_stereo(team.room, team.T_world_cam(0, 1), np.random.default_rng(5))
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert a[0].shape == (120, 160) and a[0].dtype == np.uint8
    # gain 0.9 and offset 6 in the right image: its mean is measurably lower than 0.9×left
    # plus 6 would not be by chance; check the contrast ratio instead (offset-free)
    ratio = a[1].std() / a[0].std()
    assert 0.8 < ratio < 1.0


def test_paths_stay_inside_the_room_at_camera_height():
    config = RenderConfig(robots=4, steps=300)
    for path in robot_paths(config):
        xy = path[:, :2, 3]
        assert np.all(xy > config.wall_margin - 1e-6)
        assert np.all(xy < np.array(config.room[:2]) - config.wall_margin + 1e-6)
        np.testing.assert_allclose(path[:, 2, 3], config.camera_height)
        step = np.linalg.norm(np.diff(path[:, :3, 3], axis=0), axis=1)
        np.testing.assert_allclose(step, config.step_length, rtol=0.05)


def test_rendered_team_folders(tmp_path):
    team = render_team(RenderConfig(**SMALL), tmp_path / "team")
    for i in range(2):
        d = tmp_path / "team" / f"robot_{i}"
        left = sorted((d / "left").iterdir())
        assert [p.name for p in left] == [f"{k:06d}.png" for k in range(4)]
        assert (d / "right" / "000003.png").is_file()
        t, poses = read_tum(d / "groundtruth.tum")
        np.testing.assert_allclose(poses, team.paths[i], atol=1e-6)
        np.testing.assert_allclose(t, np.arange(4) / 10.0)
        _, odo = read_tum(d / "odometry.tum")
        assert odo.shape == (4, 4, 4)
        rig = load_camera(d / "camera.yaml")
        assert rig.already_rectified
        np.testing.assert_allclose(rig.camera.intrinsics, team.config.camera().intrinsics)
    ids = np.loadtxt(tmp_path / "team" / "markers.txt", ndmin=2)[:, 0]
    np.testing.assert_array_equal(ids, team.room.marker_ids)


def test_bad_render_settings():
    with pytest.raises(InputError, match="dictionary"):
        RenderConfig(dictionary="nope")
    with pytest.raises(InputError, match="camera_height"):
        RenderConfig(camera_height=5.0)


def test_simulate_images_writes_folders_and_a_bag(tmp_path):
    from rosbags.highlevel import AnyReader

    from teamslam.api import simulate_images

    simulate_images(tmp_path / "sim", robots=1, steps=2, progress=False, image_size=(96, 72))
    assert (tmp_path / "sim" / "robot_0" / "left" / "000002.png").is_file()
    with AnyReader([tmp_path / "sim" / "images.mcap"]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts["/robot_0/left/image_raw"] == 3
    assert counts["/robot_0/right/camera_info"] == 3  # with every pair, as a camera driver
