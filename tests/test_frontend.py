"""Stereo front-end: tracking, stereo matching with its outlier gate, markers, rectification,
settings, and the error without OpenCV — checked against a rendered room's exact truth."""

from __future__ import annotations

import sys

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2", reason="the images extra (OpenCV) is not installed")

from teamslam.errors import InputError  # noqa: E402
from teamslam.frontend import (  # noqa: E402
    FeatureTracker,
    FrontendConfig,
    MarkerDetector,
    StereoRig,
    diagonal_centre,
    match_stereo,
)
from teamslam.frontend._cv import require_cv2  # noqa: E402
from teamslam.frontend.tracking import warp_change  # noqa: E402
from teamslam.sim.render import (  # noqa: E402
    T_CAM_BODY,
    RenderConfig,
    apply_effects,
    render_stereo,
    render_team,
)

SMALL = {"image_size": (320, 240), "focal": 210.0, "marker_size": 0.9, "steps": 6, "robots": 1}


@pytest.fixture(scope="module")
def sequence():
    team = render_team(RenderConfig(**SMALL))
    rng = np.random.default_rng(3)
    frames = [render_stereo(team.room, team.T_world_cam(0, k), rng) for k in range(7)]
    return team, frames


def test_tracking_keeps_ids_with_subpixel_accuracy(sequence):
    team, frames = sequence
    tracker = FeatureTracker((320, 240), FrontendConfig(max_track_warp=0.0))  # tracks not renewed
    ids0, uv0 = tracker.track(frames[0][0])
    assert ids0.size >= 100
    np.testing.assert_array_equal(ids0, np.arange(ids0.size))  # fresh ids count up
    world = dict(zip(ids0.tolist(), team.points_behind(0, 0, uv0), strict=True))
    errors = []
    for k in range(1, 7):
        ids, uv = tracker.track(frames[k][0])
        assert np.unique(ids).size == ids.size
        old = ids < ids0.size
        truth = team.project(0, k, np.array([world[i] for i in ids[old].tolist()]))
        errors.append(np.linalg.norm(uv[old] - truth[:, :2], axis=1))
    # most first-frame tracks survive six frames under their original ids
    assert np.isin(ids0, ids).mean() > 0.6
    e = np.concatenate(errors)
    assert np.median(e) < 0.25
    assert np.mean(e < 1.0) > 0.97


def test_tracks_end_after_max_track_length_and_their_corners_start_new_ones(sequence):
    _, frames = sequence
    tracker = FeatureTracker((320, 240), FrontendConfig(max_track_length=3, max_track_warp=0.0))
    seen: dict[int, int] = {}
    counts = []
    for k in range(7):
        ids, _ = tracker.track(frames[k][0])
        for t in ids.tolist():
            seen[t] = seen.get(t, 0) + 1
        counts.append(len(ids))
    lengths = np.array(list(seen.values()))
    assert lengths.max() == 3  # followed for three frames, then ended
    assert np.mean(lengths == 3) > 0.5
    # the ended tracks' corners are taken again: the count of tracks does not fall
    assert min(counts[3:]) > 0.8 * counts[0]
    with pytest.raises(InputError, match="max_track_length"):
        FrontendConfig(max_track_length=1)


def _zoom_sequence(frames: int, scale: float) -> list[np.ndarray]:
    """A random texture seen by a camera approaching it: each frame magnified ``scale`` times
    the previous one about the image centre (320×240)."""
    rng = np.random.default_rng(5)
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (240, 320)).astype(np.float32), (0, 0), 1.5)
    texture = cv2.normalize(texture, None, 0, 255, cv2.NORM_MINMAX)
    out = []
    for k in range(frames):
        M = cv2.getRotationMatrix2D((159.5, 119.5), 0.0, scale**k)
        img = cv2.warpAffine(texture, M, (320, 240), flags=cv2.INTER_CUBIC)
        out.append(np.clip(img, 0, 255).astype(np.uint8))
    return out


