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


def _at_pixel(u: float, v: float, depth: float) -> np.ndarray:
    """The body-frame point (identity pose) seen at pixel ``(u, v)`` of the left image."""
    p_cam = depth * np.linalg.solve(CAMERA.intrinsics, [u, v, 1.0])
    return (np.linalg.inv(T_CAM_BODY) @ np.r_[p_cam, 1.0])[:3]


def test_a_box_cut_by_the_border_bounds_its_object_from_one_side():
    """An object 200 px wide whose centre has left the image 80 px beyond its left border shows
    a visible part 20.5 px wide (left image only): its centre lies 90 px inward of the object's,
    4.4 σ of the cut-box noise, beyond the gate — yet the object is predicted beyond the visible
    centre towards the border that cut it, which is where a cut box puts it: named. The same box
    against an object predicted 110 px inward of it is not."""
    size = (640, 480)
    z = np.array([[9.75, 200.0, np.nan, np.nan]])
    row = box_rows(z, np.array([[20.5, 30.0]]), size, STD, SHARE)
    assert row[0, 6] == 1 and row[0, 7] == 0  # cut in u, at the left border
    noise = STD**2 + (SHARE * 20.5) ** 2 + 20.5**2  # the cut coordinate's variance
    assert (9.75 + 80.0) ** 2 / noise > 9.21  # beyond χ²(2)'s 0.99 gate as a plain residual
    for u, named in ((-80.0, True), (120.0, False)):
        state = _state({7: _at_pixel(u, 200.0, 8.0)})
        tracker = ObjectTracker(0, CAMERA, T_CAM_BODY, CONFIG, image_size=size)
        frame = tracker.assign(1, row, None, state, W)
        assert frame.ids.tolist() == ([7] if named else [-1])


def test_pair_distances_equal_each_pairs_own_and_vanish_when_censored():
    from teamslam.msckf.objects.tracking import _censor, _pair_d2

    rng = np.random.default_rng(0)
    a = rng.normal(size=(3, 4, 4))
    s = a @ np.swapaxes(a, 1, 2) + np.eye(4)
    pred, z = rng.normal(size=(3, 4)) * 5, rng.normal(size=(2, 4)) * 5
    noise = rng.uniform(0.5, 2.0, size=(3, 2, 4))
    r = z[None] - pred[:, None]
    d2 = _pair_d2(s, r, noise)
    for t in range(3):
        for j in range(2):
            cov = s[t] + np.diag(noise[t, j])
            assert np.isclose(d2[t, j], r[t, j] @ np.linalg.solve(cov, r[t, j]))
    np.testing.assert_allclose(_pair_d2(s, _censor(r, np.zeros((1, 2, 4))), noise), d2)
    # every coordinate censored on the side each residual lies: zero distance
    sides = np.where(r > 0, -1, 1)
    assert np.allclose(_pair_d2(s, _censor(r, sides), noise), 0)


def test_a_box_an_occluder_cut_short_keeps_its_object_and_a_smaller_box_inside_does_not():
    """An object seen whole as a 60 × 40 px box, then with its right 40 % hidden (a 36 px box
    whose centre lies 12 px left of the object's, 10 σ of the box noise): its left edge is the
    object's, so it stays the object's. A 20 px box of another object inside the first one's,
    8 px left of its centre, reaches neither of its edges: not taken, though an occluder could
    have hidden 40 px of a box around it."""
    state = MsckfState(np.eye(4), 0, np.eye(6) * 1e-8)
    state.add_object(7, A, np.eye(3) * 0.005**2, np.zeros((3, state.dim)))  # known: ~0.2 px
    tracker = ObjectTracker(0, CAMERA, T_CAM_BODY, CONFIG)
    whole = _boxes(state, [A], size=(60.0, 40.0))
    for t in range(5):
        assert tracker.assign(t, whole, None, state, W).ids.tolist() == [7]
    extent = tracker.extents.of(np.array([7]))[0]
    disparity = whole[0, 0] - whole[0, 2]
    np.testing.assert_allclose(extent * disparity, [60.0, 40.0])
    hidden = whole.copy()
    hidden[0, 4] = 36.0
    hidden[0, [0, 2]] -= 12.0
    plain = ObjectTracker(0, CAMERA, T_CAM_BODY, CONFIG)  # no size learned: the centre as is
    assert plain.assign(0, hidden, None, state, W).ids.tolist() == [-1]
    assert tracker.assign(5, hidden, None, state, W).ids.tolist() == [7]
    inside = whole.copy()
    inside[0, 4] = 20.0
    inside[0, [0, 2]] -= 8.0
    assert tracker.assign(6, inside, None, state, W).ids.tolist() == [-1]
