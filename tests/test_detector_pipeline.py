"""From a detector's boxes beside stereo images to a team map: `data from-images --detections`."""

from __future__ import annotations

import shutil
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("cv2")

from teamslam.datasets.identity import oracle_object_ids
from teamslam.datasets.images import dataset_from_images, rendered_team_inputs
from teamslam.datasets.storage import load_dataset, save_dataset
from teamslam.errors import InputError
from teamslam.eval.tracking import mot_metrics
from teamslam.msckf.agent import MsckfAgent
from teamslam.msckf.settings.values import MsckfConfig
from teamslam.sim.detector import DetectorConfig
from teamslam.sim.render import RenderConfig, render_team

SMALL = {"image_size": (320, 240), "focal": 210.0}


@pytest.fixture(scope="module")
def street(tmp_path_factory):
    out = tmp_path_factory.mktemp("street") / "render"
    config = RenderConfig(
        **SMALL, layout="street", objects="shapes", robots=2, steps=24, markers_per_wall=0
    )
    render_team(config, out, detector=DetectorConfig())
    return out


@pytest.fixture(scope="module")
def boxes_dataset(street):
    return dataset_from_images(**rendered_team_inputs(street), progress=False)


def test_boxes_become_detections_without_ids(street, boxes_dataset):
    ds = boxes_dataset
    assert ds.object_id_scope == "none"
    for i, robot in enumerate(ds.robots):
        det = robot.detections
        assert robot.objects.ids.size == 0 and det is not None
        record = ds.metadata["images"]["robots"][i]["detections"]
        # every box kept is a detection; in stereo or monocular, each counted once
        assert det.measurements.shape[0] == record["boxes_read"] - record["boxes_dropped"]
        assert record["right box"] + record["patch"] + record["monocular"] == len(det.truth)
        mono = ~np.isfinite(det.measurements[:, 2])
        assert mono.sum() == record["monocular"]
        # boxes measured in stereo lie on one rectified row, at a positive disparity
        stereo = det.measurements[~mono]
        assert np.all(stereo[:, 0] - stereo[:, 2] > 0)
        assert det.sizes.shape == (len(det.truth), 2) and np.all(det.sizes > 0)
        assert det.appearance.dtype == np.float32 and det.appearance.shape[0] == len(det.truth)
        assert det.classes is not None and det.scores is not None
        # the truth file lines follow the boxes: true boxes outnumber false ones
        assert (det.truth >= 0).mean() > 0.8
    # the object map is the render's (ids, positions)
    assert ds.object_ids.size == 20 and ds.object_positions.shape == (20, 3)


def test_detections_round_trip_and_oracle_ids(tmp_path, boxes_dataset):
    save_dataset(boxes_dataset, tmp_path / "d")
    back = load_dataset(tmp_path / "d")
    for a, b in zip(boxes_dataset.robots, back.robots, strict=True):
        for name in ("offsets", "measurements", "classes", "scores", "truth", "sizes"):
            np.testing.assert_array_equal(getattr(a.detections, name), getattr(b.detections, name))
        np.testing.assert_array_equal(a.detections.appearance, b.detections.appearance)
    oracle = oracle_object_ids(back)
    assert oracle.object_id_scope == "global"
    for robot in oracle.robots:
        det = robot.detections
        true = (det.truth >= 0) & np.all(np.isfinite(det.measurements), axis=1)
        # every true box in stereo is an observation of its object, none other
        assert robot.objects.ids.size <= int(true.sum())
        assert set(robot.objects.ids.tolist()) == set(det.truth[true].tolist())


def test_own_tracking_names_the_boxes(boxes_dataset):
    """The tracker, by position and appearance, names the rendered detector's boxes nearly as
    the truth does (the render's objects: 20 in a street of three rooms)."""
    config = MsckfConfig.from_settings({"filter.window": 8})
    for i, robot in enumerate(boxes_dataset.robots):
        agent = MsckfAgent(i, boxes_dataset.calibration, robot, config)
        for t in range(robot.frames):
            agent.step(t)
        det = robot.detections
        m = mot_metrics(det.offsets, det.truth, agent.tracker.hypotheses())
        assert m["idf1"] > 0.8, m
        assert m["false_objects"] <= 1
        # the descriptors of the boxes (thumbnail + hue-saturation) tell the render's objects
        # apart, look-alikes included: the ratio learned in the run separates them
        assert agent.tracker.appearance.auc() > 0.95 and agent.tracker.appearance.informative


