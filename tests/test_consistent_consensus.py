"""Consensus on information increments (``consensus_increments``): each increment counted once.

A linear-Gaussian team — robots that measure the common objects directly, ``z_i = H_i x + v_i`` —
makes every marginal a sum of information pieces, so the properties are exact:

* the gain condition: a neighbour's new information enters with the weight ``A_ij (1 + d_j) ≤ 1``,
  one where the sender's degree is at least the receiver's, and a robot's own new information
  with weight one;
* on a complete graph with every link up, every robot's marginal equals the centralised Kalman
  filter's (:func:`teamslam.dvi.kalman.kalman_update` over all robots' measurements);
* on any graph, with link loss and partial maps, no robot ever holds more information than the
  centralised filter;
* a lost message never makes an increment count twice (the sender's prior is renewed whether
  or not its message arrived).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from teamslam.dvi.kalman import kalman_update
from teamslam.errors import InputError
from teamslam.graph import complete, metropolis_weight, random_geometric, ring
from teamslam.msckf.config import MsckfConfig
from teamslam.msckf.protocol import ConsensusProtocol
from test_hybrid_consensus import OBJECTS, _exchange, _marginal, _rows, _team


def _protocols(agents, adjacency):
    return [ConsensusProtocol(a, np.flatnonzero(adjacency[a.robot])) for a in agents]


def _information(agent) -> np.ndarray:
    return np.linalg.inv(_marginal(agent)[1])


@pytest.mark.parametrize("n", [2, 3, 5])
def test_increments_equal_the_centralised_kalman_filter_on_a_complete_graph(n):
    rng = np.random.default_rng(10 + n)
    truth = rng.standard_normal(3 * OBJECTS)
    agents, mean, cov = _team(n, rng, hybrid=False, increments=True)
    adjacency = complete(n).adjacency
    protocols = _protocols(agents, adjacency)
    for step in range(1, 5):
        for a in agents:
            h, noise, z = _rows(np.random.default_rng([step, a.robot]), a, truth)
            mean, cov = kalman_update(mean, cov, h, z, noise)
        _exchange(protocols, adjacency, step)
        for a in agents:
            own_mean, own_cov = _marginal(a)
            np.testing.assert_allclose(own_cov, cov, rtol=1e-8, atol=1e-12)
            np.testing.assert_allclose(own_mean, mean, rtol=1e-8, atol=1e-10)
            assert a.counters["hybrid_fallbacks"] == 0


def _star(n: int) -> np.ndarray:
    adjacency = np.zeros((n, n), dtype=bool)
    adjacency[0, 1:] = adjacency[1:, 0] = True
    return adjacency


@pytest.mark.parametrize("measuring", [0, 2])
def test_a_neighbours_increment_enters_with_weight_a_ij_times_one_plus_its_degree(measuring):
    """The scaling condition ``A_ij (1 + d_j) ≤ 1`` on a star (hub degree 4, leaves 1): from a
    common prior, only robot ``measuring`` gathers new information ``Δ``; after one exchange
    robot ``i`` holds ``P + c_i Δ`` with ``c_i = A_ij (1 + d_j)`` for a neighbour, ``1`` for
    the robot itself and ``0`` beyond one hop."""
    n = 5
    rng = np.random.default_rng(4)
    truth = rng.standard_normal(3 * OBJECTS)
    agents, _, prior_cov = _team(n, rng, hybrid=False, increments=True)
    adjacency = _star(n)
    protocols = _protocols(agents, adjacency)
    h, noise, _ = _rows(np.random.default_rng(5), agents[measuring], truth)
    delta = h.T @ np.linalg.solve(noise, h)
    _exchange(protocols, adjacency, 1)
    degree = adjacency.sum(axis=1)
    prior = np.linalg.inv(prior_cov)
    for a in agents:
        i = a.robot
        if i == measuring:
            weight = 1.0
        elif adjacency[i, measuring]:
            weight = metropolis_weight(degree[i], degree[measuring]) * (1 + degree[measuring])
        else:
            weight = 0.0
        assert weight <= 1.0
        np.testing.assert_allclose(_information(a), prior + weight * delta, rtol=1e-8, atol=1e-9)
    # the hub's increment reaches every leaf once; a leaf's reaches the hub at 2/5
    hub = _information(agents[0]) - prior
    assert np.allclose(hub, delta if measuring == 0 else 0.4 * delta, atol=1e-9)


def _graphs(n: int) -> dict[str, np.ndarray]:
    chord = np.zeros((n, n), dtype=bool)
    for i, j in [(0, 1), (1, 2), (2, 3), (3, 4), (1, 3)]:
        chord[i, j] = chord[j, i] = True
    return {
        "complete": complete(n).adjacency,
        "ring": ring(n).adjacency,
        "chord": chord,
        "random": random_geometric(n, seed=3).adjacency,
    }


@pytest.mark.parametrize("graph", ["complete", "ring", "chord", "random"])
@pytest.mark.parametrize("loss", [0.0, 0.3])
@pytest.mark.parametrize("partial_maps", [False, True])
def test_increments_never_hold_more_information_than_the_centralised_filter(
    graph, loss, partial_maps
):
    """Any graph, messages of either round lost at random, robots holding different objects:
    every robot's information about the objects it holds stays below the centralised one."""
    n = 5
    rng = np.random.default_rng(17)
    truth = rng.standard_normal(3 * OBJECTS)
    maps = [[0, 1, 2, 3], [0, 1, 2, 3], [0, 1], [0, 2, 3], [1, 3]] if partial_maps else None
    agents, _, prior_cov = _team(n, rng, False, maps, increments=True)
    plain, _, _ = _team(n, np.random.default_rng(17), False, maps)
    adjacency = _graphs(n)[graph]
    protocols, plain_protocols = _protocols(agents, adjacency), _protocols(plain, adjacency)
    links = [(r, i, j) for r in (1, 2) for i, j in zip(*np.nonzero(adjacency), strict=True)]
    drops = np.random.default_rng(99)
    central = np.linalg.inv(prior_cov)
    for step in range(1, 11):
        for a, b in zip(agents, plain, strict=True):
            h, noise, _ = _rows(np.random.default_rng([step, a.robot]), a, truth)
            _rows(np.random.default_rng([step, a.robot]), b, truth)
            central = central + h.T @ np.linalg.solve(noise, h)
        lost = frozenset(link for link in links if drops.random() < loss)
        _exchange(protocols, adjacency, step, lost)
        _exchange(plain_protocols, adjacency, step, lost)
        central_cov = np.linalg.inv(central)
        for a in agents:
            coords = (3 * (a.state.object_ids - 10)[:, None] + np.arange(3)).ravel()
            central_info = np.linalg.inv(central_cov[np.ix_(coords, coords)])
            gap = np.linalg.eigvalsh(central_info - _information(a)).min()
            assert gap > -1e-9 * np.abs(central_info).max(), (step, a.robot, gap)
    # and it keeps more than the plain average
    kept = np.mean(
        [
            np.trace(_marginal(b)[1]) / np.trace(_marginal(a)[1])
            for a, b in zip(agents, plain, strict=True)
        ]
    )
    assert kept > 1.2


