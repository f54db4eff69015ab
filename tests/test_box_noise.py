"""A detector box centre's noise as a share of the box (``filter.object_size_share``).

The calibration recovers a known size-proportional noise from a team's detections alone, its
floor never below the pixel grid's own for boxes on images; an
object seen only through boxes cut by the image border is estimated without bias (its error
consistent with its covariance), which it is not when the cut goes unnoticed; an object leaving
the view through the right border keeps its id and a consistent estimate, which it loses when
the right centre of its cut boxes is taken as uncut; data without box sizes keep the plain σ.
"""

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
)
from teamslam.eval.tracking import mot_metrics
from teamslam.gaussian import chi2_quantile
from teamslam.msckf.agent import MsckfAgent
from teamslam.msckf.calibration import (
    BOX_QUANTIZATION_STD,
    box_noise_fit,
    box_quantization_std,
    calibrate,
)
from teamslam.msckf.configure import build_settings
from teamslam.msckf.filter.box_noise import box_rows, box_variances
from teamslam.msckf.filter.models import observe
from teamslam.msckf.objects.tracking import ObjectTracker
from teamslam.msckf.settings.health import InnovationRecord
from teamslam.msckf.settings.sources import calibration_start
from teamslam.msckf.settings.values import MsckfConfig
from teamslam.sim.lissajous import T_CAM_BODY, SimulationConfig, lissajous_team

CAMERA = SimulationConfig().camera()
IMAGE = (640, 480)


def test_variances_grow_with_the_box_and_clipped_coordinates_are_flagged():
    z = np.array([[320.0, 240.0, 300.0, 240.0], [10.0, 240.0, -5.0, 240.0]])
    sizes = np.array([[40.0, 80.0], [21.0, 30.0]])  # the second's left edge at -0.5
    rows = box_rows(z, sizes, IMAGE, 0.5, 0.03)
    assert rows[0, 6:].tolist() == [0, 0, 0, 0]
    assert rows[1, 6:].tolist() == [1, 0, 1, 0]  # u cut (both images), v not
    var = box_variances(rows, 0.5, 0.03)
    np.testing.assert_allclose(var[0], 0.25 + (0.03 * np.array([40.0, 80.0, 40.0, 80.0])) ** 2)
    np.testing.assert_allclose(var[1, [1, 3]], 0.25 + (0.03 * 30.0) ** 2)
    # a cut coordinate: the box's size, and half the disparity (the two images' hidden parts
    # differ by it), as one σ each
    np.testing.assert_allclose(var[1, [0, 2]], 0.25 + (0.03**2 + 1.0) * 21.0**2 + 7.5**2)
    assert not box_rows(z, sizes, None, 0.5, 0.03)[:, 6:].any()  # no image size: no cut known


def _boxed_team(floor: float, share: float, seed: int = 3):
    """A simulated team whose detections carry box sizes (each object a width and height in
    metres) and box-centre noise ``σ² = floor² + (share · size)²``, independent per coordinate
    (``u`` with the width, ``v`` with the height)."""
    team = strip_object_ids(lissajous_team(robots=3, steps=120, objects=120, seed=seed), to="none")
    rng = np.random.default_rng(seed)
    extent = rng.uniform(0.4, 2.5, (team.object_ids.size, 2))  # width, height (m)
    positions = dict(zip(team.object_ids.tolist(), team.object_positions, strict=True))
    robots = []
    for robot in team.robots:
        det = robot.detections
        frame = np.repeat(np.arange(det.frames), np.diff(det.offsets))
        z = np.empty_like(det.measurements)
        sizes = np.empty((z.shape[0], 2))
        for k, (f, oid) in enumerate(zip(frame.tolist(), det.truth.tolist(), strict=True)):
            point = positions[oid][None]
            z[k] = observe(CAMERA, T_CAM_BODY, robot.T_world_body[f], point)[0]
            p_cam = T_CAM_BODY @ np.linalg.inv(robot.T_world_body[f]) @ np.append(point[0], 1.0)
            sizes[k] = CAMERA.intrinsics[0, 0] * extent[oid] / p_cam[2]
        std = np.sqrt(floor**2 + (share * np.concatenate([sizes, sizes], axis=1)) ** 2)
        z = z + std * rng.standard_normal(z.shape)
        robots.append(replace(robot, detections=replace(det, measurements=z, sizes=sizes)))
    return replace(team, robots=robots, sensor_model=None)


