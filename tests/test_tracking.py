"""Each robot's tracker of its own detections: gating, assignment, confirmation, clutter, misses,
the detection format, the MOT metrics, and the id path left untouched."""

from __future__ import annotations

import numpy as np
import pytest

from teamslam.datasets.identity import strip_object_ids
from teamslam.datasets.model import DatasetError, FrameDetections
from teamslam.datasets.storage import load_dataset, save_dataset
from teamslam.errors import InputError
from teamslam.eval.tracking import (
    hypotheses_of,
    idf1_losses,
    merge_audit,
    mot_metrics,
    object_truth,
    revisit_precision,
    tracking_metrics,
)
from teamslam.msckf.agent import MsckfAgent
from teamslam.msckf.filter.models import observe
from teamslam.msckf.filter.state import MsckfState
from teamslam.msckf.objects.tracking import ObjectTracker, track_id_base
from teamslam.msckf.settings.values import MsckfConfig
from teamslam.sim.lissajous import T_CAM_BODY, SimulationConfig, lissajous_team

CAMERA = SimulationConfig().camera()
CONFIG = MsckfConfig.from_settings({"filter.object_std": 2.0})
W = CONFIG.filter.odometry_cov()


def _state(objects: dict[int, np.ndarray] | None = None, std: float = 0.05) -> MsckfState:
    """A state at the identity pose holding ``objects`` (uncorrelated, ``std`` metres)."""
    state = MsckfState(np.eye(4), 0, np.eye(6) * 1e-6)
    for oid, p in (objects or {}).items():
        state.add_object(oid, np.asarray(p, float), np.eye(3) * std**2, np.zeros((3, state.dim)))
    return state


def _z(state: MsckfState, points) -> np.ndarray:
    """Exact stereo measurements of world ``points`` from the state's current pose."""
    return observe(CAMERA, T_CAM_BODY, state.current_pose, np.asarray(points, float))


def _tracker(changes=None) -> ObjectTracker:
    return ObjectTracker(0, CAMERA, T_CAM_BODY, CONFIG.with_(changes))


# body frame: x forward, y left, z up — points ahead of the robot
A, B = np.array([10.0, 1.0, 0.0]), np.array([12.0, -3.0, 0.5])


def test_gate_keeps_near_detections_and_refuses_far_ones():
    state = _state({7: A})
    tracker = _tracker()
    near = _z(state, [A])[0] + [3.0, -2.0, 3.0, -2.0]  # ~2 σ
    far = _z(state, [A])[0] + [40.0, 0.0, 40.0, 0.0]  # ~20 σ: outside any gate
    frame = tracker.assign(0, np.stack([near, far]), None, state, W)
    assert frame.ids.tolist() == [7, -1]
    assert tracker.n_tracks == 1  # the far one starts a tentative track


def test_assignment_is_one_to_one_and_global():
    a2 = A + np.array([0.0, 0.6, 0.0])
    state = _state({1: A, 2: a2}, std=0.5)
    tracker = _tracker({"tracking.gate_probability": 0.999999})
    za, zb = _z(state, [A, a2])
    # detection 0 is nearer object 1, but only detection 1 explains object 1 well: a greedy
    # choice for detection 0 would cost more in total than the global assignment
    between = za + 0.45 * (zb - za)
    frame = tracker.assign(0, np.stack([between, za]), None, state, W)
    assert frame.ids.tolist() == [2, 1]
    # two detections of one object: one gets it, the other starts a track
    state = _state({1: A})
    frame = _tracker().assign(0, np.stack([za, za + 0.5]), None, state, W)
    assert frame.ids.tolist() == [1, -1]
    assert tracker.n_tracks == 0


def test_classes_must_agree():
    tracker = _tracker()
    state = _state()
    z = _z(state, [A])
    for t in range(3):
        frame = tracker.assign(t, z, np.array([4]), state, W)
    assert frame.ids[0] >= track_id_base(0)  # confirmed with class 4
    tid = int(frame.ids[0])
    other = tracker.assign(3, z, np.array([5]), state, W)
    assert other.ids.tolist() == [-1]  # another class: a new tentative track
    again = tracker.assign(4, np.concatenate([z, z]), np.array([5, 4]), state, W)
    assert again.ids[1] == tid


