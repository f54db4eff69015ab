"""The bounded consensus set (``consensus.set = active``): which objects are averaged jointly.

Checked: the mutual information with the window poses against its dense formula; the selection
(observed within the window, or correlated beyond the threshold); that the bounded set is the
paper's average when it holds every common object; that an object left out of a step's joint
average is averaged by no pair and keeps its conditional given the averaged objects exactly
(Prop. 2 on the smaller set), so its marginal moves only through that conditional; and that a
left-out object that moves beyond its threshold is averaged again.
"""

from __future__ import annotations

import numpy as np
import pytest

from teamslam.msckf import config_for, run_team
from teamslam.msckf.consensus.protocol import ConsensusProtocol
from teamslam.msckf.consensus.selection import (
    active_objects,
    pose_mutual_information,
    settling_thresholds,
)
from teamslam.msckf.consensus.transport import MemoryNetwork
from teamslam.sim import lissajous_team
from test_consensus_reference import _random_state
from test_protocol import _agents, _exchange


def test_pose_mutual_information_is_the_dense_formula():
    rng = np.random.default_rng(4)
    state = _random_state(rng, poses=4, objects=7)
    cov = np.asarray(state.cov)
    p = 6 * state.n_poses
    covs = state.object_covs()
    expected = []
    for slot in range(state.n_objects):
        o = p + 3 * slot + np.arange(3)
        sigma_oo = cov[np.ix_(o, o)]
        sigma_ox = cov[o, :p]
        conditional = sigma_oo - sigma_ox @ np.linalg.inv(cov[:p, :p]) @ sigma_ox.T
        expected.append(0.5 * np.log(np.linalg.det(sigma_oo) / np.linalg.det(conditional)))
    np.testing.assert_allclose(pose_mutual_information(state, covs), expected, rtol=1e-9)
    some = np.array([5, 2])
    np.testing.assert_allclose(
        pose_mutual_information(state, covs[some], some), np.array(expected)[some], rtol=1e-9
    )


def test_active_objects_are_those_observed_in_the_window_or_correlated_with_its_poses():
    rng = np.random.default_rng(5)
    state = _random_state(rng, poses=4, objects=8)
    covs = state.object_covs()
    information = pose_mutual_information(state, covs)
    # nothing observed within the window (its oldest frame is 0)
    state.object_last_seen[:] = -1
    threshold = float(np.median(information))
    np.testing.assert_array_equal(active_objects(state, covs, threshold), information > threshold)
    assert not active_objects(state, covs, np.inf).any()
    # observed at the oldest window frame: active whatever its correlation
    state.object_last_seen[[1, 6]] = state.frames.min()
    expected = information > threshold
    expected[[1, 6]] = True
    np.testing.assert_array_equal(active_objects(state, covs, threshold), expected)
    np.testing.assert_array_equal(
        active_objects(state, covs, np.inf), np.isin(np.arange(8), [1, 6])
    )


def test_bounded_set_with_one_threshold_for_all_objects_is_the_paper_average():
    """With the inactive threshold equal to ``consensus.kl_threshold`` every common object is in
    the set by the paper's rule: the run is identical to ``consensus.set = all`` (while the
    selection did leave objects inactive, so the equality is not vacuous)."""
    dataset = lissajous_team(robots=3, steps=40, seed=3)
    runs = {}
    for name in ("all", "active"):
        config = config_for(
            dataset,
            {
                "filter.window": 8,
                "filter.use_geometric_features": False,
                "consensus.set": name,
                "consensus.active_information": 0.5,
                "consensus.inactive_kl_threshold": 1e-3,
            },
        )
        runs[name] = run_team(dataset, config, progress=False)
    assert sum(c["objects_inactive"] for c in runs["active"].counters) > 0
    assert all(c.get("objects_inactive", 0) == 0 for c in runs["all"].counters)
    for r in range(dataset.n_robots):
        np.testing.assert_array_equal(runs["active"].poses[r], runs["all"].poses[r])
        np.testing.assert_array_equal(runs["active"].objects[r], runs["all"].objects[r])
        np.testing.assert_array_equal(runs["active"].object_covs[r], runs["all"].object_covs[r])


