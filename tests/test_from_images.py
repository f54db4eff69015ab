"""From image folders to a team dataset: the dataset loads with the project's loader, carries
the front-end's measurements, visual odometry stands in for missing odometry, and bad images
or stamps give an error naming the file or the stamp."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2", reason="the images extra (OpenCV) is not installed")

from teamslam.datasets import load_dataset, save_dataset  # noqa: E402
from teamslam.datasets.images import dataset_from_images, rendered_team_inputs  # noqa: E402
from teamslam.errors import InputError  # noqa: E402
from teamslam.geometry import se3  # noqa: E402
from teamslam.sim.render import RenderConfig, render_team  # noqa: E402

CONFIG = {"image_size": (320, 240), "focal": 210.0, "marker_size": 0.9, "steps": 5, "robots": 2}


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    out = tmp_path_factory.mktemp("rendered")
    team = render_team(RenderConfig(**CONFIG), out)
    return team, out


def test_dataset_from_images_loads_with_the_project_loader(rendered, tmp_path):
    team, out = rendered
    dataset = dataset_from_images(**rendered_team_inputs(out), progress=False)
    save_dataset(dataset, tmp_path / "ds")
    loaded = load_dataset(tmp_path / "ds")
    assert loaded.n_robots == 2
    for i, robot in enumerate(loaded.robots):
        assert robot.frames == 6
        np.testing.assert_allclose(robot.T_world_body, team.paths[i], atol=1e-6)
        np.testing.assert_allclose(robot.odometry, team.odometry[i], atol=1e-6)
        assert robot.features.counts().min() >= 50
        # measurements are what the renderer's truth says, within a pixel, for 99 %
        ids, z = robot.features.frame(0)
        truth = team.project(i, 0, team.points_behind(i, 0, z[:, :2]))
        assert np.mean(np.abs(z - truth).max(axis=1) < 1.0) > 0.99
        np.testing.assert_allclose(robot.timestamps, np.arange(6) / 10.0)
    # track ids are unique over the team; object ids are marker ids of the map
    ids = [np.unique(r.features.ids) for r in loaded.robots]
    assert np.intersect1d(ids[0], ids[1]).size == 0
    all_objects = np.concatenate([r.objects.ids for r in loaded.robots])
    assert all_objects.size > 0
    assert np.isin(all_objects, loaded.object_ids).all()
    info = loaded.metadata["images"]["robots"]
    assert info[0]["odometry"].startswith("file")
    assert loaded.calibration.image_size == (320, 240)


def test_visual_odometry_when_no_odometry_is_given(rendered):
    team, out = rendered
    inputs = rendered_team_inputs(out)
    inputs["odometry"] = None
    dataset = dataset_from_images(**inputs, progress=False)
    robot = dataset.robots[0]
    assert "visual odometry" in dataset.metadata["images"]["robots"][0]["odometry"]
    true = se3.inverse(team.paths[0][:-1]) @ team.paths[0][1:]
    err_t = np.linalg.norm(robot.odometry[:, :3, 3] - true[:, :3, 3], axis=1)
    assert err_t.max() < 0.01  # steps of 8 cm
    rot = np.einsum("nij,nik->njk", robot.odometry[:, :3, :3], true[:, :3, :3])
    angle = np.arccos(np.clip((np.trace(rot, axis1=1, axis2=2) - 1) / 2, -1, 1))
    assert angle.max() < 0.005


def _copy_robot(out, tmp_path):
    d = tmp_path / "robot"
    shutil.copytree(out / "robot_0", d)
    return d


def test_bad_images_are_named(rendered, tmp_path):
    _, out = rendered
    d = _copy_robot(out, tmp_path)

    def run(**kw):
        args = {
            "left_dirs": [d / "left"],
            "right_dirs": [d / "right"],
            "camera": d / "camera.yaml",
            "progress": False,
        }
        args.update(kw)
        return dataset_from_images(**args)

    small = cv2.resize(cv2.imread(str(d / "left" / "000002.png")), (100, 80))
    cv2.imwrite(str(d / "left" / "000002.png"), small)
    with pytest.raises(
        InputError, match=r"000002\.png: image is 100×80, the camera file says 320×240"
    ):
        run()
    (d / "left" / "000002.png").write_bytes(b"not an image")
    with pytest.raises(InputError, match=r"000002\.png: cannot read"):
        run()
    shutil.copy(out / "robot_0" / "left" / "000002.png", d / "left" / "000002.png")
    stamps = d / "stamps.txt"
    stamps.write_text("0.0\n0.1\n0.3\n0.2\n0.4\n0.5\n")
    with pytest.raises(InputError, match=r"stamp 0\.2 \(line 4\) is not after 0\.3"):
        run(timestamps=[stamps])
    (d / "right" / "000005.png").unlink()
    with pytest.raises(InputError, match=r"000005\.png: no right image"):
        run()


def test_odometry_must_cover_the_image_stamps(rendered, tmp_path):
    _, out = rendered
    d = _copy_robot(out, tmp_path)
    stamps = d / "late.txt"
    stamps.write_text("\n".join(str(0.5 + 0.1 * k) for k in range(6)) + "\n")
    with pytest.raises(InputError, match="outside the odometry trajectory"):
        dataset_from_images(
            [d / "left"],
            [d / "right"],
            d / "camera.yaml",
            timestamps=[stamps],
            odometry=[d / "odometry.tum"],
            progress=False,
        )


def test_the_bag_path_equals_the_folder_path(rendered, tmp_path):
    from teamslam.ros2.image_bags import ImageTopics, dataset_from_bag, images_to_bag

    _, out = rendered
    inputs = rendered_team_inputs(out)
    summary = images_to_bag(
        inputs["left_dirs"],
        inputs["right_dirs"],
        inputs["camera"],
        inputs["timestamps"],
        tmp_path / "team.mcap",
        odometry=inputs["odometry"],
        ground_truth=inputs["ground_truth"],
        robot_names=inputs["robot_names"],
    )
    # per robot and pair: left, right, two camera infos, odometry, ground truth
    assert summary["messages"] == 2 * 6 * 6
    from_folders = dataset_from_images(**inputs, progress=False)
    from_bag = dataset_from_bag(
        tmp_path / "team.mcap",
        [ImageTopics.default(n) for n in inputs["robot_names"]],
        markers=inputs["markers"],
        progress=False,
    )
    np.testing.assert_allclose(
        from_bag.calibration.camera.intrinsics, from_folders.calibration.camera.intrinsics
    )
    assert from_bag.calibration.camera.baseline == pytest.approx(0.2)
    for a, b in zip(from_folders.robots, from_bag.robots, strict=True):
        np.testing.assert_array_equal(a.features.ids, b.features.ids)
        np.testing.assert_array_equal(a.features.measurements, b.features.measurements)
        np.testing.assert_array_equal(a.objects.ids, b.objects.ids)
        np.testing.assert_array_equal(a.objects.measurements, b.objects.measurements)
        np.testing.assert_allclose(a.T_world_body, b.T_world_body, atol=1e-9)
        np.testing.assert_allclose(a.odometry, b.odometry, atol=1e-9)
        np.testing.assert_allclose(a.timestamps, b.timestamps, atol=1e-9)
    with pytest.raises(InputError, match=r"no topic .*/robot_9/left/image_raw"):
        dataset_from_bag(tmp_path / "team.mcap", [ImageTopics.default("robot_9")], progress=False)