@pytest.mark.parametrize("floor", [0.5, 0.0])
def test_calibration_recovers_a_size_proportional_noise(floor):
    # no floor in the noise: the calibration keeps the pixel grid's own (the boxes are pixels)
    share = 0.04
    team = _boxed_team(floor, share)
    boxes = sum(r.detections.measurements.shape[0] for r in team.robots)
    start = calibration_start(team, build_settings(team, calibrate="never").config)
    result = calibrate(team, start.with_(filter={"window": 10}))
    noise = result.sensor_model.team
    assert result.converged
    # Monte Carlo error: a variance from n draws is within ±√(2/n) (1 σ); the share is fitted
    # over 8 bins of ~boxes/8 innovations, the floor from the smallest ones: 3 σ of their
    # variances, halved for σ, and the filter's share of each innovation
    tolerance = 3 * np.sqrt(2 / (boxes / 8)) / 2
    assert abs(noise.object_size_share / share - 1) < max(tolerance, 0.1)
    if floor > 0:
        assert abs(noise.object_std / floor - 1) < max(2 * tolerance, 0.25)
    else:
        assert noise.object_std == pytest.approx(BOX_QUANTIZATION_STD)


def _innovations(floor: float, share: float, seed: int = 5) -> InnovationRecord:
    """Box innovations of objects the state knows exactly (``λ = 0``), their true variance
    ``floor² + (share · size)²``, whitened by a model's ``0.5² + (0.04 · size)²`` (a
    calibration pass's)."""
    rng = np.random.default_rng(seed)
    record = InnovationRecord()
    for width in rng.uniform(4.0, 200.0, 4000):
        size2 = np.full(4, width**2)
        model = 0.5**2 + 0.04**2 * size2
        variance = floor**2 + share**2 * size2
        record.c2.append(variance / model * rng.standard_normal(4) ** 2)
        record.lam.append(np.zeros(4))
        record.size2.append(size2)
        record.variance.append(model)
    return record


def test_the_box_noise_fit_is_not_moved_by_a_state_dominated_direction():
    """Innovations whose one direction the state dominates (``λ = 1000`` times the noise) and
    gets 10 % wrong there: the noise the other directions show is still the fit's. Matching the
    NIS sum instead takes those 10 % of 1000 from the noise (here: the floor a quarter low)."""
    rng = np.random.default_rng(7)
    floor, share = 0.5, 0.04
    record = InnovationRecord()
    for width in rng.uniform(4.0, 200.0, 4000):
        size2 = np.full(4, width**2)
        model = 1.6**2 + 0.11**2 * size2  # a start from above, as the calibration's
        rho = (floor**2 + share**2 * size2) / model
        lam = np.array([0.0, 0.05, 0.6, 1000.0])
        shown = lam * np.array([1.0, 1.0, 1.0, 0.9]) + rho  # the state 10 % off along λ = 1000
        record.c2.append(shown * rng.standard_normal(4) ** 2)
        record.lam.append(lam)
        record.size2.append(size2)
        record.variance.append(model)
    found = box_noise_fit(record)
    assert found is not None
    assert abs(found[0] / floor - 1) < 0.15 and abs(found[1] / share - 1) < 0.05


def test_the_box_noise_floor_is_kept_at_the_pixel_grid_s_own_error():
    # boxes whose noise has no floor: the innovations show none, and the fit keeps a floor of
    # zero unless told the least one (a box drawn on pixels: each edge anywhere in its pixel)
    record = _innovations(floor=0.0, share=0.03)
    free = box_noise_fit(record)
    assert free is not None and free[0] < 0.05 and abs(free[1] / 0.03 - 1) < 0.05
    floor, share = box_noise_fit(record, BOX_QUANTIZATION_STD)
    assert floor == pytest.approx(np.sqrt(1 / 24))
    assert abs(share / 0.03 - 1) < 0.05  # the share refitted to what the floor leaves
    # a floor the data show above the least one is the data's
    floor, share = box_noise_fit(_innovations(floor=0.8, share=0.03), BOX_QUANTIZATION_STD)
    assert abs(floor / 0.8 - 1) < 0.1 and abs(share / 0.03 - 1) < 0.05
    # only boxes on a known image are on its pixels
    team = _boxed_team(0.5, 0.04)
    assert team.calibration.image_size is not None
    assert box_quantization_std(team) == BOX_QUANTIZATION_STD
    unknown = replace(team, calibration=replace(team.calibration, image_size=None))
    assert box_quantization_std(unknown) == 0.0


