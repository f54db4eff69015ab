"""Appearance in tracking: the learned likelihood ratio and the tracker's use of it."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from teamslam.datasets.identity import strip_object_ids
from teamslam.datasets.model import (
    Calibration,
    FrameDetections,
    FrameObservations,
    RobotSequence,
    TeamDataset,
)
from teamslam.datasets.storage import load_dataset, save_dataset
from teamslam.eval.tracking import mot_metrics
from teamslam.geometry import se3
from teamslam.geometry.camera import StereoCamera
from teamslam.msckf.agent import MsckfAgent
from teamslam.msckf.objects.appearance import AppearanceModel, cosine_distances
from teamslam.msckf.settings.values import MsckfConfig
from teamslam.sim import lissajous_team
from teamslam.sim.lissajous import T_CAM_BODY


def _track(dataset: TeamDataset, robot: int = 0, **settings) -> tuple[MsckfAgent, dict]:
    config = MsckfConfig.from_settings({"filter.window": 10, **settings})
    seq = dataset.robots[robot]
    agent = MsckfAgent(robot, dataset.calibration, seq, config)
    for t in range(seq.frames):
        agent.step(t)
    det = seq.detections
    return agent, mot_metrics(det.offsets, det.truth, agent.tracker.hypotheses())


@pytest.fixture(scope="module")
def described():
    team = lissajous_team(
        robots=1, steps=80, objects=80, seed=4, clutter=0.2, miss=0.1, appearance=16
    )
    return strip_object_ids(team, to="none")


def test_ratio_is_zero_without_evidence():
    model = AppearanceModel(0.99)
    d = np.linspace(0.0, 2.0, 9)
    assert np.all(model.log_ratio(d) == 0.0) and not model.informative
    assert model.auc() == 0.5
    # the same distances for both: no evidence either way, whatever the counts
    samples = np.repeat(np.linspace(0.0, 1.0, 50), 4)
    model.add(samples, samples)
    np.testing.assert_allclose(model.log_ratio(d), 0.0, atol=1e-12)
    assert model.auc() == pytest.approx(0.5) and not model.informative
    # every descriptor equal: all distances 0, still no evidence
    flat = AppearanceModel(0.99)
    flat.add(np.zeros(300), np.zeros(3000))
    assert flat.auc() == pytest.approx(0.5) and not flat.informative


def test_learned_ratio_separates_same_from_different(described):
    agent, _ = _track(described)
    model = agent.tracker.appearance
    assert model is not None and model.same.sum() > 100 and model.different.sum() > 100
    assert model.auc() > 0.95 and model.informative
    # near descriptors favour "same", unrelated ones (cosine distance about 1) "different"
    assert model.log_ratio(np.array([0.02]))[0] > 2.0
    assert model.log_ratio(np.array([1.0]))[0] < -2.0
    # the auc equals the rank statistic of the counted samples, computed directly
    same = np.repeat(np.arange(40), model.same.astype(int))
    diff = np.repeat(np.arange(40), model.different.astype(int))
    direct = (same[:, None] < diff[None, :]).mean() + 0.5 * (same[:, None] == diff[None, :]).mean()
    assert model.auc() == pytest.approx(direct)


def test_descriptors_round_trip_and_reach_the_tracker(tmp_path, described):
    save_dataset(described, tmp_path / "d")
    back = load_dataset(tmp_path / "d")
    a, b = described.robots[0].detections, back.robots[0].detections
    np.testing.assert_array_equal(a.appearance, b.appearance)
    assert b.appearance.dtype == np.float32
    # true detections of one object look alike, of two objects do not
    truth = b.truth
    one = b.appearance[truth == truth[truth >= 0][0]]
    other = b.appearance[(truth >= 0) & (truth != truth[truth >= 0][0])]
    assert cosine_distances(one[:1], one[1:]).max() < cosine_distances(one[:1], other).min()


def test_without_descriptors_tracking_is_unchanged(described):
    """No descriptors, or appearance switched off: the same decisions and the same estimate."""
    seq = described.robots[0]
    bare = replace(
        described, robots=[replace(seq, detections=replace(seq.detections, appearance=None))]
    )
    a, _ = _track(bare)
    b, _ = _track(described, **{"tracking.appearance": False})
    np.testing.assert_array_equal(a.tracker.hypotheses(), b.tracker.hypotheses())
    np.testing.assert_array_equal(a.state.current_pose, b.state.current_pose)
    np.testing.assert_array_equal(a.state.objects, b.state.objects)
    np.testing.assert_array_equal(a.state.cov, b.state.cov)
    assert a.tracker.appearance is None and b.tracker.appearance is None


def _two_lookalike_objects(
    appearance: bool, seed: int = 0, extent: np.ndarray | None = None, path=(0.0, 6.0)
) -> TeamDataset:
    """One robot driving from ``x = path[0]`` to ``path[1]`` (towards, or back from) two
    objects at ``x = 20`` m 0.15 m apart side by side, boxed with 3 px of noise (from 14 m
    away their predictions overlap every frame); each object's descriptor distinct. With
    ``extent`` (``(2, 2)`` width and height, m) the boxes have sizes, a tenth of noise each."""
    rng = np.random.default_rng(seed)
    frames = 60
    camera = StereoCamera.from_baseline(400.0, 400.0, 320.0, 240.0, 0.5)
    poses = np.tile(np.eye(4), (frames, 1, 1))
    poses[:, 0, 3] = np.linspace(*path, frames)
    objects = np.array([[20.0, 0.075, 0.0], [20.0, -0.075, 0.0]])
    odometry = se3.inverse(poses[:-1]) @ poses[1:]
    looks = rng.standard_normal((2, 8))
    rows, truth, desc, sizes = [], [], [], []
    for k in range(frames):
        T_cam_world = T_CAM_BODY @ se3.inverse(poses[k])
        p_cam = objects @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
        z = camera.project(p_cam) + rng.normal(0.0, 3.0, (2, 4))
        order = rng.permutation(2)
        rows.append(z[order])
        truth.append(order)
        desc.append(looks[order] + rng.normal(0.0, 0.1, (2, 8)))
        if extent is not None:
            size = extent[order] * camera.intrinsics[0, 0] / p_cam[order, 2:3]
            sizes.append(size * (1.0 + rng.normal(0.0, 0.1, (2, 2))))
    detections = FrameDetections(
        np.arange(0, 2 * frames + 1, 2),
        np.concatenate(rows),
        truth=np.concatenate(truth),
        sizes=np.concatenate(sizes) if extent is not None else None,
        appearance=np.concatenate(desc) if appearance else None,
    )
    robot = RobotSequence(
        T_world_body=poses,
        odometry=odometry,
        features=FrameObservations.empty(frames),
        objects=FrameObservations.empty(frames),
        detections=detections,
    )
    return TeamDataset(
        name="lookalikes",
        calibration=Calibration(camera, T_CAM_BODY, (640, 480)),
        robots=[robot],
        object_ids=np.arange(2),
        object_positions=objects,
        object_id_scope="none",
    )


def test_useless_appearance_changes_nothing(described):
    """Every descriptor equal, or pure noise: never informative, so position decides alone."""
    seq = described.robots[0]
    det = seq.detections
    rng = np.random.default_rng(0)
    plain, _ = _track(described, **{"tracking.appearance": False})
    for looks in (np.ones_like(det.appearance), rng.standard_normal(det.appearance.shape)):
        team = replace(described, robots=[replace(seq, detections=replace(det, appearance=looks))])
        agent, _ = _track(team)
        assert not agent.tracker.appearance.informative
        np.testing.assert_array_equal(agent.tracker.hypotheses(), plain.tracker.hypotheses())
        np.testing.assert_array_equal(agent.state.cov, plain.state.cov)


def test_tracker_chooses_by_appearance_between_lookalike_positions():
    settings = {"filter.object_std": 3.0, "filter.odometry_std": [0.001] * 6}
    with_looks = [_track(_two_lookalike_objects(True, s), **settings)[1] for s in range(3)]
    positions = [_track(_two_lookalike_objects(False, s), **settings)[1] for s in range(3)]
    # by position alone the two objects' detections are swapped often; by appearance only
    # in the first frames, before any track is confirmed (no "same" sample yet)
    switches = sum(m["id_switches"] for m in positions)
    assert switches >= 20
    assert 5 * sum(m["id_switches"] for m in with_looks) <= switches
    assert all(m["idf1"] > 0.95 for m in with_looks)
    assert all(m["objects_created"] == 2 for m in with_looks)


def test_tracker_chooses_by_box_shape_between_lookalike_positions():
    """Boxes without descriptors, the robot backing away from the two objects: their shapes
    (width to height), learned while the two stood apart in the image, keep them apart once
    their predictions overlap; with ``tracking.appearance`` off, position alone swaps them
    often."""
    settings = {"filter.object_std": 3.0, "filter.odometry_std": [0.001] * 6}
    extent = np.array([[0.2, 0.8], [0.6, 0.3]])  # tall and narrow, wide and low (m)
    data = [_two_lookalike_objects(False, s, extent, path=(14.0, 6.0)) for s in range(3)]
    runs = [_track(team, **settings) for team in data]
    positions = [_track(team, **settings, **{"tracking.appearance": False})[1] for team in data]
    switches = sum(m["id_switches"] for m in positions)
    assert switches >= 20
    assert all(agent.tracker.shape.informative for agent, _ in runs)
    assert all(agent.tracker.appearance is None for agent, _ in runs)
    assert 5 * sum(m["id_switches"] for _, m in runs) <= switches
    assert all(m["idf1"] > 0.95 for _, m in runs)
