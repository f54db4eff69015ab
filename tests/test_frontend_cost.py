"""The front-end's cost accounting and its shared conversions: the stage clock counts each stage
of a frame inside the frame's own time, and an image converted once by the caller gives the same
measurements as each part converting it itself."""

from __future__ import annotations

import time

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2", reason="the images extra (OpenCV) is not installed")

from teamslam.frontend import (  # noqa: E402
    FeatureTracker,
    FrontendConfig,
    StereoFrontend,
    StereoRig,
    match_stereo,
)
from teamslam.frontend._clock import STAGES, StageClock  # noqa: E402
from teamslam.sim.render import T_CAM_BODY, RenderConfig, render_stereo, render_team  # noqa: E402

SMALL = {"image_size": (320, 240), "focal": 210.0, "marker_size": 0.9, "steps": 4, "robots": 1}


@pytest.fixture(scope="module")
def rendered():
    config = RenderConfig(**SMALL)
    team = render_team(config)
    rng = np.random.default_rng(5)
    frames = [render_stereo(team.room, team.T_world_cam(0, k), rng) for k in range(5)]
    rig = StereoRig.rectified(config.image_size, config.camera(), T_CAM_BODY)
    return rig, frames


def test_the_stage_clock_sums_each_stage_and_starts_again_on_reset():
    clock = StageClock()
    with clock.stage("a"):
        sum(range(1000))
    with pytest.raises(ZeroDivisionError), clock.stage("a"):
        1 / 0  # noqa: B018 — a stage that fails is counted too
    with clock.stage("b"):
        pass
    assert set(clock.seconds) == {"a", "b"}
    assert all(s >= 0 for s in clock.seconds.values())
    seconds = clock.reset()
    assert set(seconds) == {"a", "b"} and clock.seconds == {}


def test_each_stage_of_a_frame_is_counted_within_the_frame(rendered):
    rig, frames = rendered
    frontend = StereoFrontend(rig)
    for k, (left, right) in enumerate(frames):
        frontend.clock.reset()
        begin = time.process_time()
        frontend.process(left, right)
        spent = time.process_time() - begin
        stages = frontend.clock.reset()
        assert set(stages) <= set(STAGES)
        # disjoint blocks inside the frame on the same clock: never more than the frame
        assert sum(stages.values()) <= spent + 1e-9
        expected = {"rectification", "feature detection", "stereo search", "markers"}
        if k:  # tracks followed from the frame before, matched from their disparity
            expected |= {"temporal LK", "track alignment", "stereo LK", "stereo alignment"}
        assert expected <= set(stages), sorted(expected - set(stages))


def test_a_float_image_given_once_measures_what_each_part_converting_it_measures(rendered):
    rig, frames = rendered
    config = FrontendConfig()
    px = config.pixels(rig.image_size)
    disparities = config.disparity_range(rig.camera.fx_baseline)
    converted, given = (
        FeatureTracker(rig.image_size, config),
        FeatureTracker(rig.image_size, config),
    )
    matched = 0
    for left, right in frames:
        ids, uv = converted.track(left)
        ids_g, uv_g = given.track(left, image_f=left.astype(np.float32))
        np.testing.assert_array_equal(ids, ids_g)
        assert uv.tobytes() == uv_g.tobytes()
        a = match_stereo(left, right, uv, disparities, config, px)
        b = match_stereo(left, right, uv, disparities, config, px, left_f=left.astype(np.float32))
        np.testing.assert_array_equal(a.accepted, b.accepted)
        np.testing.assert_array_equal(a.searched, b.searched)
        assert a.uv_right.tobytes() == b.uv_right.tobytes()
        matched += int(a.accepted.sum())
    assert matched > 100  # the comparison covered real matches


def test_corners_are_looked_for_every_detection_interval_frames_and_a_checkpoint_keeps_it(
    rendered,
):
    rig, frames = rendered
    config = FrontendConfig(detection_interval=3)
    tracker = FeatureTracker(rig.image_size, config)
    new_in = []
    for k, (left, _) in enumerate(frames):
        before = tracker.next_id
        tracker.track(left)
        if tracker.next_id > before:
            new_in.append(k)
        if k == 1:
            state = tracker.state_dict()
    assert new_in == [0, 3]  # the first frame, then every third
    # from a checkpoint after frame 1 the schedule goes on as in the run it came from
    resumed = FeatureTracker(rig.image_size, config)
    resumed.load_state_dict(state)
    for left, _ in frames[2:]:
        ids, uv = resumed.track(left)
    np.testing.assert_array_equal(ids, tracker.ids)
    assert uv.tobytes() == tracker.uv.astype(np.float64).tobytes()
    assert resumed.next_id == tracker.next_id


def test_detection_interval_below_one_is_refused():
    from teamslam.errors import InputError

    with pytest.raises(InputError, match="detection_interval"):
        FrontendConfig(detection_interval=0)
