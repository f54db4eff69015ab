"""The Lissajous stereo team simulator."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from teamslam.datasets import dataset_info
from teamslam.geometry import se3
from teamslam.sim import lissajous_team


@pytest.fixture(scope="module")
def exact():
    return lissajous_team(robots=3, steps=60, seed=2, noise_free=True)


def test_noise_free_observations_are_exact_projections(exact):
    lm = dict(zip(exact.track_landmarks[:, 0], exact.track_landmarks[:, 1], strict=True))
    cam = exact.calibration.camera
    w, h = exact.calibration.image_size
    checked = 0
    for robot in exact.robots:
        T_cam_world = exact.calibration.T_cam_body @ se3.inverse(robot.T_world_body)
        for k in range(robot.frames):
            for obs, positions in (
                (robot.features, lambda ids: exact.landmark_positions[[lm[t] for t in ids]]),
                (robot.objects, lambda ids: exact.object_position(ids)),
            ):
                ids, z = obs.frame(k)
                if ids.size == 0:
                    continue
                p = positions(ids)
                p_cam = p @ T_cam_world[k, :3, :3].T + T_cam_world[k, :3, 3]
                np.testing.assert_allclose(z, cam.project(p_cam), atol=1e-9)
                assert np.all(cam.in_view(p_cam, w, h))
                checked += ids.size
    assert checked > 1000


def test_noise_free_odometry_composes_to_ground_truth(exact):
    for robot in exact.robots:
        pose = robot.T_world_body[0]
        for k, step in enumerate(robot.odometry):
            pose = pose @ step
            np.testing.assert_allclose(pose, robot.T_world_body[k + 1], atol=1e-9)


def test_tracks_are_contiguous_and_name_one_landmark(exact):
    track_lm = dict(zip(exact.track_landmarks[:, 0], exact.track_landmarks[:, 1], strict=True))
    for robot in exact.robots:
        ids = robot.features.ids
        frame_of = np.repeat(np.arange(robot.frames), robot.features.counts())
        for track in np.unique(ids)[:200]:
            frames = frame_of[ids == track]
            assert np.all(np.diff(frames) == 1)  # seen in consecutive frames only
            assert track in track_lm


def test_noisy_residuals_match_configured_noise():
    ds = lissajous_team(robots=3, steps=150, seed=5, pixel_noise=1.5, object_pixel_noise=4.0)
    lm = dict(zip(ds.track_landmarks[:, 0], ds.track_landmarks[:, 1], strict=True))
    cam = ds.calibration.camera
    for obs_name, sigma in (("features", 1.5), ("objects", 4.0)):
        residuals = []
        for robot in ds.robots:
            T_cam_world = ds.calibration.T_cam_body @ se3.inverse(robot.T_world_body)
            obs = getattr(robot, obs_name)
            for k in range(robot.frames):
                ids, z = obs.frame(k)
                if ids.size == 0:
                    continue
                if obs_name == "features":
                    p = ds.landmark_positions[[lm[t] for t in ids]]
                else:
                    p = ds.object_position(ids)
                p_cam = p @ T_cam_world[k, :3, :3].T + T_cam_world[k, :3, 3]
                residuals.append(z - cam.project(p_cam))
        r = np.concatenate(residuals)
        assert len(r) > 2000
        assert np.all(np.abs(r.mean(axis=0)) < 0.1 * sigma)
        np.testing.assert_allclose(r.std(axis=0), sigma, rtol=0.1)


def test_odometry_noise_statistics():
    ds = lissajous_team(
        robots=2,
        steps=400,
        seed=6,
        odometry_translation_noise=0.05,
        odometry_rotation_noise=0.01,
        landmarks=10,
        objects=5,
    )
    errs = np.concatenate(
        [
            se3.log(se3.inverse(se3.inverse(r.T_world_body[:-1]) @ r.T_world_body[1:]) @ r.odometry)
            for r in ds.robots
        ]
    )
    np.testing.assert_allclose(errs[:, :3].std(axis=0), 0.05, rtol=0.1)
    np.testing.assert_allclose(errs[:, 3:].std(axis=0), 0.01, rtol=0.1)


def test_default_team_is_well_posed():
    ds = lissajous_team(robots=5, steps=300, seed=0)
    info = dataset_info(ds)
    assert info["feature_observations_per_frame"]["mean"] >= 50
    assert info["object_observations_per_frame"]["mean"] >= 3
    assert info["objects_shared"] >= 100  # robots share much of the map
    assert info["geometric_track_length_mean"] >= 5
    # the camera looks along the direction of travel
    robot = ds.robots[0]
    travel = np.diff(robot.T_world_body[:, :3, 3], axis=0)
    forward = robot.T_world_body[:-1, :3, 0]
    cos = np.einsum("ij,ij->i", travel, forward) / np.linalg.norm(travel, axis=1)
    assert np.median(cos) > 0.99


def test_deterministic_across_processes():
    code = (
        "import hashlib, numpy as np; from teamslam.sim import lissajous_team;"
        "d = lissajous_team(robots=2, steps=30, seed=9, landmarks=200);"
        "h = hashlib.sha256();"
        "[h.update(np.ascontiguousarray(a).tobytes()) for r in d.robots for a in "
        "(r.T_world_body, r.odometry, r.features.ids, r.features.measurements,"
        " r.objects.measurements)];"
        "print(h.hexdigest())"
    )
    runs = {
        subprocess.run(
            [sys.executable, "-c", code],
            capture_output=True,
            text=True,
            check=True,
            env={"PYTHONHASHSEED": str(s), "PATH": ""},
        ).stdout
        for s in (1, 2)
    }
    assert len(runs) == 1
    other = lissajous_team(robots=2, steps=30, seed=10, landmarks=200)
    same = lissajous_team(robots=2, steps=30, seed=9, landmarks=200)
    assert not np.array_equal(other.robots[0].T_world_body, same.robots[0].T_world_body)


def test_bad_configuration_is_rejected():
    with pytest.raises(ValueError, match="pixel_noise"):
        lissajous_team(robots=2, steps=5, pixel_noise=-1.0)
    with pytest.raises(ValueError, match="positive"):
        lissajous_team(robots=0, steps=5)
