"""Stereo measurements of a detector's boxes and their appearance descriptors, checked against
a rendered room's exact truth and against constructed image pairs."""

from __future__ import annotations

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2", reason="the images extra (OpenCV) is not installed")

from teamslam.errors import InputError  # noqa: E402
from teamslam.frontend import FrontendConfig, StereoRig  # noqa: E402
from teamslam.frontend.appearance import DESCRIPTORS, describe, dimension  # noqa: E402
from teamslam.frontend.boxes import BoxStereo, _Pyramid  # noqa: E402
from teamslam.frontend.detections import ImageDetections  # noqa: E402
from teamslam.sim.render import (  # noqa: E402
    T_CAM_BODY,
    RenderConfig,
    apply_effects,
    render_stereo,
    render_team,
)

FRAMES = (0, 12, 24)


@pytest.fixture(scope="module")
def rendered():
    """A rendered robot (640 × 480), three of its stereo frames and the tight boxes around the
    markers wholly visible in both images of each (left and right, ids)."""
    config = RenderConfig(robots=1, steps=24)
    team = render_team(config)
    cam = config.camera()
    rig = StereoRig(
        config.image_size, cam.intrinsics, cam.intrinsics, np.zeros(5), np.zeros(5),
        cam.T_left_right, T_CAM_BODY,
    )  # fmt: skip
    rng = np.random.default_rng(7)
    frames = []
    room = team.room
    for k in FRAMES:
        left, right = render_stereo(room, team.T_world_cam(0, k), rng)
        ids, _, side = team.visible_markers(0, k)
        ids = ids[side >= 20]
        corners = room.marker_corners[np.searchsorted(room.marker_ids, ids)]
        z = team.project(0, k, corners.reshape(-1, 3)).reshape(-1, 4, 4)
        boxes = [
            np.concatenate([z[..., c : c + 2].min(1), z[..., c : c + 2].max(1)], 1) for c in (0, 2)
        ]
        frames.append((k, left, right, ids, boxes[0], boxes[1]))
    assert sum(len(f[3]) for f in frames) >= 6
    return team, rig, frames


def _detections(boxes: np.ndarray, classes=None) -> ImageDetections:
    n = len(boxes)
    classes = np.zeros(n, np.int64) if classes is None else np.asarray(classes, np.int64)
    return ImageDetections(np.asarray(boxes, float), classes, np.ones(n))


def test_box_centres_match_the_true_right_projection_within_a_pixel(rendered):
    team, rig, frames = rendered
    stereo = BoxStereo(rig)
    errors = []
    for k, left, right, ids, boxes, _ in frames:
        m = stereo.measure(left, right, _detections(boxes))
        assert list(m.source) == ["patch"] * len(ids), m.reasons
        np.testing.assert_allclose(m.z[:, :2], (boxes[:, :2] + boxes[:, 2:]) / 2)
        np.testing.assert_allclose(m.sizes, boxes[:, 2:] - boxes[:, :2])
        # truth: the wall point behind the left box centre, projected into the right camera
        truth = team.project(0, k, team.points_behind(0, k, m.z[:, :2]))
        errors.append(np.abs(m.z[:, 2:] - truth[:, 2:]))
    errors = np.concatenate(errors)
    assert errors.max() < 1.0
    assert np.median(errors[:, 0]) < 0.2


