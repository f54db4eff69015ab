"""The state is reached through typed handles: poses and objects know their columns, the
covariance leaves the state read-only, and a robot's window forwards nothing silently."""

from __future__ import annotations

import numpy as np
import pytest

from teamslam.geometry import se3
from teamslam.msckf.filter.state import MsckfState, ObjectHandle, PoseHandle


def _team_state() -> MsckfState:
    """Three robots, robot 1 with four window poses, two objects."""
    state = MsckfState.team(np.tile(np.eye(4), (3, 1, 1)), 0, 1e-2 * np.eye(6))
    rng = np.random.default_rng(2)
    for t in range(1, 4):
        state.augment(se3.exp(0.1 * rng.normal(size=6)), t, 1e-3 * np.eye(6), robot=1)
    for oid in (40, 41):
        state.add_object(oid, rng.normal(size=3), np.eye(3), 1e-3 * np.ones((3, state.dim)))
    return state


def test_pose_handles_of_a_robot_window_point_at_that_robots_columns():
    state = _team_state()
    window = state.window(1)
    newest = window.newest_pose()
    assert isinstance(newest, PoseHandle)
    # robot 0 holds window position 0, robot 1 positions 1–4, robot 2 position 5
    assert int(newest.window_index) == 4 and int(newest.frames) == 3
    np.testing.assert_array_equal(newest.columns, np.arange(24, 30))
    pair = window.pose(np.array([0, 1]))
    np.testing.assert_array_equal(pair.frames, [0, 1])
    np.testing.assert_array_equal(pair.columns.ravel(), np.arange(6, 18))
    # the covariance of a handle is the block of its columns
    np.testing.assert_array_equal(
        state.covariance(pair), state.cov[np.ix_(np.arange(6, 18), np.arange(6, 18))]
    )
    np.testing.assert_array_equal(window.current_pose_cov(), state.covariance(newest))


def test_object_handles_know_ids_and_columns():
    state = _team_state()
    objects = state.object(np.array([1, 0]))
    assert isinstance(objects, ObjectHandle)
    np.testing.assert_array_equal(objects.ids, [41, 40])
    first = 6 * state.n_poses
    np.testing.assert_array_equal(objects.columns, [first + np.arange(3, 6), first + np.arange(3)])
    np.testing.assert_array_equal(state.covariance(objects.columns), np.stack([np.eye(3)] * 2))


def test_the_covariance_leaves_the_state_read_only():
    state = _team_state()
    before = state.snapshot()["cov"]
    for view in (state.cov, state.current_pose_cov(), state.covariance(slice(0, 12))):
        with pytest.raises(ValueError, match="read-only"):
            view[0, 0] += 1.0
    np.testing.assert_array_equal(state.cov, before)


def test_a_robot_window_forwards_only_what_it_names():
    window = _team_state().window(1)
    assert window.dim == window.state.dim and window.n_objects == 2
    for hidden in ("correct", "_check", "robots", "no_such_thing"):
        with pytest.raises(AttributeError):
            getattr(window, hidden)