def test_confirmed_after_m_hits_in_n_frames_with_the_earlier_detections():
    tracker = _tracker({"tracking.confirm_hits": 3, "tracking.confirm_frames": 4})
    state = _state()
    z = _z(state, [B])
    assert tracker.assign(0, z, None, state, W).ids.tolist() == [-1]
    assert tracker.assign(1, np.zeros((0, 4)), None, state, W).ids.size == 0  # a miss
    assert tracker.assign(2, z + 0.5, None, state, W).ids.tolist() == [-1]
    frame = tracker.assign(3, z - 0.5, None, state, W)
    (tid, frames, zs), *rest = frame.confirmed
    assert not rest and frame.ids.tolist() == [tid]
    assert frames.tolist() == [0, 2]
    np.testing.assert_allclose(zs, np.stack([z[0], z[0] + 0.5]))
    # too late: 3 hits only after 4 frames
    late = _tracker({"tracking.confirm_hits": 3, "tracking.confirm_frames": 4})
    for t, zt in ((0, z), (1, z), (2, np.zeros((0, 4))), (3, np.zeros((0, 4))), (4, z)):
        frame = late.assign(t, zt, None, state, W)
    assert late.counters["tracks_confirmed"] == 0 and late.counters["tracks_dropped"] == 1


def test_a_lone_false_detection_never_reaches_the_filter():
    tracker = _tracker()
    state = _state({3: A})
    za = _z(state, [A])
    clutter = _z(state, [B])
    seen = []
    for t in range(10):
        z = np.concatenate([za, clutter]) if t == 2 else za
        seen.extend(tracker.assign(t, z, None, state, W).ids.tolist())
    assert set(seen) == {3, -1} and seen.count(-1) == 1
    assert tracker.n_tracks == 0 and tracker.counters["tracks_dropped"] == 1


def test_a_missed_object_keeps_its_id():
    tracker = _tracker()
    state = _state({9: A})
    za = _z(state, [A])
    ids = [tracker.assign(t, za, None, state, W).ids.tolist() for t in range(2)]
    for t in range(2, 8):  # not detected for six frames
        tracker.assign(t, np.zeros((0, 4)), None, state, W)
    ids.append(tracker.assign(8, za + 1.0, None, state, W).ids.tolist())
    assert ids == [[9], [9], [9]]
    # and a confirmed track not yet in the state survives fewer than N missed frames
    tracker = _tracker()
    state = _state()
    zb = _z(state, [B])
    for t in range(3):
        tid = tracker.assign(t, zb, None, state, W).ids[0]
    for t in range(3, 3 + tracker.frames_allowed - 1):
        tracker.assign(t, np.zeros((0, 4)), None, state, W)
    assert tracker.assign(3 + tracker.frames_allowed - 1, zb, None, state, W).ids[0] == tid


def test_objects_of_the_persistent_map_are_predicted():
    state = _state({5: A})
    state.retire_objects(np.array([0]))
    assert state.n_objects == 0 and len(state.retired) == 1
    frame = _tracker().assign(0, _z(state, [A]), None, state, W)
    assert frame.ids.tolist() == [5]


def test_mot_metrics_by_hand():
    # frames: 0: a→1, b→2 | 1: a→1, b→-, clutter→9 | 2: a→3, b→2 | 3: a→3, b→2
    offsets = np.array([0, 2, 5, 7, 9])
    truth = np.array([0, 1, 0, 1, -1, 0, 1, 0, 1])
    hyp = np.array([1, 2, 1, -1, 9, 3, 2, 3, 2])
    m = mot_metrics(offsets, truth, hyp)
    assert (m["gt"], m["fn"], m["fp"], m["id_switches"], m["fragmentations"]) == (8, 1, 1, 1, 1)
    assert m["mota"] == pytest.approx(1 - 3 / 8)
    # IDF1: a↔1 or a↔3 agree on 2 frames, b↔2 on 3: IDTP 5, 8 truths, 8 hypotheses
    assert m["idtp"] == 5 and m["idf1"] == pytest.approx(10 / 16)
    assert (m["objects_true"], m["objects_created"], m["false_objects"]) == (2, 4, 1)
    # the IDF1 loss 8 + 8 − 2·5 = 6: one miss, one false, a's two detections under its other id
    # (1 and 2 frames from its mapped id's: revisits beyond a gap of 0, one each beyond 1)
    losses = idf1_losses(offsets, truth, hyp, revisit_gap=0)
    assert losses["loss"] == 8 + 8 - 2 * m["idtp"] == 6
    assert (losses["missed"], losses["false"], losses["wrong_revisit"]) == (1, 1, 2)
    assert losses["wrong_within_pass"] == losses["wrong_unmapped"] == 0
    losses = idf1_losses(offsets, truth, hyp, revisit_gap=1)
    assert (losses["wrong_revisit"], losses["wrong_within_pass"]) == (1, 1)


