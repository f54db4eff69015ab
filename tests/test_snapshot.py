"""The agent owns its state: snapshot/restore (arrays only) continue a run exactly."""

from __future__ import annotations

import numpy as np
import pytest

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
