"""The tracker on a detector's boxes: class labels as evidence, boxes seen in one image only."""

from __future__ import annotations

import numpy as np

from teamslam.msckf.filter.box_noise import box_rows
from teamslam.msckf.filter.models import observe
from teamslam.msckf.filter.state import MsckfState
from teamslam.msckf.objects.tracking import LabelModel, ObjectTracker
from teamslam.msckf.settings.values import MsckfConfig
from teamslam.sim.lissajous import T_CAM_BODY, SimulationConfig

CAMERA = SimulationConfig().camera()
STD, SHARE = 0.5, 0.03
CONFIG = MsckfConfig.from_settings({"filter.object_std": STD, "filter.object_size_share": SHARE})
W = CONFIG.filter.odometry_cov()
A, B = np.array([10.0, 1.0, 0.0]), np.array([12.0, -3.0, 0.5])


def _state(objects: dict[int, np.ndarray]) -> MsckfState:
    state = MsckfState(np.eye(4), 0, np.eye(6) * 1e-6)
    for oid, p in objects.items():
        state.add_object(oid, np.asarray(p, float), np.eye(3) * 0.05**2, np.zeros((3, state.dim)))
    return state


def _boxes(state: MsckfState, points, size=(20.0, 30.0)) -> np.ndarray:
    """Box rows of exact stereo centres of ``points``, every box ``size`` pixels."""
    z = observe(CAMERA, T_CAM_BODY, state.current_pose, np.asarray(points, float))
    return box_rows(z, np.tile(size, (z.shape[0], 1)), None, STD, SHARE)


def test_a_confused_label_keeps_its_object_on_boxes_and_not_on_plain_rows():
    state = _state({7: A, 8: B})
    tracker = ObjectTracker(0, CAMERA, T_CAM_BODY, CONFIG)
    z = _boxes(state, [A, B])
    ids = []
    for t in range(30):
        labels = np.array([5 if t % 10 == 9 else 4, 2])  # A boxed as class 5 now and then
        ids.append(tracker.assign(t, z, labels, state, W).ids.tolist())
    assert all(row == [7, 8] for row in ids)
    model = tracker.label_model
    assert model.pairs > 0 and model.disagreeing == 3  # t = 9, 19, 29
    # the object's label is the majority of its detections' (4), not a confused one
    assert tracker._labels_of(np.array([7, 8])).tolist() == [4, 2]
    # plain rows (no box sizes) keep labels as a hard rule
    plain = ObjectTracker(0, CAMERA, T_CAM_BODY, CONFIG)
    plain._add_labels(np.array([7]), np.array([4]))
    assert plain.assign(0, z[:1, :4], np.array([4]), state, W).ids.tolist() == [7]
    assert plain.assign(1, z[:1, :4], np.array([5]), state, W).ids.tolist() == [-1]


def test_label_ratio_is_learned_and_silent_where_a_label_is_unknown():
    model = LabelModel()
    unknown = model.log_ratio(np.array([-1, 0]), np.array([0, -1]))
    assert unknown[0, 0] == unknown[0, 1] == unknown[1, 1] == 0.0
    model.count(np.repeat([0, 1, 2], 100))
    model.add(np.zeros(97, np.int64), np.r_[np.zeros(95, np.int64), [1, 2]])
    ratio = model.log_ratio(np.array([0]), np.array([0, 1]))[0]
    c = 3.0 / 99.0
    frequency = 101.0 / 303.0
    np.testing.assert_allclose(ratio, [np.log((1 - c) / frequency), np.log(c / 2 / frequency)])
    # a confusion is unlikely, yet not beyond the gate's odds: evidence, not a veto
    p = CONFIG.tracking.gate_probability
    assert np.log((1 - p) / p) < ratio[1] < 0 < ratio[0]


def test_a_box_seen_in_the_left_image_only_is_named_for_the_record():
    state = _state({7: A, 8: B})
    tracker = ObjectTracker(0, CAMERA, T_CAM_BODY, CONFIG)
    za, zb = _boxes(state, [A, B])
    for t in range(3):
        tracker.assign(t, np.stack([za, zb]), None, state, W)
    left_only = za.copy()
    left_only[2:4] = np.nan
    far = zb.copy()
    far[2:4] = np.nan
    far[0] += 60.0  # beyond the left image's gate
    frame = tracker.assign(3, np.stack([left_only, far]), None, state, W)
    assert frame.ids.tolist() == [7, -1]
    # an object that took a stereo box this frame takes no second, monocular one
    frame = tracker.assign(4, np.stack([za, left_only]), None, state, W)
    assert frame.ids.tolist() == [7, -1]
    assert tracker.counters["detections_monocular_named"] == 1