@pytest.fixture(scope="module")
def cluttered():
    return lissajous_team(robots=2, steps=40, objects=80, seed=3, clutter=0.3, miss=0.1, classes=3)


def test_detection_format_round_trip_and_strip(tmp_path, cluttered):
    robot = cluttered.robots[0]
    det = robot.detections
    assert det is not None and (det.truth == -1).any()
    # the oracle's observations are the true detections, the same rows
    assert robot.objects.ids.size == int((det.truth >= 0).sum())
    none = strip_object_ids(cluttered, to="none")
    assert none.object_id_scope == "none" and none.robots[0].objects.ids.size == 0
    save_dataset(none, tmp_path / "d")
    back = load_dataset(tmp_path / "d")
    for a, b in zip(none.robots, back.robots, strict=True):
        for name in ("offsets", "measurements", "classes", "truth"):
            np.testing.assert_array_equal(getattr(a.detections, name), getattr(b.detections, name))
    # a global-id dataset without detections: its observations become the detections
    plain = lissajous_team(robots=1, steps=10, objects=40, seed=1)
    stripped = strip_object_ids(plain, to="none").robots[0].detections
    np.testing.assert_array_equal(stripped.truth, plain.robots[0].objects.ids)
    with pytest.raises(DatasetError, match="truth"):
        FrameDetections([0, 2], np.zeros((2, 4)), truth=np.array([0]))
    with pytest.raises(DatasetError, match="already"):
        strip_object_ids(none, to="none")


def test_agent_tracks_clutter_without_confirming_false_objects(cluttered):
    none = strip_object_ids(cluttered, to="none")
    config = MsckfConfig.from_settings({"filter.object_std": 2.0, "filter.window": 10})
    agents = []
    for i, robot in enumerate(none.robots):
        agent = MsckfAgent(i, none.calibration, robot, config)
        for t in range(robot.frames):
            agent.step(t)
        agents.append(agent)
        # every object in the state was named from detections of real objects
        hyp = np.concatenate(agent.tracker.log)
        truth = robot.detections.truth
        for oid in agent.state.object_ids.tolist():
            assert np.all(truth[hyp == oid] >= 0)
    metrics = tracking_metrics(none, hypotheses_of(agents))
    assert metrics["team"]["false_objects"] == 0
    assert metrics["team"]["idf1"] > 0.8
    assert sum(a.counters["objects_initialised"] for a in agents) > 10


def test_ids_path_is_untouched_by_detections(cluttered):
    """A robot with ids ignores its detections: the same estimate bit for bit."""
    robot = cluttered.robots[1]
    bare = type(robot)(
        robot.T_world_body,
        robot.odometry,
        robot.features,
        robot.objects,
        robot.timestamps,
        robot.object_classes,
    )
    config = MsckfConfig.from_settings({"filter.object_std": 2.0, "filter.window": 10})
    runs = []
    for seq in (robot, bare):
        agent = MsckfAgent(1, cluttered.calibration, seq, config)
        assert agent.tracker is None
        for t in range(seq.frames):
            agent.step(t)
        runs.append(agent.state)
    np.testing.assert_array_equal(runs[0].poses, runs[1].poses)
    np.testing.assert_array_equal(runs[0].cov, runs[1].cov)


def test_an_object_unseen_for_long_is_taken_again_only_unambiguously():
    state = _state({1: A}, std=1.0)  # last seen at frame 0, uncertain by now
    za = _z(state, [A])
    two = np.stack([za[0] + [6.0, 0.0, 6.0, 0.0], za[0] - [6.0, 0.0, 6.0, 0.0]])
    tracker = _tracker()
    frame = tracker.assign(10, two, None, state, W)
    assert frame.ids.tolist() == [-1, -1]
    assert tracker.counters["revisits_refused"] == 1 and tracker.n_tracks == 2
    # the same pair seen recently is no revisit: the nearer detection gets the object
    recent = _tracker()
    assert sorted(recent.assign(3, two, None, state, W).ids.tolist()) == [-1, 1]
    # alone in its gate, the long-unseen object takes its detection (a re-identification)
    alone = _tracker()
    assert alone.assign(10, za, None, state, W).ids.tolist() == [1]
    assert alone.revisits == [(10, 0, 1)] and alone.counters["revisits_taken"] == 1


