"""Boxes seen in the left image only kept for an object named later: how long, from which pose."""

from __future__ import annotations

import numpy as np

from teamslam.geometry import se3
from teamslam.msckf.filter.box_noise import box_rows
from teamslam.msckf.filter.models import observe
from teamslam.msckf.filter.state import MsckfState
from teamslam.msckf.objects.hindsight import (
    UnnamedBoxes,
    hindsight_horizon,
    rotation_given_translation,
)
from teamslam.msckf.objects.tracking import ObjectTracker
from teamslam.msckf.settings.values import MsckfConfig
from teamslam.sim.lissajous import T_CAM_BODY, SimulationConfig

SIM = SimulationConfig()
CAMERA = SIM.camera()
STD, SHARE = 0.5, 0.03


def _random_cov(rng: np.random.Generator, n: int) -> np.ndarray:
    a = rng.normal(size=(n, n))
    return a @ a.T + n * np.eye(n)


def test_the_rotation_noise_given_the_translation_is_the_conditional_covariance():
    """The Schur complement equals the inverse of the information's rotation block, and is the
    least rotation covariance over every translation's lever: ``J W Jᵀ ≥ J_φ W_φ|ρ J_φᵀ`` for any
    translation columns ``J_ρ``."""
    rng = np.random.default_rng(3)
    w = _random_cov(rng, 6)
    given = rotation_given_translation(w)
    np.testing.assert_allclose(given, np.linalg.inv(np.linalg.inv(w)[3:, 3:]), rtol=1e-10)
    j_phi = rng.normal(size=(2, 3))
    least = j_phi @ given @ j_phi.T
    for _ in range(50):
        j = np.concatenate([rng.normal(size=(2, 3)) * rng.uniform(0, 3), j_phi], axis=1)
        assert np.linalg.eigvalsh(j @ w @ j.T - least).min() > -1e-9
    # and a translation's columns reach it: J_ρ = −J_φ W_φρ W_ρρ⁻¹
    j_rho = -j_phi @ w[3:, :3] @ np.linalg.inv(w[:3, :3])
    j = np.concatenate([j_rho, j_phi], axis=1)
    np.testing.assert_allclose(j @ w @ j.T, least, rtol=1e-9, atol=1e-12)


def test_at_the_horizon_the_gate_holds_the_miss_probability_of_chance_boxes():
    """Boxes spread uniformly over the image: at the horizon's gap, the gate the odometry's
    rotation noise alone opens around a box — its Jacobian taken here by finite differences on a
    point a million metres along the box's ray — holds on average ``1 − p`` of the frame's
    boxes (Monte Carlo, 400 000 points); at twice the gap twice that."""
    rng = np.random.default_rng(11)
    width, height = SIM.image_size
    w = np.diag([0.02, 0.02, 0.02, 0.003, 0.002, 0.004]) ** 2
    w[3, 5] = w[5, 3] = 0.5 * 0.003 * 0.004
    uv = np.array([[500.0, 120.0], [320.0, 240.0]])
    count, p = 6, 0.99
    horizon = hindsight_horizon(CAMERA, T_CAM_BODY, uv, w, count, (width, height), p)
    k_inv = np.linalg.inv(CAMERA.intrinsics)
    given = rotation_given_translation(w)
    points = rng.uniform([0.0, 0.0], [width, height], size=(400_000, 2))
    for g, (u, v) in zip(horizon, uv, strict=True):
        assert 1.0 < g < 1e4
        p_cam = 1e6 * (k_inv @ np.array([u, v, 1.0]))
        p_world = (np.linalg.inv(T_CAM_BODY) @ np.r_[p_cam, 1.0])[:3]  # body at the origin
        j = np.zeros((2, 3))
        for a in range(3):
            step = np.zeros(6)
            step[3 + a] = 1e-7
            plus = observe(CAMERA, T_CAM_BODY, se3.exp(step), p_world[None])[0, :2]
            minus = observe(CAMERA, T_CAM_BODY, se3.exp(-step), p_world[None])[0, :2]
            j[:, a] = (plus - minus) / 2e-7
        for gap, expected in ((g, 1.0 - p), (2 * g, 2 * (1.0 - p))):
            s = gap * j @ given @ j.T
            r = points - np.array([u, v])
            inside = np.einsum("ki,ij,kj->k", r, np.linalg.inv(s), r) <= -2 * np.log1p(-p)
            chance = count * inside.mean()
            assert abs(chance / expected - 1.0) < 0.1, (gap, chance, expected)