def test_boxes_of_a_raw_rotated_pair_are_measured_in_the_rectified_camera(rendered):
    team, _, _ = rendered
    config = team.config
    K = config.camera().intrinsics
    rot = cv2.Rodrigues(np.array([0.0, np.radians(3.0), np.radians(1.5)]))[0]
    T_left_right = np.eye(4)
    T_left_right[:3, :3], T_left_right[0, 3] = rot, 0.2
    rig = StereoRig(config.image_size, K, K, np.zeros(5), np.zeros(5), T_left_right, T_CAM_BODY)
    assert not rig.already_rectified
    room, k = team.room, 12
    T_world_left = team.T_world_cam(0, k)
    rng = np.random.default_rng(8)
    raw_l = apply_effects(room.render(T_world_left, K, config.image_size), K, config, False, rng)
    T_world_right = T_world_left @ T_left_right
    raw_r = apply_effects(room.render(T_world_right, K, config.image_size), K, config, True, rng)
    ids, _, side = team.visible_markers(0, k)
    corners = room.marker_corners[np.searchsorted(room.marker_ids, ids[side >= 20])]
    T_left_world = np.linalg.inv(T_world_left)
    p = corners.reshape(-1, 3) @ T_left_world[:3, :3].T + T_left_world[:3, 3]
    uv = (p[:, :2] / p[:, 2:] * K[0, 0] + K[:2, 2]).reshape(-1, 4, 2)
    boxes = np.concatenate([uv.min(axis=1), uv.max(axis=1)], axis=1)
    left, right = rig.rectify(raw_l, raw_r)
    m = BoxStereo(rig).measure(left, right, _detections(boxes))
    assert (m.source == "patch").all(), m.reasons
    np.testing.assert_allclose(
        m.z[:, :2], rig.rectify_points((boxes[:, :2] + boxes[:, 2:]) / 2), atol=1e-9
    )
    # truth: the rectified left centre's ray in the raw left camera, cast into the room,
    # projected into the rectified stereo camera
    cam = rig.camera
    rays = np.column_stack([m.z[:, :2], np.ones(len(m))]) @ np.linalg.inv(cam.intrinsics).T
    rays_raw = rays @ rig.R_rect_left
    world = room.cast(T_world_left, K, rays_raw[:, :2] / rays_raw[:, 2:] * K[0, 0] + K[:2, 2])
    p_raw = world @ T_left_world[:3, :3].T + T_left_world[:3, 3]
    truth = cam.project(p_raw @ rig.R_rect_left.T)
    np.testing.assert_allclose(truth[:, :2], m.z[:, :2], atol=1e-6)
    assert np.abs(m.z[:, 2:] - truth[:, 2:]).max() < 1.0
    with pytest.raises(InputError, match="box stereo: left image"):
        BoxStereo(rig).measure(left[:100], right, _detections(boxes))