def test_an_object_followed_frame_to_frame_is_served_before_a_long_unseen_one():
    """Pass 1 (targets seen within N frames) before pass 2: a long-unseen object whose wide
    covariance puts the detection nearer in Mahalanobis distance does not take it from the
    object seen in the last frame."""
    b = A + np.array([0.0, 0.3, 0.0])
    state = _state({1: A}, std=0.05)
    state.add_object(2, b, np.eye(3), np.zeros((3, state.dim)))  # 1 m, unseen since frame 0
    state.mark_seen(state.object_slots(np.array([2])), 0)
    state.mark_seen(state.object_slots(np.array([1])), 9)
    za, zb = _z(state, [A, b])
    z = za + 0.3 * (zb - za)
    tracker = _tracker()
    assert tracker.assign(10, z[None], None, state, W).ids.tolist() == [1]
    assert tracker.n_tracks == 0


def _d2(tracker: ObjectTracker, state: MsckfState, z: np.ndarray) -> np.ndarray:
    """Squared Mahalanobis distance of each (target, detection) pair, as the tracker gates."""
    _, _, _, pred, s, _, _, _ = tracker._predict(0, state, W)
    r = z[None, :, :] - pred[:, None, :]
    return np.einsum("tdi,tdi->td", r, np.linalg.solve(s[:, None], r[..., None])[..., 0])


def test_assignment_weighs_a_pair_against_leaving_both_to_miss_and_birth():
    """Two poor pairs (each inside the gate) never beat one good pair plus a miss and a birth:
    assigning the most pairs would give object 1's clear detection to object 2."""
    a2 = A + np.array([0.0, 1.0, 0.0])
    state = _state({1: A, 2: a2}, std=0.3)
    tracker = _tracker()
    za, zb = _z(state, [A, a2])
    x = za + 0.02 * (zb - za)  # object 1's, also inside object 2's gate
    y = za - (zb - za)  # on the far side of object 1, outside object 2's gate
    d2 = _d2(tracker, state, np.stack([x, y]))
    g = tracker.gate
    assert d2[0, 0] < d2[1, 0] < g and d2[0, 1] < g < d2[1, 1]
    assert d2[1, 0] + d2[0, 1] > d2[0, 0] + g  # the two poor pairs cost more
    frame = tracker.assign(0, np.stack([x, y]), None, state, W)
    assert frame.ids.tolist() == [1, -1]
    # …and the other way round when the two pairs are good: both assigned
    frame = _tracker().assign(0, np.stack([zb, za]), None, state, W)
    assert frame.ids.tolist() == [2, 1]


def test_outer_gate_keeps_a_heavy_tailed_detection_on_its_object():
    state = _state({4: A}, std=0.05)
    state.mark_seen(state.object_slots(np.array([4])), 0)
    tracker = _tracker()
    za = _z(state, [A])[0]
    direction = np.array([1.0, 0.0, 1.0, 0.0])
    # a detection between the gate and the outer gate of its object, and no other target
    for k in np.linspace(1.0, 40.0, 400):
        d2 = _d2(tracker, state, (za + k * direction)[None])[0, 0]
        if tracker.gate < d2 < tracker.birth_gate:
            break
    off = za + k * direction
    assert tracker.gate < d2 < tracker.birth_gate
    assert tracker.assign(1, off[None], None, state, W).ids.tolist() == [4]
    # with the outer gate off it is left alone, and starts no track next to its object
    off_tracker = _tracker({"tracking.birth_probability": CONFIG.tracking.gate_probability})
    assert off_tracker.assign(1, off[None], None, state, W).ids.tolist() == [-1]
    # two such detections: ambiguous, neither is given the object and neither starts a track
    mirror = za - k * direction
    both = _tracker()
    assert both.assign(1, np.stack([off, mirror]), None, state, W).ids.tolist() == [-1, -1]
    assert both.n_tracks == 0 and both.counters["detections_near_object"] == 2