def test_warp_change_measures_growth_and_shear_not_rotation():
    c, s = np.cos(0.7), np.sin(0.7)
    A = np.array([[[c, -s], [s, c]], [[1.1, 0.0], [0.0, 1.1]], [[1.0, 0.2], [0.0, 1.0]]])
    change = warp_change(A)
    assert change[0] == pytest.approx(0.0, abs=1e-12)
    assert change[1] == pytest.approx(np.log(1.1))
    # a shear stretches one direction: the larger singular value of [[1, t], [0, 1]]
    assert change[2] == pytest.approx(np.log((0.2 + np.sqrt(0.2**2 + 4)) / 2))
    assert warp_change(np.zeros((1, 2, 2)))[0] == np.inf


def test_tracks_end_when_their_warp_exceeds_max_track_warp():
    scale = 1.03
    images = _zoom_sequence(9, scale)

    def lengths(config):
        tracker = FeatureTracker((320, 240), config)
        seen: dict[int, int] = {}
        changes = np.zeros(0)
        for k, img in enumerate(images):
            ids, _ = tracker.track(img)
            for t in ids.tolist():
                seen[t] = seen.get(t, 0) + 1
            if k == 0:
                first_ids = ids
            if k == 3:  # the warps of the first frame's tracks, three frames later
                changes = warp_change(tracker._A[np.isin(ids, first_ids)])
        return np.array(list(seen.values())), changes

    unlimited, changes = lengths(FrontendConfig(max_track_warp=0.0))
    assert changes.size > 50
    # the track's affine warp follows the magnification: 3 frames of 3 % each
    assert np.median(changes) == pytest.approx(3 * np.log(scale), abs=0.01)
    assert unlimited.max() == len(images)
    limited, _ = lengths(FrontendConfig(max_track_warp=0.1))
    # 3 frames is a warp of 0.089, 4 frames 0.118: no track is followed for more than 4 frames
    assert limited.max() <= 4
    assert np.mean(limited == 4) > 0.3
    with pytest.raises(InputError, match="max_track_warp"):
        FrontendConfig(max_track_warp=-0.1)


def test_stereo_matches_true_disparity_within_a_pixel(sequence):
    team, frames = sequence
    left, right = frames[0]
    corners = cv2.goodFeaturesToTrack(left, 300, 0.005, 5).reshape(-1, 2).astype(float)
    camera = team.config.camera()
    config = FrontendConfig()
    m = match_stereo(left, right, corners, config.disparity_range(camera.fx_baseline), config)
    assert m.accepted.mean() > 0.8
    truth = team.project(0, 0, team.points_behind(0, 0, corners[m.accepted]))
    err = np.abs(m.uv_right[m.accepted] - truth[:, 2:])
    assert err.max() < 1.0
    assert np.median(err[:, 0]) < 0.2
    assert np.all(np.isnan(m.uv_right[~m.accepted]))


def _occlusion_pair():
    """Random texture at disparity 4 behind a textured square at disparity 20."""
    rng = np.random.default_rng(0)
    h, w = 120, 200
    back = cv2.GaussianBlur(rng.uniform(0, 255, (h, w + 40)).astype(np.float32), (0, 0), 1.2)
    front = cv2.GaussianBlur(rng.uniform(0, 255, (h, 60)).astype(np.float32), (0, 0), 1.2)
    left = back[:, 20 : 20 + w].copy()
    right = back[:, 24 : 24 + w].copy()
    x0 = 100  # the square covers columns x0 … x0 + 59 in the left image, 20 fewer in the right
    left[30:90, x0 : x0 + 60] = front[30:90]
    right[30:90, x0 - 20 : x0 + 40] = front[30:90]
    return left.astype(np.uint8), right.astype(np.uint8), x0