@pytest.mark.parametrize("lost_round", [1, 2])
def test_a_lost_message_never_counts_an_increment_twice(lost_round):
    """Two robots; at step 1 both gather new information ``Δ_0``, ``Δ_1`` and robot 0's message
    to robot 1 is lost; at step 2 nobody measures and every message arrives. Robot 0 renewed
    its prior although its message was lost, so ``Δ_0`` is not sent again at full weight: at
    step 2 both hold ``P + Δ_1 + Δ_0 / 2`` (re-sending it would give robot 1 ``Δ_0`` whole and
    ``Δ_1`` one and a half times)."""
    rng = np.random.default_rng(8)
    truth = rng.standard_normal(3 * OBJECTS)
    agents, _, prior_cov = _team(2, rng, hybrid=False, increments=True)
    adjacency = complete(2).adjacency
    protocols = _protocols(agents, adjacency)
    deltas = []
    for a in agents:
        h, noise, _ = _rows(np.random.default_rng([1, a.robot]), a, truth)
        deltas.append(h.T @ np.linalg.solve(noise, h))
    prior = np.linalg.inv(prior_cov)
    _exchange(protocols, adjacency, 1, frozenset({(lost_round, 0, 1)}))
    if lost_round == 2:  # robot 1 heard robot 0 but got no marginal: it keeps its own
        np.testing.assert_allclose(_information(agents[1]), prior + deltas[1], rtol=1e-9)
        np.testing.assert_allclose(
            _information(agents[0]), prior + deltas[0] + deltas[1], rtol=1e-9
        )
    _exchange(protocols, adjacency, 2)
    central = prior + deltas[0] + deltas[1]
    for a in agents:
        info = _information(a)
        assert np.linalg.eigvalsh(central - info).min() > -1e-9 * np.abs(central).max()
        if lost_round == 2:
            expected = prior + deltas[1] + 0.5 * deltas[0]
            np.testing.assert_allclose(info, expected, rtol=1e-8, atol=1e-9)


def test_increment_settings_are_checked_and_asynchronous_exchanges_stay_plain():
    with pytest.raises(InputError, match="consensus_increments needs joint marginals"):
        MsckfConfig(consensus_increments=True, consensus_per_object=True)
    agents, _, _ = _team(1, np.random.default_rng(0), hybrid=False, increments=True)
    protocol = ConsensusProtocol(agents[0], [1])
    assert protocol.increments and protocol.hybrid
    asynchronous = ConsensusProtocol(agents[0], [1], max_age=2)
    assert not asynchronous.increments and not asynchronous.hybrid


def test_montecarlo_runs_the_increments_mode_on_a_chosen_graph_with_link_loss(tmp_path, capsys):
    from teamslam.cli import main
    from teamslam.eval.team_montecarlo import MonteCarloSpec

    def study(*flags: str) -> dict:
        argv = ["montecarlo", "--robots", "3", "--steps", "40", "--runs", "2", "--filters"]
        argv += ["fej", "--modes", "consensus,increments", "--workers", "1"]
        assert main([*argv, *flags, "--json", "--out", str(tmp_path)]) == 0
        return json.loads(capsys.readouterr().out)

    lossy = study("--graph", "ring", "--loss", "0.5")
    assert (lossy["graph"], lossy["loss"]) == ("ring", 0.5)
    results = lossy["results"]["fej"]
    paired = lossy["paired_rmse"]["increments-consensus"]["fej"]
    diff = np.subtract(
        results["increments"]["position_rmse_per_run_m"],
        results["consensus"]["position_rmse_per_run_m"],
    )
    assert paired["mean_difference_m"] == pytest.approx(diff.mean(), abs=1e-15)
    # a ring of three is a complete graph: only the link loss tells the two studies apart
    whole = study("--graph", "complete")["results"]["fej"]
    for mode in ("consensus", "increments"):
        lost = results[mode]["position_rmse_per_run_m"]
        assert not np.allclose(whole[mode]["position_rmse_per_run_m"], lost, rtol=1e-9, atol=0)
    with pytest.raises(InputError, match="unknown graph"):
        MonteCarloSpec(graph="star")
    with pytest.raises(InputError, match="link loss"):
        MonteCarloSpec(loss=1.0)