def _texture(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    return cv2.GaussianBlur(rng.uniform(0, 255, (h, w)).astype(np.float32), (0, 0), 1.5)


def _synthetic_rig(size=(320, 160)) -> StereoRig:
    """A rectified rig with ``fx · b = 80`` px: disparities 0.8 … 160 px by default."""
    K = np.array([[400.0, 0, size[0] / 2], [0, 400.0, size[1] / 2], [0, 0, 1]])
    T = np.eye(4)
    T[0, 3] = 0.2
    return StereoRig(size, K, K, np.zeros(5), np.zeros(5), T)


def _u8(a: np.ndarray) -> np.ndarray:
    return np.clip(a, 0, 255).astype(np.uint8)


def test_a_box_whose_match_leaves_the_right_image_stays_monocular():
    rng = np.random.default_rng(1)
    scene = _texture(rng, 160, 400)
    # disparity 30 (right image column = left column − 30), the right camera's gain and offset
    left, right = _u8(scene[:, 40:360]), _u8(0.9 * scene[:, 70:390] + 6)
    # a box in the middle finds its disparity; one at the left border has its match at
    # columns −25 … 25 of the right image: cut off, so it is kept without a right centre
    boxes = np.array([[150.0, 50, 200, 100], [5.0, 50, 55, 100]])
    m = BoxStereo(_synthetic_rig()).measure(left, right, _detections(boxes))
    assert list(m.source) == ["patch", "monocular"]
    assert m.z[0, 0] - m.z[0, 2] == pytest.approx(30.0, abs=0.1)
    assert m.z[0, 3] == m.z[0, 1]
    assert np.isnan(m.z[1, 2:]).all() and np.isfinite(m.z[1, :2]).all()
    assert m.reasons[1] != "" and m.counts()[m.reasons[1]] == 1
    assert m.counts()["monocular"] == 1 and m.counts()["patch"] == 1


def test_an_occluded_right_patch_stays_monocular():
    rng = np.random.default_rng(2)
    scene = _texture(rng, 160, 400)
    left, right = scene[:, 40:360].copy(), scene[:, 70:390].copy()
    right[40:110, 110:180] = _texture(rng, 70, 70)  # something in front, seen only from the right
    boxes = np.array([[150.0, 50, 200, 100]])
    m = BoxStereo(_synthetic_rig()).measure(_u8(left), _u8(right), _detections(boxes))
    assert m.source[0] == "monocular" and m.reasons[0] in ("weak", "not unique", "left-right")


def test_uniqueness_rejects_a_repetitive_texture():
    rng = np.random.default_rng(3)
    period = _texture(rng, 160, 16)
    scene = np.tile(period, (1, 24))  # the same 16 columns over and over
    left, right = _u8(scene[:, 40:360]), _u8(scene[:, 60:380])  # disparity 20
    boxes = np.array([[150.0, 50, 214, 100]])
    m = BoxStereo(_synthetic_rig()).measure(left, right, _detections(boxes))
    assert m.source[0] == "monocular" and m.reasons[0] == "not unique"
    # the same box on a texture that does not repeat is measured
    scene = _texture(rng, 160, 384)
    left, right = _u8(scene[:, 40:360]), _u8(scene[:, 60:380])
    m = BoxStereo(_synthetic_rig()).measure(left, right, _detections(boxes))
    assert m.source[0] == "patch"
    assert m.z[0, 0] - m.z[0, 2] == pytest.approx(20.0, abs=0.1)


def test_left_right_check_rejects_a_patch_seen_twice_in_the_left_image():
    """Two look-alikes side by side in the left image, only one of them in the right one: the
    right patch searched back in the left image lands on the other (a repeated texture)."""
    rng = np.random.default_rng(4)
    left = _texture(rng, 160, 320)
    right = _texture(rng, 160, 320)
    thing = _texture(rng, 40, 30)
    u, d0 = 200, 60  # the box's columns in the left image and its true disparity
    left[60:100, u : u + 30] = thing + rng.normal(0, 4, thing.shape)
    left[60:100, u - 40 : u - 10] = thing  # its twin, 40 px to the left
    right[60:100, u - d0 : u - d0 + 30] = thing
    boxes = np.array([[u, 60.0, u + 29, 99]])
    rig = _synthetic_rig()
    m = BoxStereo(rig).measure(_u8(left), _u8(right), _detections(boxes))
    assert m.source[0] == "monocular" and m.reasons[0] == "left-right"
    # without the check (a tolerance of the whole diagonal) the forward match is taken
    lenient = BoxStereo(rig, FrontendConfig(left_right_share=1.0))
    m = lenient.measure(_u8(left), _u8(right), _detections(boxes))
    assert m.source[0] == "patch"
    assert m.z[0, 0] - m.z[0, 2] == pytest.approx(d0, abs=0.5)


def test_right_image_boxes_are_paired_by_class_row_and_disparity(rendered):
    _, rig, frames = rendered
    _, left, right, ids, boxes, right_boxes = max(frames, key=lambda f: len(f[3]))
    assert len(ids) >= 2
    stereo = BoxStereo(rig)
    # the detector's right boxes: the first marker's, one of another class on the second
    # marker, and a same-class box far below any left box (no row overlap)
    h = right_boxes[0, 3] - right_boxes[0, 1]
    far = right_boxes[0] + np.array([0, 1, 0, 1]) * (h + 300)
    given = np.stack([far, right_boxes[1], right_boxes[0]])
    classes = np.zeros(len(ids), np.int64)
    m = stereo.measure(left, right, _detections(boxes, classes), _detections(given, [0, 5, 0]))
    assert m.source[0] == "right box"
    np.testing.assert_allclose(m.z[0, 2:], (right_boxes[0, :2] + right_boxes[0, 2:]) / 2)
    assert list(m.source[1:]) == ["patch"] * (len(ids) - 1)  # the others fall back to the patch
    assert m.counts()["right box"] == 1
    # the same class on the second marker: paired too
    classes[1] = 5
    m = stereo.measure(left, right, _detections(boxes, classes), _detections(given, [0, 5, 0]))
    assert list(m.source[:2]) == ["right box", "right box"]
    np.testing.assert_allclose(m.z[1, 2:], (right_boxes[1, :2] + right_boxes[1, 2:]) / 2)


def test_a_right_box_cut_by_an_occluder_is_not_paired_and_its_patch_gives_the_disparity():
    """Eight boxes at one depth (disparity 20 px), the detector's right boxes jittered by 1 % of
    their size, and one object whose right 60 % an occluder hides in the right image (its right
    box cut to the visible 40 %): that box's centre is 12 px off the object's and the pair is
    refused by the learned width ratio; its whole patch finds no match, the part of the left box
    the right image shows does, to within a pixel. The others stay paired with the detector's
    right boxes."""
    rng = np.random.default_rng(3)
    rig = _synthetic_rig((480, 200))
    left = _texture(rng, 200, 480)
    d = 20.0
    right = np.zeros_like(left)
    right[:, : 480 - int(d)] = left[:, int(d) :]
    x0 = np.arange(8) * 50.0 + 60.0
    y0 = np.where(np.arange(8) % 2 == 0, 30.0, 110.0)
    boxes = np.stack([x0, y0, x0 + 40.0, y0 + 50.0], axis=1)
    given = boxes - [d, 0.0, d, 0.0]
    given += rng.normal(0.0, 0.01, given.shape) * 40.0
    cut = 5
    given[cut, 2] = given[cut, 0] + 0.4 * 40.0  # the occluder hides its right 60 %
    x, y = int(boxes[cut, 0] - d + 16), int(boxes[cut, 1])
    right[y - 5 : y + 55, x : x + 40] = _texture(rng, 60, 40)  # the occluder
    stereo = BoxStereo(rig)
    pyramids = _Pyramid(cv2, _u8(left)), _Pyramid(cv2, _u8(right))
    d_whole, reason = stereo._search(cv2, *pyramids, boxes[cut])
    assert reason or abs(d_whole - d) > 1.0  # the whole patch: no match, or not the object's
    m = stereo.measure(_u8(left), _u8(right), _detections(boxes), _detections(given))
    assert list(np.flatnonzero(m.source != "right box")) == [cut]
    assert m.source[cut] == "patch"
    assert abs(m.z[cut, 0] - m.z[cut, 2] - d) < 1.0
    # without the width test the cut box's centre would have given a disparity 12 px off
    assert abs((boxes[cut, 0] + boxes[cut, 2] - given[cut, 0] - given[cut, 2]) / 2 - d) > 10.0
    assert stereo.width_ratios.size == 8


def test_rectify_points_agrees_with_the_rectified_camera():
    K = np.array([[300.0, 0, 160], [0, 310.0, 120], [0, 0, 1]])
    rot = cv2.Rodrigues(np.array([0.01, np.radians(3.0), np.radians(1.5)]))[0]
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rot, [0.2, 0.005, 0.0]
    distortion = np.array([-0.1, 0.02, 0.0, 0.0, 0.0])
    rig = StereoRig((320, 240), K, K, distortion, distortion, T)
    uv = np.random.default_rng(0).uniform([20, 20], [300, 220], (50, 2))
    for side, R, D in (
        ("left", rig.R_rect_left, distortion),
        ("right", rig.R_rect_right, distortion),
    ):
        rect = rig.rectify_points(uv, side)
        # back: the rectified ray rotated into the raw camera, distorted, projected
        ray = np.column_stack([rect, np.ones(len(rect))]) @ np.linalg.inv(rig.camera.intrinsics).T
        raw, _ = cv2.projectPoints(ray @ R, np.zeros(3), np.zeros(3), K, D)
        np.testing.assert_allclose(raw.reshape(-1, 2), uv, atol=1e-3)
    rectified = _synthetic_rig()
    np.testing.assert_array_equal(rectified.rectify_points(uv), uv)
    with pytest.raises(ValueError, match="side"):
        rig.rectify_points(uv, "middle")


def test_box_settings_are_checked():
    for bad in (
        {"box_ncc_min": 1.0},
        {"box_uniqueness": 1.5},
        {"box_patch_samples": 4},
        {"box_width_probability": 1.0},
    ):
        with pytest.raises(InputError, match="box_"):
            FrontendConfig(**bad)


def _jitter(boxes: np.ndarray, share: float, rng: np.random.Generator) -> np.ndarray:
    size = np.tile(boxes[:, 2:] - boxes[:, :2], 2)
    return boxes + rng.uniform(-share, share, boxes.shape) * size


def test_descriptor_survives_box_jitter_better_than_a_change_of_marker(rendered):
    _, _, frames = rendered
    rng = np.random.default_rng(5)
    wins, pairs = 0, 0
    for _, left, right, ids, boxes, right_boxes in frames:
        if len(ids) < 2:
            continue
        a = describe(left, boxes)
        assert a.shape == (len(ids), dimension()) and a.dtype == np.float32
        different = ~np.eye(len(ids), dtype=bool)
        # the same image, each box moved and resized by up to 10 % per side: every marker is
        # closer to its own jittered box than to any other marker's
        cos = a @ describe(left, _jitter(boxes, 0.1, rng)).T
        assert np.all(np.diag(cos) > np.where(different, cos, -np.inf).max(axis=1)), cos
        # the right camera (another gain and offset, another view) and a jittered box: most
        # (same, other) comparisons still rank the same marker first
        cos = a @ describe(right, _jitter(right_boxes, 0.1, rng)).T
        wins += int(np.sum(np.diag(cos)[:, None] > np.where(different, cos, np.inf)))
        pairs += int(different.sum())
    assert wins >= 0.8 * pairs


def test_descriptors_are_unit_vectors_of_fixed_size_on_grey_and_colour():
    rng = np.random.default_rng(6)
    colour = _u8(np.stack([_texture(rng, 120, 160) for _ in range(3)], axis=2))
    grey = cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY)
    boxes = np.array([[10.0, 10, 60, 70], [80.0, 30, 150, 110]])
    for kind in DESCRIPTORS:
        for image in (grey, colour):
            d = describe(image, boxes, kind)
            assert d.shape == (2, dimension(kind)) and d.dtype == np.float32
            norms = np.linalg.norm(d, axis=1)
            if kind == "hue-saturation" and image is grey:
                assert np.all(norms == 0)  # no colour: the colour part is absent
            else:
                np.testing.assert_allclose(norms, 1.0, rtol=1e-5)
    # the colour half carries the hue: a gain on the colour image changes little
    brighter = _u8(0.8 * colour.astype(np.float32) + 10)
    a, b = describe(colour, boxes), describe(brighter, boxes)
    assert np.all(np.sum(a * b, axis=1) > 0.95)
    # grey images: the default's colour half is zero
    g = describe(grey, boxes)
    assert not np.any(g[:, dimension("thumbnail") :])
    # the default: a colour image by its hue alone (the thumbnail block zero), a grey one by
    # its thumbnail alone, to the bit as thumbnail+hue-saturation gives it
    c = describe(colour, boxes)
    assert not np.any(c[:, : dimension("thumbnail")])
    np.testing.assert_allclose(
        c[:, dimension("thumbnail") :], describe(colour, boxes, "hue-saturation"), atol=1e-6
    )
    np.testing.assert_array_equal(g, describe(grey, boxes, "thumbnail+hue-saturation"))
    np.testing.assert_allclose(g[:, : dimension("thumbnail")], describe(grey, boxes, "thumbnail"))
    with pytest.raises(InputError, match="appearance"):
        describe(grey.astype(np.float32), boxes)
    with pytest.raises(InputError, match="unknown"):
        describe(grey, boxes, "sift")