def test_left_right_check_rejects_an_occlusion():
    left, right, x0 = _occlusion_pair()
    # background hidden behind the square in the right image: left columns x0 − 16 … x0 − 1
    hidden = np.array([[u, v] for u in range(x0 - 13, x0 - 7, 2) for v in range(45, 76, 6)], float)
    visible = np.array([[u, v] for u in range(30, 60, 4) for v in range(40, 80, 8)], float)
    lenient = {"ncc_min": 1e-6, "uniqueness": 1.0, "refine_share": 1.0}
    with_check = FrontendConfig(**lenient)
    without = FrontendConfig(**lenient, left_right_share=1.0)
    m_hidden = match_stereo(left, right, hidden, (0.0, 40.0), with_check)
    m_free = match_stereo(left, right, hidden, (0.0, 40.0), without)
    assert m_hidden.searched.all()
    assert not m_hidden.accepted.any()  # the left-right check alone rejects them
    assert m_free.accepted.mean() > 0.5  # ... which would otherwise pass
    m_vis = match_stereo(left, right, visible, (0.0, 40.0), FrontendConfig())
    assert m_vis.accepted.all()
    np.testing.assert_allclose(visible[:, 0] - m_vis.uv_right[:, 0], 4.0, atol=0.1)


def test_stereo_from_a_guess_finds_the_searched_match(sequence):
    """A tracked point followed from its previous disparity (Lucas–Kanade there and back)
    lands where the full NCC search of the row lands, within 1 px of the truth."""
    team, frames = sequence
    left, right = frames[0]
    corners = cv2.goodFeaturesToTrack(left, 300, 0.005, 5).reshape(-1, 2).astype(float)
    camera = team.config.camera()
    config = FrontendConfig()
    d_range = config.disparity_range(camera.fx_baseline)
    searched = match_stereo(left, right, corners, d_range, config)
    truth = team.project(0, 0, team.points_behind(0, 0, corners))
    # the previous frame's disparity: off by up to 2 px
    off = np.random.default_rng(1).uniform(-2.0, 2.0, len(corners))
    guess = corners[:, 0] - truth[:, 2] + off
    followed = match_stereo(left, right, corners, d_range, config, disparity_guess=guess)
    both = searched.accepted & followed.accepted
    assert followed.accepted.mean() > 0.8 and both.sum() > 0.9 * searched.accepted.sum()
    np.testing.assert_allclose(followed.uv_right[both], searched.uv_right[both], atol=0.02)
    err = np.abs(followed.uv_right[followed.accepted] - truth[followed.accepted, 2:])
    assert err.max() < 1.0
    # with the guess switched off the same call searches, and gives the searched matches
    no_guess = FrontendConfig(stereo_from_guess=False)
    again = match_stereo(left, right, corners, d_range, no_guess, disparity_guess=guess)
    assert again.accepted.sum() > 0.8 * searched.accepted.sum()
    ok = again.accepted & searched.accepted
    np.testing.assert_allclose(again.uv_right[ok], searched.uv_right[ok], atol=0.02)


def test_a_guess_is_not_followed_into_an_occlusion():
    """A point that was matched at the background's disparity and is now hidden behind the
    square in the right image is rejected (Lucas–Kanade from the guess does not come back to
    the left point, or leaves the guess's interval), even with lenient NCC and refine gates;
    visible points followed from a guess 1.5 px off are matched exactly."""
    left, right, x0 = _occlusion_pair()
    hidden = np.array([[u, v] for u in range(x0 - 13, x0 - 7, 2) for v in range(45, 76, 6)], float)
    visible = np.array([[u, v] for u in range(30, 60, 4) for v in range(40, 80, 8)], float)
    lenient = {"ncc_min": 1e-6, "uniqueness": 1.0, "refine_share": 1.0}
    guess = np.full(len(hidden), 4.0)
    m_hidden = match_stereo(
        left, right, hidden, (0.0, 40.0), FrontendConfig(**lenient), disparity_guess=guess
    )
    assert m_hidden.searched.all()
    assert not m_hidden.accepted.any()
    m_vis = match_stereo(
        left, right, visible, (0.0, 40.0), FrontendConfig(), disparity_guess=np.full(40, 5.5)
    )
    assert m_vis.accepted.all()
    np.testing.assert_allclose(visible[:, 0] - m_vis.uv_right[:, 0], 4.0, atol=0.1)