def _conditional(state, cov: np.ndarray, given: np.ndarray, of: np.ndarray):
    """``(A, Σ_o|J)`` of the objects ``of`` given the objects ``given`` (ids) under ``cov``."""
    j = state.object(state.object_slots(given)).columns.ravel()
    o = state.object(state.object_slots(of)).columns.ravel()
    gain = cov[np.ix_(o, j)] @ np.linalg.inv(cov[np.ix_(j, j)])
    return gain, cov[np.ix_(o, o)] - gain @ cov[np.ix_(j, o)]


@pytest.fixture(scope="module")
def team4():
    return lissajous_team(robots=4, steps=30, seed=2, landmarks=600), None


def _with_inactive_copies(agents, inactive_threshold):
    """Two more common objects on every agent, last observed before the window and each
    correlated with one of the objects every robot observes now (a noisy copy of it); only
    objects observed within the window are active, inactive ones move back in only beyond
    ``inactive_threshold`` nats."""
    for a in agents:
        state = a.state
        for source, oid in ((1000, 1002), (1001, 1003)):
            columns = state.object(state.object_slots(np.array([source]))).columns.ravel()
            cross = np.array(state.cov[columns])
            slot = state.object_slots(np.array([source]))[0]
            state.add_object(
                oid, state.objects[slot] + 0.1, cross[:, columns] + 0.5 * np.eye(3), cross
            )
            state.object_last_seen[-1] = state.frames.min() - 1
        a.config = a.config.with_(
            {
                "consensus.set": "active",
                "consensus.active_information": np.inf,
                "consensus.inactive_kl_threshold": inactive_threshold,
            }
        )
    return agents


def test_objects_left_out_keep_their_conditional_and_move_back_in_when_they_change(team4):
    agents = _with_inactive_copies(_agents(team4[0], 2), 20.0)
    protocols = [ConsensusProtocol(a, [1 - a.robot], kl_threshold=1e-3) for a in agents]
    network = MemoryNetwork(2)
    ends = [network.endpoint(i) for i in range(2)]
    first = _exchange(protocols, ends, 15)  # nothing on record: every common object
    common = np.intersect1d(agents[0].state.object_ids, agents[1].state.object_ids)
    assert first == [common.size] * 2
    # the averages started run until the pair agrees (settling), then nothing is exchanged
    rounds = [_exchange(protocols, ends, 16 + k) for k in range(30)]
    assert rounds[-1] == [0, 0], rounds
    # which common objects each robot's window still changes
    active = [
        a.state.object_ids[active_objects(a.state, a.state.object_covs(), np.inf)] for a in agents
    ]
    joint = np.intersect1d(common, np.union1d(*active))
    left_out = np.setdiff1d(common, joint)
    assert joint.size > 0 and left_out.size > 0, (joint.size, left_out.size)
    # an update on robot 0 moves its active objects (a later step: nothing is settling)
    state = agents[0].state
    slots = state.object_slots(joint)
    state.objects[slots] += 3.0 * np.sqrt(np.diagonal(state.object_covs()[slots], axis1=1, axis2=2))
    before = [np.array(a.state.cov) for a in agents]
    second = _exchange(protocols, ends, 60)
    # the pair averages the same set, only common objects active on either side
    averaged = protocols[0]._pending[1]
    np.testing.assert_array_equal(averaged, protocols[1]._pending[0])
    assert second == [averaged.size] * 2
    assert averaged.size > 0 and np.isin(averaged, joint).all()
    # Prop. 2 on the averaged set: every other object keeps its conditional given it exactly
    left = np.setdiff1d(common, averaged)
    for a, cov in zip(agents, before, strict=True):
        gain, conditional = _conditional(a.state, cov, averaged, left)
        gain_after, conditional_after = _conditional(a.state, np.array(a.state.cov), averaged, left)
        np.testing.assert_allclose(gain_after, gain, rtol=1e-7, atol=1e-9)
        np.testing.assert_allclose(conditional_after, conditional, rtol=1e-7, atol=1e-12)
    # robot 1 moves one left-out object far (as an update would): it is averaged again
    moved = left_out[:1]
    slot = agents[1].state.object_slots(moved)[0]
    agents[1].state.objects[slot] += 20.0 * np.sqrt(np.diag(agents[1].state.object_covs()[slot]))
    third = _exchange(protocols, ends, 80)
    assert third[0] == third[1]
    assert protocols[0]._pending[1].tolist().count(int(moved[0])) == 1
    assert not np.isin(np.setdiff1d(left_out, moved), protocols[0]._pending[1]).any()