def test_colour_histograms_leave_out_what_another_box_covers():
    """Two objects side by side, the left one's box reaching into the right one: its colour is
    counted only where no other box lies (the neighbour's colour stays out); a box the others
    cover wholly keeps all its pixels; the layouts take the whole box."""
    image = np.zeros((100, 200, 3), np.uint8)
    image[:, :100] = (0, 0, 200)  # red (BGR)
    image[:, 100:] = (200, 60, 0)  # blue
    rng = np.random.default_rng(7)
    image = _u8(image + rng.normal(0.0, 8.0, image.shape))  # some spread inside each colour
    reaching, right = [10.0, 10, 129, 90], [100.0, 10, 190, 90]
    red_only, blue_only = [10.0, 10, 99, 90], [130.0, 10, 190, 90]
    for kind in ("hue-saturation", "hue-saturation-or-thumbnail", "intensity"):
        both = describe(image, np.array([reaching, right]), kind)
        np.testing.assert_allclose(both[0], describe(image, np.array([red_only]), kind)[0])
        np.testing.assert_allclose(both[1], describe(image, np.array([blue_only]), kind)[0])
        alone = describe(image, np.array([reaching]), kind)[0]
        assert float(alone @ both[0]) < 0.99  # alone, its box counts the neighbour's colour too
    # a box inside another: all of its pixels (the outer box leaves them out)
    inner = [140.0, 30, 160, 60]
    nested = describe(image, np.array([right, inner]))
    np.testing.assert_allclose(nested[1], describe(image, np.array([inner]))[0])
    for kind in ("thumbnail", "hog"):
        np.testing.assert_allclose(
            describe(image, np.array([reaching, right]), kind)[0],
            describe(image, np.array([reaching]), kind)[0],
        )