def test_markers_found_with_subpixel_centres(sequence):
    team, frames = sequence
    detector = MarkerDetector(FrontendConfig())
    camera = team.config.camera()
    rng_d = FrontendConfig().disparity_range(camera.fx_baseline)
    checked = 0
    for k, (left, right) in enumerate(frames):
        ids, z = detector.detect_stereo(left, right, rng_d, 2.0)
        true_ids, true_z, side = team.visible_markers(0, k)
        for i, zt in zip(true_ids[side >= 25], true_z[side >= 25], strict=True):
            assert i in ids, f"marker {i} ({side.max():.0f} px) missed in frame {k}"
            assert np.abs(z[ids == i][0] - zt).max() < 1.0
            checked += 1
        # every reported marker is a real one seen by the camera
        assert np.isin(ids, true_ids).all()
    assert checked >= 3


def _small_marker(side: float, rng) -> tuple[np.ndarray, np.ndarray]:
    """A 4×4 ArUco marker of ``side`` pixels, slanted by a homography into a 160×120 grey
    image with blur and noise; returns the image and the true corners."""
    bits = cv2.aruco.generateImageMarker(
        cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_250), 7, 600
    )
    canvas = np.full((1000, 1000), 255, np.uint8)
    canvas[200:800, 200:800] = bits
    source = np.array([[200, 200], [800, 200], [800, 800], [200, 800]], np.float32)
    corners = np.array([[0, 0], [side, 0.06 * side], [side * 0.97, side], [0.04 * side, side]])
    corners = (corners + np.array([60.3, 40.7])).astype(np.float32)
    H = cv2.getPerspectiveTransform(source, corners)
    img = cv2.warpPerspective(canvas.astype(np.float32), H, (160, 120), flags=cv2.INTER_AREA)
    img = cv2.GaussianBlur(img, (0, 0), 0.6) * 0.7 + 40 + rng.normal(0, 1.0, img.shape)
    # the warp maps pixel centres: the marker's corners are the outer edges of the bits image
    return np.clip(img, 0, 255).astype(np.uint8), corners


def test_marker_corner_window_reaches_the_detector_and_small_markers_are_subpixel():
    rng = np.random.default_rng(2)
    detector = MarkerDetector(FrontendConfig(marker_corner_window=0.4))
    params = detector._detector.getDetectorParameters()
    assert params.relativeCornerRefinmentWinSize == pytest.approx(0.4)
    errors = []
    for side in (26.0, 30.0, 36.0):
        img, corners = _small_marker(side, rng)
        found = detector.detect(img)
        assert found.ids.tolist() == [7]
        errors.append(np.abs(found.centres[0] - diagonal_centre(corners)).max())
    assert max(errors) < 0.5
    with pytest.raises(InputError, match="marker_corner_window"):
        FrontendConfig(marker_corner_window=0.0)


def test_diagonal_centre_is_the_projective_centre():
    corners = np.array([[10.0, 10.0], [50.0, 12.0], [44.0, 40.0], [12.0, 44.0]])
    c = diagonal_centre(corners)
    # on both diagonals
    for a, b in ((0, 2), (1, 3)):
        d = corners[b] - corners[a]
        r = c - corners[a]
        assert abs(d[0] * r[1] - d[1] * r[0]) < 1e-9