def _one_robot(poses, boxes, floor: float, share: float, settings: dict | None = None):
    """A robot driving ``poses`` with exact odometry (the filter's σ a millimetre), its only
    observations the boxes ``(offsets, rows, sizes, truth)``, and its filter's settings."""
    offsets, rows, sizes, truth = boxes
    detections = FrameDetections(
        np.array(offsets), np.array(rows), truth=np.array(truth), sizes=np.array(sizes)
    )
    frames = poses.shape[0]
    empty = (np.zeros(0, np.int64), np.zeros((0, 4)))
    sequence = RobotSequence(
        T_world_body=poses,
        odometry=np.linalg.inv(poses[:-1]) @ poses[1:],
        features=FrameObservations.from_frames([empty] * frames),
        objects=FrameObservations.from_frames([empty] * frames),
        detections=detections,
    )
    config = MsckfConfig.from_settings(
        {
            "filter.object_std": floor,
            "filter.object_size_share": share,
            "filter.odometry_std": (1e-3,) * 3 + (1e-4,) * 3,
            "filter.window": 10,
            **(settings or {}),
        }
    )
    return sequence, config


def _clipped_sequence(seed: int, objects: int = 10):
    """One robot driving straight past objects on its left, each detected only while the left
    image border cuts its box (the visible part's box, its centre and size, plus noise)."""
    rng = np.random.default_rng(seed)
    step = 0.1
    steps = int((12.0 + 4.0 * objects) / step)
    poses = np.tile(np.eye(4), (steps + 1, 1, 1))
    poses[:, 0, 3] = step * np.arange(steps + 1)
    k = CAMERA.intrinsics
    fx, cx = k[0, 0], k[0, 2]
    # one after another along the way, each reaching the left border of the view at a depth
    # of 6 to 12 m, at various heights; half-widths in metres
    x = 12.0 + 4.0 * np.arange(objects)
    y = rng.uniform(6.0, 12.0, objects) * cx / fx
    z = rng.uniform(-1.0, 1.0, objects)
    half = rng.uniform(1.0, 2.0, objects)
    points = np.column_stack([x, y, z])
    floor, share = 0.3, 0.03
    offsets, rows, sizes, truth = [0], [], [], []
    for t in range(steps + 1):
        depth = points[:, 0] - poses[t, 0, 3]
        ahead = depth > 1.0
        z_true = np.full((objects, 4), np.nan)
        z_true[ahead] = observe(CAMERA, T_CAM_BODY, poses[t], points[ahead])
        width = 2 * fx * half / np.maximum(depth, 1.0)
        height = 2 * fx * 0.5 / np.maximum(depth, 1.0)
        count = 0
        for j in range(objects):
            if not ahead[j]:
                continue
            left, right = z_true[j, 0] - width[j] / 2, z_true[j, 0] + width[j] / 2
            left_r, right_r = z_true[j, 2] - width[j] / 2, z_true[j, 2] + width[j] / 2
            if not (left < -0.5 and left_r < -0.5 and right_r - (-0.5) > 0.4 * width[j]):
                continue  # seen whole, or too little of it in the right image
            centre_l, centre_r = (right - 0.5) / 2, (right_r - 0.5) / 2
            w_vis = right + 0.5  # the left image's visible part
            std = np.sqrt(floor**2 + (share * np.array([w_vis, height[j]])) ** 2)
            noise = std[[0, 1, 0, 1]] * rng.standard_normal(4)
            rows.append(np.array([centre_l, z_true[j, 1], centre_r, z_true[j, 3]]) + noise)
            sizes.append([w_vis, height[j]])
            truth.append(j)
            count += 1
        offsets.append(offsets[-1] + count)
    boxes = (offsets, rows, sizes, truth)
    sequence, config = _one_robot(poses, boxes, floor, share, {"objects.retire_after": 0})
    return sequence, points, config


def _nees(image_size) -> tuple[float, int]:
    """Mean NEES/3 of the objects one robot maps from cut boxes only, and how many."""
    nees = []
    for seed in range(3):
        sequence, points, config = _clipped_sequence(seed)
        agent = MsckfAgent(0, Calibration(CAMERA, T_CAM_BODY, image_size), sequence, config)
        for t in range(sequence.frames):
            agent.step(t)
        hyp = agent.tracker.hypotheses()
        truth = sequence.detections.truth
        ids, means, covs = agent.state.full_map()
        for oid, mean, cov in zip(ids.tolist(), means, covs, strict=True):
            named = truth[: hyp.size][hyp == oid]
            values, counts = np.unique(named, return_counts=True)
            if not values.size:
                continue
            error = mean - points[values[np.argmax(counts)]]
            nees.append(error @ np.linalg.solve(cov, error) / 3)
    return float(np.mean(nees)), len(nees)