def _window(poses: np.ndarray, frames: np.ndarray, cov: np.ndarray, t: int, size: int):
    """The window of the last ``size`` poses up to frame ``t``."""
    view = MsckfState(np.eye(4), 0, np.eye(6) * 1e-6)
    first = max(0, t - size + 1)
    view.poses, view.frames = poses[first : t + 1], frames[first : t + 1]
    view.robots = np.zeros(view.frames.size, np.int64)
    view.pose_fe = view.poses.copy()
    view._cov = cov[6 * first : 6 * (t + 1), 6 * first : 6 * (t + 1)].copy()
    return view


def _drive(
    tracker: ObjectTracker,
    w: np.ndarray,
    window: int,
    crowd: int = 0,
    live: list[int] | None = None,
    old: bool = False,
) -> list[int]:
    """A robot driving 0.5 m a frame towards an object seen in the left image only for frames
    0–3 (frame 2's box 40 px off: another object's), then in both images; the first ids.
    ``crowd``: after frame 3, say each kept frame held that many boxes; ``live``: a list to
    collect the id each frame's box got when it came; ``old``: the object is object 7 of the map,
    last seen long before (2 cm off, a covariance of 5 cm)."""
    c = np.array([10.0, 1.0, 0.3])
    frames = 8
    state = MsckfState(np.eye(4), 0, np.eye(6) * 1e-6)
    move = np.eye(4)
    move[:3, 3] = [0.5, 0.0, 0.0]
    for t in range(1, frames + 1):
        state.augment(move, t, w)
    for t in range(frames + 1):
        view = _window(state.poses, state.frames, state.cov, t, window)
        if old:
            view.add_object(7, c + 0.02, np.eye(3) * 0.05**2, np.zeros((3, view.dim)))
            view.object_last_seen[:] = -100
        z = observe(CAMERA, T_CAM_BODY, state.poses[t], c[None])
        box = box_rows(z, np.array([[20.0, 30.0]]), SIM.image_size, STD, SHARE)
        if t <= 3:
            box[:, 2:4] = np.nan
        if t == 2:
            box[:, 0] += 40.0
        frame = tracker.assign(t, box, None, view, w)
        if live is not None:
            live.append(int(frame.ids[0]))
        if t == 3 and crowd:
            tracker.unnamed.counts[:] = crowd
    return tracker.first_ids().tolist()


def test_a_confirmed_track_names_its_earlier_left_image_only_boxes_from_their_own_poses():
    """An object seen in the left image only for its first frames, then in both; the images'
    size unknown, so the window's rule: once its track is confirmed, the boxes of frames still
    in the window are named too — each where the track's point falls from the pose of its own
    frame (the robot drove 0.5 m a frame towards it, the box moved ~5 px), a box 40 px off is
    not; a box older than the window is not."""
    window = 6
    config = MsckfConfig.from_settings(
        {"filter.object_std": STD, "filter.object_size_share": SHARE, "filter.window": window}
    )
    w = config.filter.odometry_cov()
    tracker = ObjectTracker(0, CAMERA, T_CAM_BODY, config)
    ids: list[int] = []
    named = _drive(tracker, w, window, live=ids)
    assert ids[:4] == [-1, -1, -1, -1]  # no track yet: nothing to name them
    tid = ids[-1]
    assert tid >= 0
    # confirmed at frame 6 (three stereo boxes), when the window holds frames 1..6: frame 0's
    # box has left it, frame 2's is another object's
    assert named[:4] == [-1, tid, -1, tid]
    assert named[4:] == [tid] * 5
    assert tracker.counters["detections_named_in_hindsight"] == 2
    # the boxes used the pose of their own frame: from the newest pose, frame 3's box is
    # outside the gate (the track's point projects ~17 px away)
    c = np.array([10.0, 1.0, 0.3])
    pose_then, pose_now = np.eye(4), np.eye(4)
    pose_then[0, 3], pose_now[0, 3] = 1.5, 4.0
    z_now = observe(CAMERA, T_CAM_BODY, pose_now, c[None])[0]
    z_then = observe(CAMERA, T_CAM_BODY, pose_then, c[None])[0]
    assert abs(z_now[0] - z_then[0]) > 10.0