def test_a_detection_near_an_object_that_took_another_one_starts_a_track():
    """A detector boxes an object once per frame: a second detection next to an object that
    took its own is a new object (a car parked behind another), not the same one twice."""
    state = _state({6: A}, std=0.05)
    tracker = _tracker()
    za = _z(state, [A])[0]
    near = za + np.array([12.0, 0.0, 12.0, 0.0])
    assert tracker.gate < _d2(tracker, state, near[None])[0, 0] < tracker.birth_gate
    assert tracker.assign(0, np.stack([za, near]), None, state, W).ids.tolist() == [6, -1]
    assert tracker.n_tracks == 1


@pytest.mark.parametrize("where", ["state", "persistent map"])
def test_a_revisited_object_keeps_its_id_after_a_track_started_on_it(where):
    """A revisited object whose first detection was ambiguous (two in its gate: both start
    tracks) is continued by the track whose next detections are alone in its gate: when the
    track is confirmed it takes the object's id instead of a new one."""
    state = _state({1: A}, std=1.0)  # last seen at frame 0, uncertain by now
    if where == "persistent map":
        state.retire_objects(np.array([0]))
    za = _z(state, [A])[0]
    tracker = _tracker()
    step = np.array([6.0, 0.0, 6.0, 0.0])
    two = np.stack([za + step, za - step])
    assert tracker.assign(10, two, None, state, W).ids.tolist() == [-1, -1]
    assert tracker.n_tracks == 2
    # the next detections are inside the gate of a tentative track and of the object
    d2 = _d2(tracker, state, za[None])[:, 0]
    assert (d2 < tracker.gate).sum() >= 2
    assert tracker.assign(11, za[None], None, state, W).ids.tolist() == [-1]
    frame = tracker.assign(12, za[None], None, state, W)
    assert frame.ids.tolist() == [1] and frame.confirmed == []
    assert tracker.revisits == [(12, 0, 1)] and tracker.counters["revisits_taken"] == 1
    # the filter then holds it (re-entered from the persistent map) and sees it
    if where == "persistent map":
        state.reenter_objects(np.array([1]), 12)
    state.mark_seen(state.object_slots(np.array([1])), 12)
    for t in range(13, 17):  # it keeps its id; the other track expires unconfirmed
        assert tracker.assign(t, za[None], None, state, W).ids.tolist() == [1]
        state.mark_seen(state.object_slots(np.array([1])), t)
    assert tracker.n_tracks == 0 and tracker.counters["tracks_confirmed"] == 0


def test_no_reidentification_with_two_objects_in_the_gate():
    """Two long-unseen objects in a detection's gate: neither takes it (never guess), whether
    or not a tentative track also holds it."""
    a2 = A + np.array([0.0, 0.5, 0.0])
    state = _state({1: A, 2: a2}, std=1.0)
    za, zb = _z(state, [A, a2])
    mid = 0.5 * (za + zb)
    d2 = _d2(_tracker(), state, mid[None])[:, 0]
    assert np.all(d2 < _tracker().gate)
    tracker = _tracker()
    ids = [tracker.assign(t, mid[None], None, state, W).ids[0] for t in range(10, 14)]
    assert 1 not in ids and 2 not in ids
    assert tracker.revisits == [] and tracker.counters["revisits_refused"] >= 2
    # the track the detections start is confirmed as an object of its own
    assert ids[-1] >= track_id_base(0)


def test_revisit_precision_by_hand():
    offsets = np.array([0, 1, 2, 3, 4])
    truth = np.array([5, 5, 6, 5])
    hyp = np.array([1, 1, 1, 1])
    # frame 2: object 1 was truth 5 before, the detection is 6 (wrong); frame 3: right;
    # frame 0: nothing before, not judged
    assert revisit_precision(offsets, truth, hyp, [(2, 0, 1), (3, 0, 1), (0, 0, 1)]) == (1, 2)


def test_merge_audit_by_hand():
    first = np.array([10, 10, 20, 20, 30, 30, 40, 10, 50, 10, 10, 10, 10])
    truth = np.array([1, 1, 2, 2, 1, 1, 2, 1, 2, 2, 2, 2, 2])
    merges = [(30, 10), (40, 10), (20, 99), (50, 10)]
    audit = merge_audit(truth, first, merges)
    # 30 → 10 right, 40 → 10 and 50 → 10 wrong (one pass of object 2 into 10, twice), 99 never
    # named: unjudged. Object 10 took more of object 2's detections after the merges than it
    # had of object 1's before them: each merge is judged by what 10 was before the new one
    assert (audit["merges"], audit["right"], audit["wrong"], audit["unjudged"]) == (4, 1, 2, 1)
    assert (audit["passes"], audit["passes_wrong"], audit["largest_pass"]) == (2, 1, 2)
    with pytest.raises(InputError, match="13 detections but 12 ids"):
        merge_audit(truth, first[:-1], merges)