def test_an_object_seen_only_through_cut_boxes_is_estimated_without_bias():
    with_cut, n = _nees(IMAGE)
    assert n >= 20
    # consistent: the mean NEES/3 of n objects inside χ²(3n)/(3n)'s 99.9% quantile
    assert with_cut < chi2_quantile(0.999, 3 * n) / (3 * n)
    # the same boxes with the cut unnoticed (no image size): the inward bias shows
    without, _ = _nees(None)
    assert without > 3 * with_cut


def test_a_box_the_right_border_cut_has_both_centres_cut():
    # the left box cut at the right border; its right centre the visible part's, 30 px of
    # disparity to the left, where the right image's box (as wide) is clear of its border
    z = np.array([[600.0, 240.0, 570.0, 240.0], [600.0, 240.0, np.nan, np.nan]])
    sizes = np.array([[79.0, 60.0], [79.0, 60.0]])
    rows = box_rows(z, sizes, IMAGE, 0.5, 0.03)
    assert rows[0, 6:].tolist() == [1, 0, 1, 0]
    assert rows[1, 6:].tolist() == [1, 0, 0, 0]  # no right centre: nothing of it to cut
    clear = box_rows(z[:1] - [20.0, 0.0, 20.0, 0.0], sizes[:1], IMAGE, 0.5, 0.03)
    assert not clear[:, 6:].any()  # the same box clear of the border by some σ
    # the tracker bounds both centres from the right, also a wide near box's right centre in
    # the image's left half
    tracker = ObjectTracker(0, CAMERA, T_CAM_BODY, MsckfConfig(), image_size=IMAGE)
    wide = box_rows(np.array([[420.0, 240.0, 300.0, 240.0]]), [[439.0, 60.0]], IMAGE, 0.5, 0.03)
    assert tracker._cut_sides(rows[:1]).tolist() == [[1, 0, 1, 0]]
    assert tracker._cut_sides(wide).tolist() == [[1, 0, 1, 0]]


def _passing_sequence(seed: int, first: float, lateral: tuple, least_depth: float, visible):
    """One robot driving straight past eight objects on its right (one every 5 m from ``first``
    m ahead, ``lateral`` m to the side), each detected between ``least_depth`` and 15 m:
    ``visible(j, z_true, width)`` the part of object ``j`` its box shows — the left centre and
    the visible width, or ``None`` — at its true stereo centre ``z_true`` and width ``width``
    px; the right centre the visible part's at the object's disparity (as the front-end finds
    it by the part's patch), plus noise. ``visible`` is made by ``visible(rng, depth)`` once
    the objects are drawn, ``depth`` the current depths (``(objects,)``, updated each frame)."""
    rng = np.random.default_rng(seed)
    objects, step = 8, 0.1
    steps = int((first - 2.0 + 5.0 * objects) / step)
    poses = np.tile(np.eye(4), (steps + 1, 1, 1))
    poses[:, 0, 3] = step * np.arange(steps + 1)
    fx = CAMERA.intrinsics[0, 0]
    points = np.column_stack(
        [
            first + 5.0 * np.arange(objects),
            -rng.uniform(*lateral, objects),
            rng.uniform(-0.5, 0.5, objects),
        ]
    )
    half = rng.uniform(0.3, 0.6, objects)  # half-widths in metres
    depth = np.zeros(objects)
    part = visible(rng, depth)
    floor, share = 0.3, 0.03
    offsets, rows, sizes, truth = [0], [], [], []
    for t in range(steps + 1):
        depth[:] = points[:, 0] - poses[t, 0, 3]
        count = 0
        for j in np.flatnonzero((depth > least_depth) & (depth < 15.0)).tolist():
            z_true = observe(CAMERA, T_CAM_BODY, poses[t], points[j][None])[0]
            width, height = 2 * fx * half[j] / depth[j], fx / depth[j]
            shown = part(j, z_true, width)
            if shown is None:
                continue
            centre_l, w_vis = shown
            centre_r = centre_l - (z_true[0] - z_true[2])
            std = np.sqrt(floor**2 + (share * np.array([w_vis, height])) ** 2)
            noise = std[[0, 1, 0, 1]] * rng.standard_normal(4)
            rows.append(np.array([centre_l, z_true[1], centre_r, z_true[3]]) + noise)
            sizes.append([w_vis, height])
            truth.append(j)
            count += 1
        offsets.append(offsets[-1] + count)
    sequence, config = _one_robot(poses, (offsets, rows, sizes, truth), floor, share)
    return sequence, points, config