def test_rectification_of_a_rotated_pair():
    cfg = RenderConfig(**SMALL)
    team = render_team(cfg)
    room = team.room
    K = cfg.camera().intrinsics
    T_world_left = team.T_world_cam(0, 2)
    # the right camera: 0.2 m to the right, yawed 3° and rolled 1.5°
    rot = cv2.Rodrigues(np.array([0.0, np.radians(3.0), np.radians(1.5)]))[0]
    T_left_right = np.eye(4)
    T_left_right[:3, :3], T_left_right[0, 3] = rot, 0.2
    no_effects = RenderConfig(**SMALL, jpeg_quality=None, pixel_noise=0.0, vignetting=0.0)
    rng = np.random.default_rng(0)
    raw_l = apply_effects(room.render(T_world_left, K, (320, 240)), K, no_effects, False, rng)
    T_world_right = T_world_left @ T_left_right
    raw_r = apply_effects(room.render(T_world_right, K, (320, 240)), K, no_effects, True, rng)
    rig = StereoRig((320, 240), K, K, np.zeros(5), np.zeros(5), T_left_right, T_CAM_BODY)
    assert not rig.already_rectified
    left, right = rig.rectify(raw_l, raw_r)
    cam = rig.camera
    assert cam.baseline == pytest.approx(0.2, rel=1e-6)
    corners = cv2.goodFeaturesToTrack(left, 200, 0.005, 6).reshape(-1, 2).astype(float)
    cfg_fe = FrontendConfig()
    m = match_stereo(left, right, corners, cfg_fe.disparity_range(cam.fx_baseline), cfg_fe)
    assert m.accepted.mean() > 0.6
    # truth: the rectified left ray back in the raw left camera, cast into the room, projected
    # into the rectified stereo camera
    uv = corners[m.accepted]
    rays_rect = np.column_stack([uv, np.ones(len(uv))]) @ np.linalg.inv(cam.intrinsics).T
    rays_raw = rays_rect @ rig.R_rect_left  # R⁻¹ = Rᵀ: raw = Rᵀ rect
    uv_raw = rays_raw[:, :2] / rays_raw[:, 2:] * K[0, 0] + K[:2, 2]
    world = room.cast(T_world_left, K, uv_raw)
    T_left_world = np.linalg.inv(T_world_left)
    p_raw = world @ T_left_world[:3, :3].T + T_left_world[:3, 3]
    truth = cam.project(p_raw @ rig.R_rect_left.T)
    np.testing.assert_allclose(truth[:, :2], uv, atol=1e-6)
    err = np.abs(m.uv_right[m.accepted] - truth[:, 2:])
    assert np.median(err) < 0.2
    assert np.mean(err.max(axis=1) < 1.0) > 0.97


def test_settings_scale_with_the_image():
    c = FrontendConfig()
    small, big = c.pixels((320, 240)), c.pixels((1280, 960))
    assert big.lk_window > 3 * small.lk_window - 6
    assert big.spacing == pytest.approx(4 * small.spacing)
    lo, hi = c.disparity_range(84.0)
    assert lo == pytest.approx(84.0 / c.max_depth) and hi == pytest.approx(84.0 / c.min_depth)
    with pytest.raises(InputError, match="min_depth"):
        FrontendConfig(min_depth=5.0, max_depth=1.0)
    with pytest.raises(InputError, match="marker_dictionary"):
        FrontendConfig(marker_dictionary="9x9")


def test_without_opencv_the_error_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "cv2", None)
    with pytest.raises(
        InputError, match=r"needs the 'images' extra: pip install 'teamslam\[images\]'"
    ):
        require_cv2()


def test_tracks_across_skipped_frames_are_looked_for_where_the_motion_takes_them():
    """A live robot that dropped frames gives the front-end the camera's motion since the last
    frame it saw: each track with a stereo depth is predicted where its point now projects
    (exactly, up to the disparity's error), and the tracks survive a gap that loses them
    without it."""
    from teamslam.frontend.pipeline import StereoFrontend
    from teamslam.geometry import se3

    config = RenderConfig(**{**SMALL, "steps": 8})
    team = render_team(config)
    rig = StereoRig.rectified(config.image_size, config.camera(), T_CAM_BODY)
    rng = np.random.default_rng(3)
    gap = 6
    frames = [render_stereo(team.room, team.T_world_cam(0, k), rng) for k in (0, gap)]
    motion = se3.inverse(team.T_world_cam(0, 0)) @ team.T_world_cam(0, gap)  # T_prev_cur
    kept = {}
    for given in (False, True):
        frontend = StereoFrontend(rig, FrontendConfig())
        first = frontend.process(*frames[0])
        uv = first.features[:, :2]
        if given:
            truth = team.project(0, gap, team.points_behind(0, 0, uv))[:, :2]
            moved = np.linalg.norm(uv - truth, axis=1)
            error = np.linalg.norm(
                frontend.predicted(first.feature_ids, uv, motion) - truth, axis=1
            )
            assert np.median(moved) > 20.0 and np.median(error) < 0.5
        second = frontend.process(*frames[1], motion=motion if given else None)
        kept[given] = int(np.isin(first.feature_ids, second.feature_ids).sum())
    assert first.feature_ids.size > 300
    assert kept[False] < 30 and kept[True] > 120, kept
