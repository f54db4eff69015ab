"""``consensus.iterations``: ``L`` consensus exchanges per step.

On the linear-Gaussian team of :mod:`test_hybrid_consensus` (robots that measure the common
objects directly, so every marginal is a sum of information pieces):

* plain consensus iterated on a connected graph converges to the exact network average of the
  robots' information (eq. 19 with doubly-stochastic Metropolis weights);
* consensus on information increments with ``L`` exchanges still equals the centralised Kalman
  filter on a complete graph and never holds more information than it on sparse graphs, with
  link loss and partial maps (each increment is sent at its gain once, then only mixed);
* exchange ``l`` of step ``t`` travels as ``t·L + l`` (``t`` itself for ``L = 1``);
* a team run with ``L = 2`` exchanges twice as often as with ``L = 1``, and robots that
  disagree on ``L`` are refused by name.
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import pytest

from teamslam.errors import InputError, InternalError
from teamslam.graph import complete
from teamslam.msckf import config_for, run_team
from teamslam.msckf.consensus.messages import CommonMarginalMessage, MapIdsMessage
from teamslam.msckf.consensus.protocol import ConsensusProtocol
from teamslam.msckf.settings.values import MsckfConfig
from teamslam.msckf.team import exchanges_per_frame
from teamslam.sim import lissajous_team
from test_consistent_consensus import (
    _follow_the_centralised_filter,
    _graphs,
    _information,
    _initialise,
    _object_order,
)
from test_hybrid_consensus import OBJECTS, _marginal, _rows, _team


def _iterated(agents, iterations: int) -> None:
    for a in agents:
        a.config = a.config.with_({"consensus.iterations": iterations})


def _protocols(agents, adjacency):
    return [ConsensusProtocol(a, np.flatnonzero(adjacency[a.robot])) for a in agents]


def _exchange(protocols, adjacency, step, iteration, lost=frozenset()) -> None:
    """Exchange ``iteration`` of ``step`` over ``adjacency``; a message ``(iteration, round,
    sender, receiver)`` in ``lost`` does not arrive."""
    n = len(protocols)
    boxes: dict[int, list] = defaultdict(list)
    for i in range(n):
        for m in protocols[i].requests(step, np.flatnonzero(adjacency[i]), iteration):
            assert m.step == protocols[i].exchange(step, iteration)
            if (iteration, 1, m.sender, m.receiver) not in lost:
                boxes[m.receiver].append(m)
    replies: dict[int, list] = defaultdict(list)
    for i in range(n):
        for m in protocols[i].answer([m for m in boxes[i] if isinstance(m, MapIdsMessage)]):
            if (iteration, 2, m.sender, m.receiver) not in lost:
                replies[m.receiver].append(m)
    for i in range(n):
        assert all(isinstance(m, CommonMarginalMessage) for m in replies[i])
        protocols[i].average(replies[i])


def _step(protocols, adjacency, step, lost=frozenset()) -> None:
    for iteration in range(protocols[0].iterations):
        _exchange(protocols, adjacency, step, iteration, lost)


def test_an_exchange_is_numbered_by_step_and_iteration():
    agents, _, _ = _team(1, np.random.default_rng(0), hybrid=False)
    assert ConsensusProtocol(agents[0], [1]).exchange(7) == 7  # L = 1: the step itself
    _iterated(agents, 3)
    protocol = ConsensusProtocol(agents[0], [1])
    assert [protocol.exchange(7, k) for k in range(3)] == [21, 22, 23]
    with pytest.raises(InternalError, match="exchange 3 of a step with 3"):
        protocol.exchange(7, 3)
    assert ConsensusProtocol(agents[0], [1], max_age=2).iterations == 1  # asynchronous
    with pytest.raises(InputError, match=r"consensus\.iterations must be an integer"):
        MsckfConfig.from_settings({"consensus.iterations": 0})


def _metropolis(adjacency: np.ndarray) -> np.ndarray:
    degree = adjacency.sum(axis=1)
    weights = np.where(adjacency, 1.0 / (1 + np.maximum.outer(degree, degree)), 0.0)
    return weights + np.diag(1 - weights.sum(axis=1))


@pytest.mark.parametrize("graph", ["ring", "chord"])
def test_iterated_plain_consensus_is_the_metropolis_power_and_reaches_the_network_average(graph):
    """Every robot measured something different; after ``L`` exchanges in one step robot ``i``
    holds ``Σ_k (W^L)_ik Ω_k`` (``W`` the Metropolis matrix), for information matrices and
    vectors alike — and with many exchanges the exact average over robots."""
    n = 5
    truth = np.random.default_rng(21).standard_normal(3 * OBJECTS)
    adjacency = _graphs(n)[graph]
    for iterations in (1, 4, 200):
        agents, _, _ = _team(n, np.random.default_rng(21), hybrid=False)
        _iterated(agents, iterations)
        for a in agents:
            _rows(np.random.default_rng([1, a.robot]), a, truth)
        infos = np.stack([_information(a) for a in agents])
        etas = np.stack([info @ _marginal(a)[0] for info, a in zip(infos, agents, strict=True)])
        power = np.linalg.matrix_power(_metropolis(adjacency), iterations)
        _step(_protocols(agents, adjacency), adjacency, 1)
        for i, a in enumerate(agents):
            info = _information(a)
            np.testing.assert_allclose(info, np.tensordot(power[i], infos, 1), rtol=1e-8)
            np.testing.assert_allclose(info @ _marginal(a)[0], power[i] @ etas, rtol=1e-8)
            if iterations == 200:
                np.testing.assert_allclose(info, infos.mean(axis=0), rtol=1e-8, atol=1e-8)
            else:  # not there yet
                assert np.abs(info - infos.mean(axis=0)).max() > 1e-6


@pytest.mark.parametrize("iterations", [2, 3])
def test_iterated_increments_equal_the_centralised_kalman_filter_on_a_complete_graph(iterations):
    n = 4
    rng = np.random.default_rng(40 + iterations)
    truth = rng.standard_normal(3 * OBJECTS)
    agents, mean, cov = _team(n, rng, hybrid=False, increments=True)
    _iterated(agents, iterations)
    adjacency = complete(n).adjacency
    protocols = _protocols(agents, adjacency)
    _follow_the_centralised_filter(
        agents, mean, cov, truth, 3, lambda step: _step(protocols, adjacency, step)
    )


@pytest.mark.parametrize("graph", ["ring", "chord", "random"])
@pytest.mark.parametrize("loss", [0.0, 0.3])
def test_iterated_increments_never_hold_more_information_than_the_centralised_filter(graph, loss):
    """Three exchanges per step on a sparse graph, messages of any exchange and round lost at
    random, partial maps and objects initialised late: every robot's information about the
    objects it holds stays below the centralised one, and the robots agree more closely than
    after one exchange per step (more information is not promised: later exchanges average)."""
    n = 5
    maps = [[0, 1, 2, 3], [0, 1, 2, 3], [0, 1], [0, 2, 3], [1, 3]]
    late = {(4, 2): 12, (4, 4): 10}
    adjacency = _graphs(n)[graph]
    edges = list(zip(*np.nonzero(adjacency), strict=True))
    links = [(k, r, i, j) for k in range(3) for r in (1, 2) for i, j in edges]
    spread = {}
    for iterations in (1, 3):
        rng = np.random.default_rng(17)
        truth = rng.standard_normal(3 * OBJECTS)
        agents, _, prior_cov = _team(n, rng, False, maps, increments=True)
        _iterated(agents, iterations)
        protocols = _protocols(agents, adjacency)
        drops = np.random.default_rng(99)
        central = np.linalg.inv(prior_cov)
        for step in range(1, 9):
            for a in agents:
                if (step, a.robot) in late:
                    draw = np.random.default_rng(step)
                    central = central + _initialise(a, late[step, a.robot], truth, draw)[0]
                h, noise, _ = _rows(np.random.default_rng([step, a.robot]), a, truth)
                central = central + h.T @ np.linalg.solve(noise, h)
            lost = frozenset(link for link in links if drops.random() < loss)
            _step(protocols, adjacency, step, lost)
            central_cov = np.linalg.inv(central)
            for a in agents:
                coords = _object_order(a)
                central_info = np.linalg.inv(central_cov[np.ix_(coords, coords)])
                gap = np.linalg.eigvalsh(central_info - _information(a)).min()
                assert gap > -1e-9 * np.abs(central_info).max(), (iterations, step, a.robot, gap)
        # object 10, held by every robot from step 4 on: how far apart the robots' means are
        means = np.stack([a.state.objects[a.state.object_slots(np.array([10]))[0]] for a in agents])
        spread[iterations] = np.linalg.norm(means - means.mean(axis=0), axis=1).max()
    # more exchanges bring the robots closer together
    assert spread[3] < spread[1]


@pytest.fixture(scope="module")
def tiny_team():
    return lissajous_team(robots=3, steps=30, seed=1, landmarks=600)


def test_a_team_with_two_exchanges_per_frame_exchanges_twice(tiny_team):
    """Every frame after the first runs two exchanges: twice the map-ids messages (one per
    neighbour and exchange, all links up) and more objects averaged."""
    config = config_for(tiny_team, {"filter.window": 6})
    runs = {
        iterations: run_team(
            tiny_team, config.with_({"consensus.iterations": iterations}), progress=False
        )
        for iterations in (1, 2)
    }
    frames = tiny_team.robots[0].T_world_body.shape[0]
    for iterations, run in runs.items():
        ids_messages = iterations * 2 * (frames - 1)  # two neighbours, every frame but the first
        marginals = [c["messages"] - ids_messages for c in run.counters]
        assert all(0 <= m <= ids_messages for m in marginals) and sum(marginals) > 0
        assert all(c.get("links_lost", 0) == 0 for c in run.counters)
        assert all(np.isfinite(p).all() for p in run.poses)
    averaged = {L: sum(c["objects_averaged"] for c in run.counters) for L, run in runs.items()}
    assert averaged[2] > averaged[1] > 0


def test_robots_that_disagree_on_the_exchanges_per_frame_are_refused(tiny_team):
    config = config_for(tiny_team, {"filter.window": 6})
    configs = [config, config, config.with_({"consensus.iterations": 2})]
    with pytest.raises(InputError, match=r"same consensus\.iterations, not \[1, 2\]"):
        run_team(tiny_team, configs, progress=False)
    assert exchanges_per_frame([]) == 1