def _leaving_sequence(seed: int):
    """Objects detected whole and then while the left image's right border cuts them, until
    less than 0.4 of each shows (:func:`_passing_sequence`)."""
    border = IMAGE[0] - 0.5

    def cut(rng, depth):
        def part(j, z_true, width):
            left, right = z_true[0] - width / 2, z_true[0] + width / 2
            if left < -0.5 or border - left < 0.4 * width:
                return None
            if right <= border:
                return z_true[0], width
            return (left + border) / 2, border - left

        return part

    return _passing_sequence(seed, 10.0, (2.0, 4.0), 1.0, cut)


@pytest.mark.parametrize("seed", [0, 1])
def test_an_object_leaving_through_the_right_border_keeps_its_id_and_its_estimate(seed):
    sequence, points, config = _leaving_sequence(seed)
    detections = sequence.detections
    cut = box_rows(detections.measurements, detections.sizes, IMAGE, 0.3, 0.03)[:, 6]
    assert cut.sum() >= 5 * points.shape[0]  # every object leaves through the border
    # one id per object over its whole pass, the cut boxes' included (the right centre taken
    # as uncut puts the cut boxes outside their object's gate: a second track, a second id)
    _assert_one_id_and_a_consistent_estimate_each(sequence, points, config)


def _assert_one_id_and_a_consistent_estimate_each(sequence, points, config) -> None:
    """One robot runs ``sequence``: every box of each object of ``points`` gets that object's
    one id, and each object's final error lies inside χ²(3)'s 99.9 % quantile of its
    covariance."""
    agent = MsckfAgent(0, Calibration(CAMERA, T_CAM_BODY, IMAGE), sequence, config)
    for t in range(sequence.frames):
        agent.step(t)
    detections = sequence.detections
    hyp = agent.tracker.hypotheses()
    metrics = mot_metrics(detections.offsets, detections.truth, hyp)
    assert metrics["fn"] == 0 and metrics["id_switches"] == 0
    assert metrics["objects_created"] == points.shape[0]
    ids, means, covs = agent.state.full_map()
    nees = []
    for oid, mean, cov in zip(ids.tolist(), means, covs, strict=True):
        named = detections.truth[hyp == oid]
        if named.size:
            error = mean - points[np.bincount(named).argmax()]
            nees.append(error @ np.linalg.solve(cov, error))
    assert len(nees) == points.shape[0]
    assert max(nees) < chi2_quantile(0.999, 3)


def test_data_without_box_sizes_keeps_one_sigma():
    team = lissajous_team(robots=2, steps=30, objects=60, seed=1)
    stripped = strip_object_ids(team, to="none")
    assert all(r.detections.sizes is None for r in stripped.robots)
    settings = build_settings(stripped, calibrate="never")
    assert settings.config.filter.object_size_share == 0.0
    assert "filter.object_size_share" not in {
        k for k, v in settings.sources.items() if v == "calibration"
    }


def _occluded_sequence(seed: int):
    """Objects seen whole first (:func:`_passing_sequence`), then for a stretch of their pass
    with an occluder hiding the same side of each (45 to 60 % of its width), then whole again;
    none while leaving the view."""

    def occluded(rng, depth):
        n = depth.size
        hidden = rng.uniform(0.45, 0.6, n) * rng.choice([-1.0, 1.0], n)  # side and share
        near, far = rng.uniform(5.0, 7.0, n), rng.uniform(9.0, 11.0, n)  # the stretch hidden

        def part(j, z_true, width):
            if z_true[0] + width / 2 > IMAGE[0] - 0.5:
                return None
            if not near[j] < depth[j] < far[j]:
                return z_true[0], width
            w_vis = (1.0 - abs(hidden[j])) * width
            return z_true[0] + np.sign(hidden[j]) * (width - w_vis) / 2, w_vis

        return part

    return _passing_sequence(seed, 16.0, (1.0, 2.0), 2.0, occluded)


@pytest.mark.parametrize("seed", [0, 1])
def test_an_object_an_occluder_hides_in_part_keeps_its_id_and_its_estimate(seed):
    """A box an occluder cut short lies off its object's centre by half the hidden part (here
    up to 18 σ of the box noise): taken as it is, it starts a second track and drags the
    object's estimate; taken at the edge the occluder left, the object keeps one id and an
    estimate its covariance covers."""
    sequence, points, config = _occluded_sequence(seed)
    _assert_one_id_and_a_consistent_estimate_each(sequence, points, config)
