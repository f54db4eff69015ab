"""Consensus adds nothing along a first-estimates filter's rigid motions at its first estimates."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import scipy.linalg

from teamslam.geometry import se3
from teamslam.msckf import config_for, run_team
from teamslam.msckf.agent import MsckfAgent
from teamslam.msckf.consensus.average import consensus_average
from teamslam.msckf.consensus.directions import constrained_average, rigid_directions
from teamslam.msckf.consensus.marginals import common_marginal_message
from teamslam.sim import long_route_team


def _spd(rng: np.random.Generator, n: int) -> np.ndarray:
    a = rng.normal(size=(n, n))
    return a @ a.T + 0.1 * np.eye(n)


def test_constrained_average_keeps_the_rigid_motions_and_averages_the_rest():
    rng = np.random.default_rng(3)
    k = 7
    first = rng.normal(size=(k, 3)) * 15 + [250.0, -40.0, 1.0]
    own_info, avg_info = _spd(rng, 3 * k), _spd(rng, 3 * k) * 3.0
    own_mean = first.ravel() + rng.normal(size=3 * k)
    avg_mean = own_mean + rng.normal(size=3 * k)
    mean, cov = constrained_average(own_mean, own_info, avg_mean, np.linalg.inv(avg_info), first)
    info = np.linalg.inv(cov)
    u = rigid_directions(first, np.zeros(3))
    # Ω' U = Ω U: nothing gained or lost along the rigid motions, nor between them and the rest
    np.testing.assert_allclose(
        info @ u, own_info @ u, rtol=1e-7, atol=1e-7 * np.abs(own_info @ u).max()
    )
    # the information vector moves by nothing along them either: Uᵀ(Ω'μ' − Ωμ) = Uᵀ Ω' (μ' − μ)
    np.testing.assert_allclose(u.T @ info @ (mean - own_mean), 0.0, atol=1e-6 * np.abs(u).max())
    # every quantity cᵀx the rigid motions leave unchanged (cᵀU = 0: the map's shape) takes the
    # average's mean and variance — no more information than the average has of it
    c = np.linalg.svd(u.T)[2][6:]  # (3k − 6, 3k): c U = 0
    avg_cov = np.linalg.inv(avg_info)
    np.testing.assert_allclose(c @ cov @ c.T, c @ avg_cov @ c.T, rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(c @ mean, c @ avg_mean, rtol=1e-9, atol=1e-9)
    # one object: its rigid motions are every direction it has, so the average is undone
    one = constrained_average(
        own_mean[:3], own_info[:3, :3], avg_mean[:3], np.linalg.inv(avg_info[:3, :3]), first[:1]
    )
    np.testing.assert_allclose(one[0], own_mean[:3], atol=1e-9)
    np.testing.assert_allclose(np.linalg.inv(one[1]), own_info[:3, :3], rtol=1e-9)


@pytest.fixture(scope="module")
def two_robots():
    """Two `fej` robots side by side on the long route, each alone so far: each first
    estimated the objects they share by itself."""
    dataset = long_route_team(robots=2, steps=40, seed=43, noise_seed=1)
    config = config_for(dataset, {"filter.linearization": "fej", "filter.window": 10})
    agents = [MsckfAgent(r, dataset.calibration, dataset.robots[r], config) for r in range(2)]
    for t in range(dataset.robots[0].frames):
        for agent in agents:
            agent.step(t)
    return agents


def _rigid_information(state) -> np.ndarray:
    """``Uᵀ Σ⁻¹ U``: the state's information along the rigid motions of the world at its
    first estimates (window poses and objects)."""
    u = np.zeros((state.dim, 6))
    u[: 6 * state.n_poses] = se3.adjoint(se3.inverse(state.pose_fe)).reshape(-1, 6)
    u[6 * state.n_poses :] = rigid_directions(state.object_fe, np.zeros(3))
    return u.T @ np.linalg.solve(state.cov, u)


def test_an_average_gives_no_information_along_our_rigid_motions(two_robots):
    """Robot 0 averages robot 1's marginal of their common objects. The robots first estimated
    them apart, so robot 1's marginal, taken as it is, hands robot 0 information along its
    rigid motions that no measurement gave; constrained, the average leaves robot 0's whole
    state's information along them as it was, and still moves its map."""
    ours, theirs = (agent.state for agent in two_robots)
    common = np.intersect1d(ours.object_ids, theirs.object_ids)
    assert common.size >= 10
    apart = (
        ours.object_fe[ours.object_slots(common)] - theirs.object_fe[theirs.object_slots(common)]
    )
    assert np.median(np.linalg.norm(apart, axis=1)) > 0.1
    message = common_marginal_message(theirs, 1, 0, 0, common, information=True)
    before = _rigid_information(ours)
    scale = np.sqrt(np.outer(np.diag(before), np.diag(before)))
    gained, states = {}, {}
    for constrained in (False, True):
        state = copy.deepcopy(ours)
        consensus_average(state, 0.5, [(0.5, message)], rigid_directions=constrained)
        gained[constrained] = (_rigid_information(state) - before) / scale
        assert not np.allclose(state.objects, ours.objects)
        states[constrained] = state
    assert np.abs(gained[True]).max() < 1e-6
    assert np.abs(gained[False]).max() > 1e-2
    # the shape of the common map (every cᵀy with cᵀU = 0) is known exactly as well as the
    # average knows it, not better: taking the average's information on the complement of U
    # as it is (without marginalising its part along U) claimed several times more
    slots = ours.object_slots(common)
    c = np.linalg.svd(rigid_directions(ours.object_fe[slots], np.zeros(3)).T)[2][6:]
    shape = {}
    for constrained, state in states.items():
        cols = state.object(state.object_slots(common)).columns.ravel()
        shape[constrained] = c @ state.cov[np.ix_(cols, cols)] @ c.T
    ratio = scipy.linalg.eigh(shape[False], shape[True], eigvals_only=True)
    np.testing.assert_allclose(ratio, 1.0, rtol=1e-6)


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
