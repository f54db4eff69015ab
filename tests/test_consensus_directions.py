"""Consensus keeps each robot's rigid-motion directions at its own first estimates."""

from __future__ import annotations

import numpy as np
import pytest

from teamslam.msckf import config_for, run_team
from teamslam.msckf.agent import MsckfAgent
from teamslam.msckf.consensus.checks import receive_marginal
from teamslam.msckf.consensus.directions import (
    at_first_estimates,
    reexpressed_information,
    rigid_directions,
)
from teamslam.msckf.consensus.marginals import common_marginal_message
from teamslam.sim import long_route_team


def _along(info: np.ndarray, points: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """``Uᵀ Ω U``: the information of a marginal along the rigid motions at ``points``."""
    u = rigid_directions(points, centre)
    return u.T @ info @ u


def _excess(info_a: np.ndarray, info_b: np.ndarray) -> float:
    """Largest generalised eigenvalue of ``info_a`` against ``info_b`` (1: no more)."""
    w, v = np.linalg.eigh(info_b)
    half = v @ np.diag(w**-0.5) @ v.T
    return float(np.linalg.eigvalsh(half @ info_a @ half).max())


def test_reexpressed_information_moves_the_rigid_motions_and_nothing_else():
    rng = np.random.default_rng(3)
    k = 7
    points = rng.normal(size=(k, 3)) * 15 + [250.0, -40.0, 1.0]
    others = points + rng.normal(size=(k, 3)) * 2.0
    a = rng.normal(size=(3 * k, 3 * k))
    info = a @ a.T + 0.1 * np.eye(3 * k)
    cov = np.linalg.inv(info)
    moved, moved_cov = reexpressed_information(info, points, others, cov)
    centre = points.mean(axis=0)
    before = _along(info, points, centre)
    after = _along(moved, others, centre)
    np.testing.assert_allclose(after, before, rtol=1e-9, atol=1e-9 * np.abs(before).max())
    # the information along the old directions is not what it was: the change is real
    assert np.abs(_along(moved, points, centre) - before).max() > 1e-3 * np.abs(before).max()
    # directions Ω-orthogonal to the old rigid motions keep their information
    u = rigid_directions(points, centre)
    q, _ = np.linalg.qr(np.linalg.solve(info, np.linalg.svd(u.T)[2][6:].T))
    np.testing.assert_allclose(q.T @ np.linalg.inv(moved_cov) @ q, q.T @ info @ q, rtol=1e-8)
    np.testing.assert_allclose(np.linalg.inv(moved_cov), moved, rtol=1e-8, atol=1e-10)
    # moving back gives the marginal it started from
    back = reexpressed_information(moved, others, points)
    np.testing.assert_allclose(back, info, rtol=1e-9, atol=1e-9 * np.abs(info).max())
    # agreeing points, or too few objects to span six directions: the same array
    assert reexpressed_information(info, points, points) is info
    two = info[:6, :6]
    assert reexpressed_information(two, points[:2], others[:2]) is two


@pytest.fixture(scope="module")
def two_robots():
    """Two `fej` robots side by side on the long route, each alone, so that each first
    estimates the objects they share by itself."""
    dataset = long_route_team(robots=2, steps=40, seed=43, noise_seed=1)
    config = config_for(dataset, {"filter.linearization": "fej", "filter.window": 10})
    agents = [MsckfAgent(r, dataset.calibration, dataset.robots[r], config) for r in range(2)]
    for t in range(dataset.robots[0].frames):
        for agent in agents:
            agent.step(t)
    return agents


def test_a_neighbour_marginal_tells_no_more_about_our_rigid_motions_than_its_own(two_robots):
    """Robot 1's marginal of the objects both robots hold, as robot 0 averages it: along robot
    0's rigid motions at its first estimates it carries what it carries along robot 1's at its
    own. Sent as the state holds it, it carries far more: the robots first estimated the same
    objects metres apart, and what robot 1 knows of their shape then reads as knowledge of
    robot 0's unobservable rotations."""
    ours, theirs = (agent.state for agent in two_robots)
    common = np.intersect1d(ours.object_ids, theirs.object_ids)
    assert common.size >= 10
    first_ours = ours.object_fe[ours.object_slots(common)]
    first_theirs = theirs.object_fe[theirs.object_slots(common)]
    assert np.median(np.linalg.norm(first_ours - first_theirs, axis=1)) > 0.1
    cols = theirs.object(theirs.object_slots(common)).columns.ravel()
    own_info = np.linalg.inv(theirs.covariance(cols))
    centre = first_theirs.mean(axis=0)
    reference = _along(own_info, first_theirs, centre)  # robot 1's, along its own directions
    received = {}
    for directions in (False, True):
        message = common_marginal_message(
            theirs, 1, 0, 0, common, information=True, directions=directions
        )
        problem, marginal = receive_marginal(ours, message)
        assert problem is None
        if directions:
            marginal = at_first_estimates(ours, marginal)
        received[directions] = _along(marginal.info, first_ours, centre)
    assert _excess(received[True], reference) == pytest.approx(1.0, abs=1e-6)
    assert _excess(reference, received[True]) == pytest.approx(1.0, abs=1e-6)
    assert _excess(received[False], reference) > 1.5


def test_filters_without_first_estimates_average_as_before():
    """`std` is not touched by the setting (bit for bit); `fej` is."""
    dataset = long_route_team(robots=3, steps=25, seed=43, noise_seed=0)
    for linearization, same in (("std", True), ("fej", False)):
        config = config_for(dataset, {"filter.linearization": linearization, "filter.window": 8})
        poses = [
            np.stack(
                run_team(
                    dataset, config.with_({"consensus.rigid_directions": on}), progress=False
                ).poses
            )
            for on in (False, True)
        ]
        assert np.array_equal(poses[0], poses[1]) == same
