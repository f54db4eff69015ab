"""Consensus adds nothing along a first-estimates filter's rigid motions at its first estimates,
and averaging again marginals that did not change adds no information."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import scipy.linalg

from teamslam.gaussian import completed_geometric_average
from teamslam.geometry import se3
from teamslam.msckf import config_for, run_team
from teamslam.msckf.agent import MsckfAgent
from teamslam.msckf.consensus.average import consensus_average
from teamslam.msckf.consensus.checks import receive_marginal
from teamslam.msckf.consensus.directions import (
    at_first_estimates,
    constrained_average,
    reexpressed_information,
    rigid_directions,
    shape_average,
)
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


def _shape_information(info: np.ndarray, u: np.ndarray) -> np.ndarray:
    """``S(Ω) = Ω − Ω U (Uᵀ Ω U)⁻¹ Uᵀ Ω``: what ``Ω`` knows of the shape (``U`` marginalised)."""
    w = info @ u
    return info - w @ np.linalg.solve(u.T @ w, w.T)


def test_shape_average_averages_the_shape_marginals_and_keeps_the_rigid_motions():
    """The plain average of a first-estimates filter: our marginal along our rigid motions as it
    was, and on the shape the eq. 19 average of the robots' shape marginals — each neighbour's
    marginal completed by our conditional on the objects it lacks (eq. 42)."""
    rng = np.random.default_rng(5)
    k = 7
    first = rng.normal(size=(k, 3)) * 15 + [250.0, -40.0, 1.0]
    own_info = _spd(rng, 3 * k)
    own_cov = np.linalg.inv(own_info)
    own_mean = first.ravel() + rng.normal(size=3 * k)
    u = rigid_directions(first, np.zeros(3))
    terms, completed = [], []
    for weight, objects in ((0.3, np.arange(k)), (0.25, np.array([0, 2, 3, 5, 6]))):
        sub = (3 * objects[:, None] + np.arange(3)).ravel()
        m_info = _spd(rng, sub.size) * 2.0
        m_mean = own_mean[sub] + rng.normal(size=sub.size)
        own_sub = np.linalg.inv(own_cov[np.ix_(sub, sub)])
        terms.append((weight, sub, m_info, m_info @ m_mean, own_sub))
        # completed by our conditional: information Ω + Lᵀ(M − Ω_C)L, vector likewise
        info_j = own_info.copy()
        info_j[np.ix_(sub, sub)] += m_info - own_sub
        eta_j = own_info @ own_mean
        eta_j[sub] += m_info @ m_mean - own_sub @ own_mean[sub]
        completed.append((weight, info_j, eta_j))
    completed.append((1.0 - 0.3 - 0.25, own_info, own_info @ own_mean))
    mean, cov = shape_average(own_mean, own_info, terms, first)
    info = np.linalg.inv(cov)
    # Ω' U = Ω U and the mean does not move along U
    np.testing.assert_allclose(
        info @ u, own_info @ u, rtol=1e-7, atol=1e-7 * np.abs(own_info @ u).max()
    )
    np.testing.assert_allclose(u.T @ own_info @ (mean - own_mean), 0.0, atol=1e-6 * np.abs(u).max())
    # on the shape: the weighted sum of the completed marginals' shape informations and vectors
    shape = sum(w * _shape_information(i, u) for w, i, _ in completed)
    vector = sum(w * _shape_information(i, u) @ np.linalg.solve(i, e) for w, i, e in completed)
    scale = np.abs(shape).max()
    np.testing.assert_allclose(_shape_information(info, u), shape, atol=1e-8 * scale)
    np.testing.assert_allclose(
        _shape_information(info, u) @ mean, vector, atol=1e-8 * np.abs(vector).max()
    )
    # a neighbour marginal equal to ours leaves ours as it was
    same = shape_average(
        own_mean,
        own_info,
        [(0.5, np.arange(3 * k), own_info, own_info @ own_mean, own_info)],
        first,
    )
    np.testing.assert_allclose(same[0], own_mean, atol=1e-9)
    np.testing.assert_allclose(np.linalg.inv(same[1]), own_info, rtol=1e-9, atol=1e-9)


def test_averaging_again_marginals_that_did_not_change_adds_no_information():
    """Two robots with the same first estimates average each other's marginal twice with no
    measurement in between. The first average makes their shape marginals agree, so the second
    changes nothing. The marginal of the joint average (the constrained version of a finished
    average) instead gains shape information at every repeat — each robot keeps its own
    information along U, and the two rigid parts together know something of the shape — which
    is how `consensus.set=all` built up overconfidence with first estimates: an old object that
    moved is averaged again, and the invented information moves it again."""
    rng = np.random.default_rng(11)
    k = 6
    first = rng.normal(size=(k, 3)) * 15
    u = rigid_directions(first, np.zeros(3))
    everything = np.arange(3 * k)
    for version in ("shape", "marginal"):
        infos = [_spd(rng, 3 * k), _spd(rng, 3 * k)]
        means = [first.ravel() + rng.normal(size=3 * k) for _ in range(2)]
        shape = []
        for _ in range(3):
            new = []
            for r in range(2):
                other = infos[1 - r], infos[1 - r] @ means[1 - r]
                if version == "shape":
                    term = (0.5, everything, *other, infos[r])
                    new.append(shape_average(means[r], infos[r], [term], first))
                else:
                    avg_info = 0.5 * (infos[r] + other[0])
                    avg_mean = np.linalg.solve(avg_info, 0.5 * (infos[r] @ means[r] + other[1]))
                    avg = avg_mean, np.linalg.inv(avg_info)
                    new.append(constrained_average(means[r], infos[r], *avg, first))
            means = [m for m, _ in new]
            infos = [np.linalg.inv(c) for _, c in new]
            shape.append(_shape_information(infos[0], u))
        # generalised eigenvalues of the shape information after the third average against the
        # first's (the 6 directions along U are zero in both: left out)
        c = np.linalg.svd(u.T)[2][6:]
        gain = scipy.linalg.eigh(c @ shape[2] @ c.T, c @ shape[0] @ c.T, eigvals_only=True)
        if version == "shape":
            np.testing.assert_allclose(gain, 1.0, rtol=1e-7)
        else:
            assert gain.max() > 1.5


@pytest.fixture(scope="module")
def two_robots():
    """Two `fej` robots side by side on the long route, each alone so far: each first
    estimated the objects they share by itself."""
    dataset = long_route_team(robots=2, steps=40, seed=43, noise_seed=1)
    # objects enter from their first views, each robot's first estimates as far apart as a
    # few views leave them, and keep them (not re-anchored: a robot in a team keeps them too)
    settings = {
        "filter.linearization": "fej",
        "filter.window": 10,
        "objects.init_linearity_probability": 0,
        "objects.reanchor_probability": 0,
    }
    config = config_for(dataset, settings)
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
    # the shape of the common map (every cᵀy with cᵀU = 0): the eq. 19 average of the two
    # robots' shape marginals, never more than the unconstrained average knows of it
    slots = ours.object_slots(common)
    u = rigid_directions(ours.object_fe[slots], np.zeros(3))
    cols = ours.object(slots).columns.ravel()
    own = np.linalg.inv(ours.cov[np.ix_(cols, cols)])
    expected = 0.5 * (_shape_information(own, u) + _shape_information(message.info, u))
    shape = {}
    for constrained, state in states.items():
        cols = state.object(state.object_slots(common)).columns.ravel()
        shape[constrained] = _shape_information(np.linalg.inv(state.cov[np.ix_(cols, cols)]), u)
    c = np.linalg.svd(u.T)[2][6:]
    ratio = scipy.linalg.eigh(c @ shape[True] @ c.T, c @ expected @ c.T, eigvals_only=True)
    np.testing.assert_allclose(ratio, 1.0, rtol=1e-6)
    less = scipy.linalg.eigh(c @ shape[True] @ c.T, c @ shape[False] @ c.T, eigvals_only=True)
    assert less.max() < 1 + 1e-6


def test_repeated_averages_with_an_unchanged_neighbour_end_with_its_knowledge_of_the_shape(
    two_robots,
):
    """Robot 0 averages robot 1's marginal, unchanged, again and again: its shape information
    moves half way to robot 1's each time (a convex combination), and ends with robot 1's — not
    more, as the marginal of the joint average gave it."""
    ours, theirs = (agent.state for agent in two_robots)
    common = np.intersect1d(ours.object_ids, theirs.object_ids)
    message = common_marginal_message(theirs, 1, 0, 0, common, information=True)
    slots = ours.object_slots(common)
    u = rigid_directions(ours.object_fe[slots], np.zeros(3))
    c = np.linalg.svd(u.T)[2][6:]
    cols = ours.object(slots).columns.ravel()

    def shape_of(state):
        info = np.linalg.inv(state.cov[np.ix_(cols, cols)])
        return c @ _shape_information(info, u) @ c.T

    start, neighbour = shape_of(ours), c @ _shape_information(message.info, u) @ c.T
    state = copy.deepcopy(ours)
    for n in range(1, 4):
        consensus_average(state, 0.5, [(0.5, message)], rigid_directions=True)
        expected = 0.5**n * start + (1 - 0.5**n) * neighbour
        ratio = scipy.linalg.eigh(shape_of(state), expected, eigvals_only=True)
        np.testing.assert_allclose(ratio, 1.0, rtol=1e-5)


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


def _linear_team(rng: np.random.Generator, k: int = 6):
    """Two robots' marginals of ``k`` common objects in a linear-Gaussian team with the same
    first estimates (where eq. 19's guarantees hold): each map is the truth moved by the team's
    common placement error ``g`` (the starts' shared world frame, covariance ``prior``) and by
    the robot's own drift ``d_i`` along the rigid motions ``U``, plus its own shape error.
    Robot 0 drifted far, robot 1 hardly at all. Returns the first estimates, ``U``, the prior,
    each robot's covariance and the joint covariance of the two robots' errors."""
    first = rng.normal(size=(k, 3)) * 12.0 + [80.0, -30.0, 1.0]
    u = rigid_directions(first, first.mean(axis=0))
    prior = np.diag([0.02**2] * 3 + [1e-3**2] * 3)
    drifts = (np.diag([2.0**2] * 3 + [0.05**2] * 3), 1e-3 * prior)
    shapes = [0.05**2 * _spd(rng, 3 * k) / (3 * k) for _ in range(2)]
    covs = [u @ (prior + d) @ u.T + n for d, n in zip(drifts, shapes, strict=True)]
    common = u @ prior @ u.T  # the two robots' errors share the placement of the world frame
    joint = np.block([[covs[0], common], [common, covs[1]]])
    return first, u, prior, covs, joint


def test_on_a_linear_team_the_plain_average_pools_drift_but_not_the_world_frame():
    """Robot 0 averages robot 1's marginal, again and again, in a linear-Gaussian team. The
    plain average (eq. 19, ``consensus.rigid_directions=false``) stays consistent — its
    covariance bounds the error of its mean, whatever the two robots' errors share — so along
    the rigid motions of the map it never knows more than the team's prior on the world frame,
    which no measurement and no average can sharpen; and it learns robot 0's drift from robot 1,
    which has hardly drifted, until it knows the placement nearly as well as robot 1.
    Keeping robot 0's own marginal along its rigid motions (``true``) leaves its drift as it
    was: the information the team has on it is thrown away. Adding robot 1's marginal at every
    exchange (counting the shared world frame again each time) breaks the bound."""
    rng = np.random.default_rng(21)
    first, u, prior, covs, joint = _linear_team(rng)
    infos = [np.linalg.inv(c) for c in covs]
    means = [first.ravel() + rng.multivariate_normal(np.zeros(u.shape[0]), c) for c in covs]
    # our coordinates along the rigid motions, b = G y with G U = I
    g = np.linalg.solve(u.T @ infos[0] @ u, u.T @ infos[0])
    n = u.shape[0]
    everything = np.arange(n)
    term = (0.5, everything, infos[1], infos[1] @ means[1])
    mean, cov = means[0], covs[0]
    # the average's error is A e₀ + B e₁ (linear in the two robots' errors)
    gains = np.hstack([np.eye(n), np.zeros((n, n))])
    for _ in range(8):
        info = np.linalg.inv(cov)
        mean, new_cov = completed_geometric_average(mean, cov, [term], info=info)
        gains = 0.5 * new_cov @ (info @ gains + infos[1] @ np.hstack([np.zeros((n, n)), np.eye(n)]))
        cov = new_cov
        # consistent: the covariance of its error under the joint is bounded by the one reported
        error_cov = gains @ joint @ gains.T
        assert np.linalg.eigvalsh(cov - error_cov).min() > -1e-9 * np.abs(cov).max()
        # along the rigid motions never more than the prior on the world frame
        placement = g @ cov @ g.T
        assert scipy.linalg.eigh(prior, placement, eigvals_only=True).max() <= 1 + 1e-9
    # robot 0 learnt its drift from robot 1: it knows its placement nearly as robot 1 does,
    # a hundred times better and more than it did
    neighbour, own = g @ covs[1] @ g.T, g @ covs[0] @ g.T
    assert scipy.linalg.eigh(neighbour, placement, eigvals_only=True).min() > 0.9
    assert scipy.linalg.eigh(placement, own, eigvals_only=True).max() < 0.01
    np.testing.assert_allclose(g @ mean, g @ means[1], atol=0.05 * np.sqrt(np.diag(own)).max())
    # the old constraint keeps robot 0's own marginal along them, drift and all
    kept_mean, kept_cov = shape_average(means[0], infos[0], [(*term, infos[0])], first)
    np.testing.assert_allclose(g @ kept_cov @ g.T, own, atol=1e-9 * np.abs(own).max())
    np.testing.assert_allclose(g @ kept_mean, g @ means[0], atol=1e-8)
    # adding robot 1's information at each exchange instead counts the shared world frame again
    # and again, and claims more than the prior
    summed = np.linalg.inv(infos[0] + 8 * infos[1])
    assert scipy.linalg.eigh(prior, g @ summed @ g.T, eigvals_only=True).max() > 1.5


def _along(info: np.ndarray, points: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """``Uᵀ Ω U``: the information of a marginal along the rigid motions at ``points``."""
    u = rigid_directions(points, centre)
    return u.T @ info @ u


def test_reexpressed_information_moves_the_rigid_motions_and_nothing_else():
    rng = np.random.default_rng(3)
    k = 7
    points = rng.normal(size=(k, 3)) * 15 + [250.0, -40.0, 1.0]
    others = points + rng.normal(size=(k, 3)) * 2.0
    info = _spd(rng, 3 * k)
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


def test_a_moved_marginal_tells_no_more_about_our_rigid_motions_than_its_own(two_robots):
    """Robot 1's marginal of the objects both robots hold, as robot 0 averages it with
    ``consensus.at_first_estimates``: along robot 0's rigid motions at its first estimates it
    carries what it carries along robot 1's at its own — where robot 1 places the map. Sent as
    the state holds it, it carries far more: the robots first estimated the same objects apart,
    and what robot 1 knows of their shape then reads as knowledge of robot 0's unobservable
    rotations."""
    ours, theirs = (agent.state for agent in two_robots)
    common = np.intersect1d(ours.object_ids, theirs.object_ids)
    first_ours = ours.object_fe[ours.object_slots(common)]
    first_theirs = theirs.object_fe[theirs.object_slots(common)]
    assert np.median(np.linalg.norm(first_ours - first_theirs, axis=1)) > 0.1
    cols = theirs.object(theirs.object_slots(common)).columns.ravel()
    own_info = np.linalg.inv(theirs.covariance(cols))
    centre = first_theirs.mean(axis=0)
    reference = _along(own_info, first_theirs, centre)  # robot 1's, along its own directions
    received = {}
    for moved in (False, True):
        message = common_marginal_message(
            theirs, 1, 0, 0, common, information=True, directions=moved
        )
        problem, marginal = receive_marginal(ours, message)
        assert problem is None
        if moved:
            marginal = at_first_estimates(ours, marginal)
        received[moved] = _along(marginal.info, first_ours, centre)
    ratio = scipy.linalg.eigh(received[True], reference, eigvals_only=True)
    np.testing.assert_allclose(ratio, 1.0, atol=1e-6)
    assert scipy.linalg.eigh(received[False], reference, eigvals_only=True).max() > 1.5
