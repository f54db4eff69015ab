"""The agent owns its state: snapshot/restore (arrays only) continue a run exactly."""

from __future__ import annotations

import numpy as np
import pytest

from teamslam.datasets.identity import strip_object_ids
from teamslam.msckf import config_for
from teamslam.msckf.agent import MsckfAgent
from teamslam.sim import lissajous_team


@pytest.fixture(scope="module")
def solo():
    dataset = lissajous_team(robots=1, steps=30, seed=4)
    return dataset, config_for(dataset, {"filter.window": 6})


def _agent(solo, linearization="std"):
    dataset, config = solo
    config = config.with_({"filter.linearization": linearization})
    return MsckfAgent(0, dataset.calibration, dataset.robots[0], config)


@pytest.mark.parametrize("linearization", ["std", "fej"])
def test_restored_agent_continues_exactly_like_the_original(solo, linearization):
    """Also with first-estimate Jacobians: the first estimates are part of the snapshot."""
    original = _agent(solo, linearization)
    for t in range(12):
        original.step(t)
    snapshot = original.snapshot()
    assert all(isinstance(v, np.ndarray) for v in snapshot.values())
    assert all(v.dtype != object for v in snapshot.values())
    resumed = _agent(solo, linearization)
    resumed.restore({k: v.copy() for k, v in snapshot.items()})
    for t in range(12, 30):
        original.step(t)
        resumed.step(t)
    np.testing.assert_array_equal(resumed.state.poses, original.state.poses)
    np.testing.assert_array_equal(resumed.state.cov, original.state.cov)
    np.testing.assert_array_equal(resumed.state.objects, original.state.objects)
    assert dict(resumed.counters) == dict(original.counters)


def test_a_restored_agent_keeps_the_views_of_its_objects(solo):
    dataset, config = solo
    config = config.with_({"association.mode": "own"})
    original = MsckfAgent(0, dataset.calibration, dataset.robots[0], config)
    for t in range(12):
        original.step(t)
    assert len(original.views) > 0
    resumed = MsckfAgent(0, dataset.calibration, dataset.robots[0], config)
    resumed.restore({k: v.copy() for k, v in original.snapshot().items()})
    for t in range(12, 30):
        original.step(t)
        resumed.step(t)
    ids = original.views.ids
    assert np.array_equal(resumed.views.ids, ids)
    np.testing.assert_array_equal(resumed.views.of(ids), original.views.of(ids))


@pytest.mark.parametrize(
    ("edit", "reason"),
    [
        (lambda s: s.pop("state_cov"), "lacks"),
        (lambda s: s.__setitem__("state_cov", s["state_cov"][:-1, :-1]), "state dimension"),
        (lambda s: s.__setitem__("state_cov", -s["state_cov"]), "not positive definite"),
        (lambda s: s["state_objects"].__setitem__((0, 0), np.nan), "non-finite"),
        (lambda s: s.__setitem__("frame", np.array(99)), "snapshot at frame 99"),
    ],
)
def test_a_bad_snapshot_is_named_and_changes_nothing(solo, edit, reason):
    agent = _agent(solo)
    for t in range(12):
        agent.step(t)
    snapshot = agent.snapshot()
    assert snapshot["state_objects"].size > 0
    edit(snapshot)
    fresh = _agent(solo)
    before = fresh.state.snapshot()
    with pytest.raises(ValueError, match=reason):
        fresh.restore(snapshot)
    for k, v in fresh.state.snapshot().items():
        np.testing.assert_array_equal(v, before[k])
    assert fresh.frame == -1


@pytest.fixture(scope="module")
def detected():
    """One robot's detections without ids (clutter, misses, classes, appearance): its agent
    tracks them, with loop closure in its own map."""
    team = lissajous_team(
        robots=1, steps=160, seed=0, clutter=0.05, miss=0.1, classes=3, appearance=8
    )
    config = config_for(team, calibrate="never").with_({"tracking.loop_closure": True})
    return strip_object_ids(team, to="none"), config


def _same(a, b, where: str) -> None:
    """``a`` and ``b`` equal, arrays bit for bit, through dicts, lists, tuples and objects."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        assert np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True), where
    elif isinstance(a, dict):
        assert isinstance(b, dict) and list(a) == list(b), where
        for k in a:
            _same(a[k], b[k], f"{where}[{k!r}]")
    elif isinstance(a, list | tuple):
        assert type(a) is type(b) and len(a) == len(b), where
        for k, (x, y) in enumerate(zip(a, b, strict=True)):
            _same(x, y, f"{where}[{k}]")
    elif hasattr(a, "__dict__") and not callable(a):
        assert type(a) is type(b), where
        _same(vars(a), vars(b), where)
    elif not callable(a):
        assert a == b, where


def test_a_restored_tracker_continues_with_the_same_ids(detected):
    """A robot resumed from a snapshot tracks on exactly as the uninterrupted one: the same
    estimate bit for bit, the same ids for every detection, the same merges (loop closure) and
    appearance statistics — every part of the tracker alike."""
    dataset, config = detected
    robot = dataset.robots[0]
    original = MsckfAgent(0, dataset.calibration, robot, config)
    for t in range(80):
        original.step(t)
    snapshot = original.snapshot()
    assert original.tracker.appearance is not None and original.tracker.history
    resumed = MsckfAgent(0, dataset.calibration, robot, config)
    resumed.restore({k: v.copy() for k, v in snapshot.items()})
    for t in range(80, robot.frames):
        original.step(t)
        resumed.step(t)
    np.testing.assert_array_equal(resumed.state.poses, original.state.poses)
    np.testing.assert_array_equal(resumed.state.cov, original.state.cov)
    np.testing.assert_array_equal(resumed.state.objects, original.state.objects)
    np.testing.assert_array_equal(resumed.tracker.hypotheses(), original.tracker.hypotheses())
    assert dict(resumed.counters) == dict(original.counters)
    views = ("views", "config", "camera")  # the robot's own (rebuilt on restore)
    for name, value in vars(original.tracker).items():
        if name not in views:
            _same(getattr(resumed.tracker, name), value, f"tracker.{name}")


def test_a_snapshot_of_a_tracking_robot_without_its_tracker_is_named(detected):
    dataset, config = detected
    agent = MsckfAgent(0, dataset.calibration, dataset.robots[0], config)
    for t in range(12):
        agent.step(t)
    snapshot = {k: v for k, v in agent.snapshot().items() if not k.startswith("tracker_")}
    fresh = MsckfAgent(0, dataset.calibration, dataset.robots[0], config)
    with pytest.raises(ValueError, match="lacks 'tracker_ids'"):
        fresh.restore(snapshot)
    assert fresh.frame == -1 and fresh.tracker.log == []