def test_the_association_summaries_carry_the_classes_the_boxes_voted_for(boxes_dataset):
    """Each robot's summaries to its neighbours carry, per object, the class its tracker's
    detections voted for (the association pairs objects of one class only, and revokes a held
    pair whose classes came to differ)."""
    from teamslam.graph import complete
    from teamslam.msckf import config_for
    from teamslam.msckf.consensus.transport import MemoryNetwork
    from teamslam.msckf.team import lockstep_drivers, run_drivers

    config = config_for(boxes_dataset, {"filter.window": 8}).with_({"association.mode": "own"})
    n = boxes_dataset.n_robots
    drivers = lockstep_drivers(boxes_dataset, [config] * n, MemoryNetwork(n), complete(n))
    run_drivers(drivers, "complete", 0.0, None, progress=False)
    for driver in drivers:
        protocol = driver.protocol
        state = protocol.agent.state
        ids = np.sort(state.object_ids)
        covs = np.repeat(np.eye(3)[None], ids.size, axis=0)
        summary = protocol._object_summary(ids, state.objects[state.object_slots(ids)], covs)
        labels = protocol.agent.tracker.labels_of(ids)
        assert ids.size and (labels >= 0).all()
        np.testing.assert_array_equal(summary.classes, labels)


def test_user_folders_with_yolo_files(tmp_path, street):
    """The user's way: folders of images and of YOLO files, from the command line."""
    inputs = rendered_team_inputs(street)
    args = []
    for left, right in zip(inputs["left_dirs"], inputs["right_dirs"], strict=True):
        args += [str(left), str(right)]
    for flag, key in (
        ("--odometry", "odometry"),
        ("--timestamps", "timestamps"),
        ("--detections", "detections"),
    ):
        for value in inputs[key]:
            args += [flag, str(value)]
    cmd = [sys.executable, "-m", "teamslam", "data", "from-images", *args]
    cmd += ["--camera", str(inputs["camera"]), "--quiet", "--out", str(tmp_path / "ds")]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr
    assert "boxes:" in done.stdout
    ds = load_dataset(tmp_path / "ds")
    assert ds.object_id_scope == "none"
    assert all(r.detections.truth is None for r in ds.robots)  # no truth given: none kept


def test_bad_detection_inputs_name_what_is_wrong(tmp_path, street):
    inputs = rendered_team_inputs(street)
    given = {k: inputs[k] for k in ("left_dirs", "right_dirs", "camera")}
    with pytest.raises(InputError, match="without detections"):
        dataset_from_images(**given, detection_truth=inputs["detection_truth"], progress=False)
    with pytest.raises(InputError, match="one per robot"):
        dataset_from_images(**given, detections=[inputs["detections"][0], None], progress=False)
    # a truth folder whose lines do not follow the boxes
    truth = tmp_path / "truth"
    shutil.copytree(inputs["detection_truth"][0], truth)
    victim = sorted(truth.glob("*.txt"))[0]
    victim.write_text(victim.read_text() + "3\n")
    with pytest.raises(InputError, match=f"{victim.name}.*truth lines for"):
        dataset_from_images(
            **given,
            detections=inputs["detections"],
            detection_truth=[truth, inputs["detection_truth"][1]],
            progress=False,
        )


def test_boxes_through_a_ros2_bag(tmp_path, street):
    """The same images and boxes as a bag (Image and Detection2DArray topics) give the same
    detections as the folders: `data import-bag --images … --detections TOPIC`."""
    pytest.importorskip("rosbags")
    from teamslam.ros2.image_bags import images_to_bag

    inputs = rendered_team_inputs(street)
    bag = tmp_path / "boxes.mcap"
    images_to_bag(
        inputs["left_dirs"],
        inputs["right_dirs"],
        inputs["camera"],
        inputs["timestamps"],
        bag,
        odometry=inputs["odometry"],
        robot_names=inputs["robot_names"],
        detections=inputs["detections"],
    )
    cmd = [sys.executable, "-m", "teamslam", "data", "import-bag", str(bag)]
    cmd += ["--images", "/{name}/left/image_raw,/{name}/right/image_raw"]
    cmd += ["--camera", str(inputs["camera"]), "--detections", "/{name}/detections"]
    for name in inputs["robot_names"]:
        cmd += ["--robot", f"{name}:/{name}/odom"]
    cmd += ["--quiet", "--out", str(tmp_path / "ds")]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr
    ds = load_dataset(tmp_path / "ds")
    assert ds.object_id_scope == "none"
    # the folders without their right-image boxes (the bag has none): the same measurements
    folders = dataset_from_images(
        **{k: v for k, v in inputs.items() if k != "right_detections"}, progress=False
    )
    for a, b in zip(folders.robots, ds.robots, strict=True):
        np.testing.assert_array_equal(a.detections.offsets, b.detections.offsets)
        np.testing.assert_allclose(a.detections.measurements, b.detections.measurements, atol=1e-6)
        np.testing.assert_array_equal(a.detections.classes, b.detections.classes)
        np.testing.assert_allclose(a.detections.scores, b.detections.scores, atol=1e-6)
    # a topic of boxes without image topics is refused in one line
    cmd = [sys.executable, "-m", "teamslam", "data", "import-bag", str(bag), "--detections", "/x"]
    cmd += ["--robot", "robot_0", "--out", str(tmp_path / "ds2")]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    assert done.returncode == 2 and "needs --images" in done.stderr