def test_boxes_past_the_window_are_named_from_their_frames_poses_within_the_horizon():
    """With the images' size known, a box seen in the left image only outlives the window (3
    frames) as long as the horizon allows: the track confirmed at frame 6 names frames 0, 1 and
    3 from the poses those frames had — not frame 2's box, 40 px off. With a hundred times the
    rotation noise (horizon under two frames) none is named; without an image size, the
    window's frames only (none here)."""
    window = 3
    config = MsckfConfig.from_settings(
        {"filter.object_std": STD, "filter.object_size_share": SHARE, "filter.window": window}
    )
    w = config.filter.odometry_cov()
    p = config.tracking.gate_probability
    centre = np.array([[320.0, 240.0]])
    assert hindsight_horizon(CAMERA, T_CAM_BODY, centre, w, 1, SIM.image_size, p)[0] > 6
    tracker = ObjectTracker(0, CAMERA, T_CAM_BODY, config, image_size=SIM.image_size)
    named = _drive(tracker, w, window)
    tid = named[-1]
    assert tid >= 0 and named == [tid, tid, -1, tid] + [tid] * 5
    assert tracker.counters["detections_named_in_hindsight"] == 3
    assert len(tracker.unnamed) == 1  # frame 2's box, kept until its horizon

    noisy = w.copy()
    noisy[3:, 3:] *= 100.0**2
    assert hindsight_horizon(CAMERA, T_CAM_BODY, centre, noisy, 1, SIM.image_size, p)[0] < 2
    tracker = ObjectTracker(0, CAMERA, T_CAM_BODY, config, image_size=SIM.image_size)
    assert _drive(tracker, noisy, window)[:4] == [-1] * 4

    tracker = ObjectTracker(0, CAMERA, T_CAM_BODY, config)
    assert _drive(tracker, w, window)[:4] == [-1] * 4


def test_a_name_in_hindsight_is_refused_where_the_objects_gate_holds_chance_boxes():
    """The same drive, the kept frames said to hold a thousand boxes each after they were kept
    (their horizon already set): the object's own gate around each box — the point's
    covariance, the gap's odometry noise and the box's — would hold more than the gate's miss
    probability of them by chance, so none is named; said to hold one each, all three are."""
    config = MsckfConfig.from_settings(
        {"filter.object_std": STD, "filter.object_size_share": SHARE, "filter.window": 3}
    )
    w = config.filter.odometry_cov()
    tracker = ObjectTracker(0, CAMERA, T_CAM_BODY, config, image_size=SIM.image_size)
    assert _drive(tracker, w, 3, crowd=1000)[:4] == [-1] * 4
    tracker = ObjectTracker(0, CAMERA, T_CAM_BODY, config, image_size=SIM.image_size)
    named = _drive(tracker, w, 3, crowd=1)
    assert named[:4] == [named[-1], named[-1], -1, named[-1]]


def test_kept_boxes_survive_a_checkpoint_and_an_old_checkpoint_keeps_the_window_rule():
    kept = UnnamedBoxes()
    pose = np.eye(4)
    pose[0, 3] = 2.0
    kept.keep(5, np.array([0, 2]), np.arange(14.0).reshape(2, 7), np.array([9.0, 30.0]), pose)
    kept.keep(6, np.array([1]), np.ones((1, 7)), np.array([np.inf]), np.eye(4))
    back = UnnamedBoxes.from_arrays(kept.arrays(), window=10)
    for name, value in kept.arrays().items():
        np.testing.assert_array_equal(back.arrays()[name], value)
    kept.drop(np.array([False, False, True]))
    assert kept.pose_frames.tolist() == [5] and kept.counts.tolist() == [2]
    old = UnnamedBoxes.from_arrays({"unnamed_keys": kept.keys, "unnamed": kept.boxes}, window=10)
    assert old.until.tolist() == [14.0, 14.0] and np.isnan(old.poses).all()


def test_an_object_of_the_map_seen_again_names_its_earlier_left_image_only_boxes():
    """The same drive towards an object of the map last seen long before: its boxes seen in the
    left image only are not named as they come (the object is not followed), and the first box
    seen in both images takes it again; then the kept boxes of frames 0, 1 and 3 are named too,
    from their own poses held against the map's point — not frame 2's, 40 px off."""
    window = 3
    config = MsckfConfig.from_settings(
        {"filter.object_std": STD, "filter.object_size_share": SHARE, "filter.window": window}
    )
    w = config.filter.odometry_cov()
    tracker = ObjectTracker(0, CAMERA, T_CAM_BODY, config, image_size=SIM.image_size)
    live: list[int] = []
    named = _drive(tracker, w, window, live=live, old=True)
    assert live[:4] == [-1] * 4 and live[4:] == [7] * 5
    assert named == [7, 7, -1, 7] + [7] * 5
    assert tracker.counters["detections_named_in_hindsight"] == 3