def test_settling_thresholds_test_the_previous_exchange_at_the_paper_threshold():
    thresholds = np.array([1e-3, 0.3, 0.3, -np.inf])
    at = np.array([4, 4, 2, 4])
    np.testing.assert_array_equal(
        settling_thresholds(thresholds, at, 5, 1e-3), [1e-3, 1e-3, 0.3, -np.inf]
    )
    np.testing.assert_array_equal(settling_thresholds(thresholds, at, 7, 1e-3), thresholds)


def _pair_kl(agents, a, b, ids):
    """Symmetrised Kullback–Leibler divergence (nats) between robots ``a`` and ``b``'s
    marginals of each object in ``ids``."""
    out = []
    for oid in ids:
        m, c = [], []
        for r in (a, b):
            state = agents[r].state
            slot = state.object_slots(np.array([oid]))[0]
            m.append(state.objects[slot])
            c.append(state.object_covs()[slot])
        d = m[0] - m[1]
        kl = 0.5 * (
            np.trace(np.linalg.solve(c[1], c[0]) + np.linalg.solve(c[0], c[1])) - 6
        ) + 0.25 * d @ (np.linalg.solve(c[0], d) + np.linalg.solve(c[1], d))
        out.append(kl)
    return np.array(out)


def test_left_out_objects_averaged_on_part_of_the_team_are_averaged_until_it_agrees(team4):
    """On a path 0 – 1 – 2 one average leaves robots 0 and 2 apart (each mixes only robot 1's
    marginal into its own). An average once started runs until the pair agrees to within the
    paper's threshold, so an inactive object — which its own threshold would not bring back,
    and uncorrelated with every other, so no other average moves it — ends in agreement along
    the path instead of keeping that first residual."""
    agents = _with_inactive_copies(_agents(team4[0], 3), 20.0)
    rng = np.random.default_rng(7)
    inactive = np.array([1004, 1005])
    for a in agents:
        for oid in inactive:
            cov = np.eye(3) * rng.uniform(0.5, 2)
            a.state.add_object(oid, rng.normal(size=3), cov, np.zeros((3, a.state.dim)))
            a.state.object_last_seen[-1] = a.state.frames.min() - 1
    path = {0: [1], 1: [0, 2], 2: [1]}
    protocols = [ConsensusProtocol(a, path[a.robot], kl_threshold=1e-3) for a in agents]
    network = MemoryNetwork(3)
    ends = [network.endpoint(i) for i in range(3)]
    start = _pair_kl(agents, 0, 2, inactive)
    _exchange(protocols, ends, 15)
    after_one = _pair_kl(agents, 0, 2, inactive)
    assert (after_one > 0.05).all() and (after_one < start).all(), (start, after_one)
    rounds = [_exchange(protocols, ends, 16 + k) for k in range(60)]
    assert rounds[-1] == [0, 0, 0], rounds
    assert (_pair_kl(agents, 0, 2, inactive) < 0.1 * after_one).all()