def test_a_long_unseen_object_that_cannot_be_detected_takes_no_detection():
    """Re-identification asks for targets a detector could report: one predicted beside the
    camera, outside the image, takes no detection, however alone it is in that detection's
    gate (its wide gate covers the whole image); without the image's size the gate decides."""
    beside = np.array([1.2, 2.5, 0.0])  # 1.2 m ahead, 2.5 m to the left: far outside the image
    state = _state({1: beside}, std=3.0)  # last seen at frame 0, uncertain by now
    z = _z(state, [A])  # an object not in the map, in the image
    assert _z(state, [beside])[0, 0] < 0  # predicted left of the image
    unknown_size = ObjectTracker(0, CAMERA, T_CAM_BODY, CONFIG)
    assert unknown_size.assign(10, z, None, state, W).ids.tolist() == [1]  # the gate's answer
    sized = ObjectTracker(0, CAMERA, T_CAM_BODY, CONFIG, image_size=(640, 480))
    assert sized.assign(10, z, None, state, W).ids.tolist() == [-1]
    assert sized.revisits == [] and sized.n_tracks == 1


def test_object_truth_is_the_majority_of_each_named_objects_detections():
    truth = np.array([3, 3, 5, -1, -1, 5, 7, 7, 2, 9])
    hyp = np.array([10, 10, 10, 11, 11, 11, 12, 12, 12, -1])
    ids, team = object_truth(truth, hyp)
    np.testing.assert_array_equal(ids, [10, 11, 12])
    # 10: mostly 3; 11: mostly false detections; 12: two of 7 against one of 2
    np.testing.assert_array_equal(team, [3, -1, 7])
    ids, team = object_truth(np.array([4, 1]), np.array([6, 6]))  # a tie: the smaller true id
    assert team.tolist() == [1]
    assert object_truth(np.array([1]), np.array([-1]))[0].size == 0
    with pytest.raises(InputError, match="2 detections but 3 hypotheses"):
        object_truth(np.array([1, 2]), np.array([1, 2, 3]))


def test_association_of_tracked_objects_is_scored_by_their_detections_truth():
    """Robots that name their own detections: the inter-robot pairs are scored by the true
    object of each named object (no id truth exists), as an independent scoring gives."""
    from teamslam.association import score_correspondences
    from teamslam.eval.metrics import team_metrics
    from teamslam.msckf.configure import config_for
    from teamslam.msckf.team import run_team

    team = strip_object_ids(
        lissajous_team(robots=3, steps=50, seed=4, landmarks=500, miss=0.05), to="none"
    )
    assert team.object_identity.size == 0
    result = run_team(team, config_for(team, {"filter.window": 6}), progress=False)
    metrics = team_metrics(team, result)
    # each robot's merges judged from what its driver recorded of its tracker
    for entry, record in zip(
        metrics["tracking"]["robots"], result.extra["tracking_records"], strict=True
    ):
        audit = entry["merges"]
        assert audit["merges"] == len(record["tracking_merges"])
        assert audit["right"] + audit["wrong"] + audit["unjudged"] == audit["merges"]
        assert entry["object_overconfidence"] >= 1.0
    links = metrics["association"]["links"]
    scored = [link for link in links.values() if link.get("precision") is not None]
    assert scored, links
    assert metrics["association"]["team"]["correct"] > 0
    truths = [
        object_truth(r.detections.truth, np.asarray(h))
        for r, h in zip(team.robots, result.extra["tracking_hypotheses"], strict=True)
    ]
    for key, link in links.items():
        i, j = map(int, key.split("-"))
        pairs = np.asarray(result.extra["association"][i][str(j)]["pairs"]).reshape(-1, 2)
        pairs = pairs[
            np.isin(pairs[:, 0], result.object_ids[i]) & np.isin(pairs[:, 1], result.object_ids[j])
        ]
        own = score_correspondences(
            pairs, result.object_ids[i], result.object_ids[j], truths[i], truths[j]
        )
        assert (link["correct"], link["wrong"], link["shared"]) == (
            own.correct,
            own.wrong,
            own.shared,
        )
