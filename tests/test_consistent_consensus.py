"""Consensus on information increments (``consensus.rule = increments``): each increment counted
once.

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
  or not its message arrived);
* an object that enters a second robot's map keeps every prior whole: the new holder takes the
  old holders' prior (the message carries it beside the marginal), the old holder keeps its own;
* the prior travels on the wire (format version 6) exactly, and version 5 is refused by name.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from teamslam.dvi.kalman import kalman_update
from teamslam.errors import InputError
from teamslam.graph import complete, metropolis_weight, random_geometric, ring
from teamslam.msckf.consensus.protocol import ConsensusProtocol
from teamslam.msckf.settings.values import MsckfConfig
from test_hybrid_consensus import OBJECTS, _exchange, _marginal, _measure, _rows, _team


def _protocols(agents, adjacency):
    return [ConsensusProtocol(a, np.flatnonzero(adjacency[a.robot])) for a in agents]


def _information(agent) -> np.ndarray:
    return np.linalg.inv(_marginal(agent)[1])


def _follow_the_centralised_filter(agents, mean, cov, truth, steps, exchange) -> None:
    """Each step every robot updates on its own rows (and the centralised filter on all of
    them), ``exchange(step)`` runs the team's consensus; every robot must then hold the
    centralised estimate."""
    for step in range(1, steps + 1):
        for a in agents:
            h, noise, z = _rows(np.random.default_rng([step, a.robot]), a, truth)
            mean, cov = kalman_update(mean, cov, h, z, noise)
        exchange(step)
        for a in agents:
            own_mean, own_cov = _marginal(a)
            np.testing.assert_allclose(own_cov, cov, rtol=1e-8, atol=1e-12)
            np.testing.assert_allclose(own_mean, mean, rtol=1e-8, atol=1e-10)
            assert a.counters["hybrid_fallbacks"] == 0


@pytest.mark.parametrize("n", [2, 3, 5])
def test_increments_equal_the_centralised_kalman_filter_on_a_complete_graph(n):
    rng = np.random.default_rng(10 + n)
    truth = rng.standard_normal(3 * OBJECTS)
    agents, mean, cov = _team(n, rng, hybrid=False, increments=True)
    adjacency = complete(n).adjacency
    protocols = _protocols(agents, adjacency)
    _follow_the_centralised_filter(
        agents, mean, cov, truth, 4, lambda step: _exchange(protocols, adjacency, step)
    )


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


def _initialise(agent, object_id: int, truth: np.ndarray, rng) -> tuple[np.ndarray, np.ndarray]:
    """The robot initialises object ``object_id`` from a measurement of its own (independent of
    its state); returns the measurement's information and information vector over all
    ``OBJECTS`` objects, for the centralised reference."""
    cov = np.diag(rng.uniform(0.1, 0.4, 3))
    coords = slice(3 * (object_id - 10), 3 * (object_id - 10) + 3)
    z = truth[coords] + rng.multivariate_normal(np.zeros(3), cov)
    agent.state.add_object(object_id, z, cov, np.zeros((3, agent.state.dim)))
    info = np.zeros((3 * OBJECTS, 3 * OBJECTS))
    eta = np.zeros(3 * OBJECTS)
    info[coords, coords] = np.linalg.inv(cov)
    eta[coords] = info[coords, coords] @ z
    return info, eta


def _object_order(agent) -> np.ndarray:
    """The coordinates of the robot's objects in the reference's order (ids 10, 11, …)."""
    return (3 * (agent.state.object_ids - 10)[:, None] + np.arange(3)).ravel()


@pytest.mark.parametrize("n", [2, 3])
def test_an_object_entering_a_second_map_keeps_every_prior_whole(n):
    """Robot 0 holds every object, the others all but the last; after a first exchange the
    others initialise the last object from their own measurement while robot 0 measures. On a
    complete graph every robot then equals the centralised Kalman filter: the new holders take
    robot 0's prior of the object whole and robot 0 keeps its own (a single matrix per message
    cannot tell a prior from new information and leaves ``A_ij`` of the prior to each)."""
    rng = np.random.default_rng(30 + n)
    truth = rng.standard_normal(3 * OBJECTS)
    maps = [list(range(OBJECTS))] + [list(range(OBJECTS - 1))] * (n - 1)
    agents, prior_mean, prior_cov = _team(n, rng, False, maps, increments=True)
    adjacency = complete(n).adjacency
    protocols = _protocols(agents, adjacency)
    info = np.linalg.inv(prior_cov)
    eta = info @ prior_mean
    late = 10 + OBJECTS - 1
    for step in (1, 2, 3):
        for a in agents:
            draw = np.random.default_rng([step, a.robot])
            if step == 2 and a.robot > 0:
                piece, piece_eta = _initialise(a, late, truth, draw)
            elif step == 1 and a.robot == 0:
                continue  # the others' first pieces lie on the objects all hold
            else:
                piece, piece_eta = _measure(draw, a, truth)
            info, eta = info + piece, eta + piece_eta
        _exchange(protocols, adjacency, step)
        cov = np.linalg.inv(info)
        mean = cov @ eta
        for a in agents:
            order = _object_order(a)
            own_mean, own_cov = _marginal(a)
            np.testing.assert_allclose(own_cov, cov[np.ix_(order, order)], rtol=1e-8, atol=1e-12)
            np.testing.assert_allclose(own_mean, mean[order], rtol=1e-8, atol=1e-10)
            assert a.counters["hybrid_fallbacks"] == 0


@pytest.mark.parametrize("graph", ["complete", "ring", "chord", "random"])
@pytest.mark.parametrize("loss", [0.0, 0.3])
@pytest.mark.parametrize("partial_maps", [False, True])
def test_increments_never_hold_more_information_than_the_centralised_filter(
    graph, loss, partial_maps
):
    """Any graph, messages of either round lost at random, robots holding different objects
    (with partial maps robots 2 and 4 also initialise an object each at step 4, one the others
    hold and one only robot 2 had): every robot's information about the objects it holds stays
    below the centralised one."""
    n = 5
    rng = np.random.default_rng(17)
    truth = rng.standard_normal(3 * OBJECTS)
    maps = [[0, 1, 2, 3], [0, 1, 2, 3], [0, 1], [0, 2, 3], [1, 3]] if partial_maps else None
    late = {(4, 2): 12, (4, 4): 10} if partial_maps else {}
    agents, _, prior_cov = _team(n, rng, False, maps, increments=True)
    plain, _, _ = _team(n, np.random.default_rng(17), False, maps)
    adjacency = _graphs(n)[graph]
    protocols, plain_protocols = _protocols(agents, adjacency), _protocols(plain, adjacency)
    links = [(r, i, j) for r in (1, 2) for i, j in zip(*np.nonzero(adjacency), strict=True)]
    drops = np.random.default_rng(99)
    central = np.linalg.inv(prior_cov)
    for step in range(1, 11):
        for a, b in zip(agents, plain, strict=True):
            if (step, a.robot) in late:
                piece, _ = _initialise(a, late[step, a.robot], truth, np.random.default_rng(step))
                _initialise(b, late[step, a.robot], truth, np.random.default_rng(step))
                central = central + piece
            h, noise, _ = _rows(np.random.default_rng([step, a.robot]), a, truth)
            _rows(np.random.default_rng([step, a.robot]), b, truth)
            central = central + h.T @ np.linalg.solve(noise, h)
        lost = frozenset(link for link in links if drops.random() < loss)
        _exchange(protocols, adjacency, step, lost)
        _exchange(plain_protocols, adjacency, step, lost)
        central_cov = np.linalg.inv(central)
        for a in agents:
            coords = _object_order(a)
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
    with pytest.raises(InputError, match=r"consensus\.rule increments needs joint marginals"):
        MsckfConfig.from_settings({"consensus.rule": "increments", "consensus.per_object": True})
    agents, _, _ = _team(1, np.random.default_rng(0), hybrid=False, increments=True)
    protocol = ConsensusProtocol(agents[0], [1])
    assert protocol.rule.name == "increments"
    asynchronous = ConsensusProtocol(agents[0], [1], max_age=2)
    assert asynchronous.rule.name == "average"


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


def test_the_prior_travels_on_the_wire_and_version_5_is_refused():
    from teamslam.msckf.consensus.messages import CommonMarginalMessage
    from teamslam.runtime.wire import WireError, decode, encode, team_id

    team = team_id("increments")
    rng = np.random.default_rng(3)
    root = rng.standard_normal((12, 12))
    info = root @ root.T + 12 * np.eye(12)
    held = np.array([True, False, True, True])
    message = CommonMarginalMessage(
        1,
        2,
        7,
        np.array([3, 5, 8, 13]),
        rng.standard_normal(12),
        None,
        degree=3,
        info=info,
        prior_held=held,
        prior_mean=rng.standard_normal(9),
        prior_info=info[:9, :9] / 2,
    )
    data = encode(message, team)
    assert len(data) == message.nbytes()
    back = decode(data, team, 4)
    np.testing.assert_array_equal(back.prior_held, held)
    np.testing.assert_array_equal(back.prior_mean, message.prior_mean)
    np.testing.assert_array_equal(back.prior_info, message.prior_info)
    np.testing.assert_array_equal(back.info, info)
    single = decode(encode(replace_single(message), team), team, 4)
    assert single.single_precision and single.has_prior
    with pytest.raises(WireError, match="the prior's flags say"):
        decode(data[:-4], team, 4)
    old = bytearray(data)
    old[4] = 5
    with pytest.raises(WireError, match="format version 5 is no longer read"):
        decode(bytes(old), team, 4)


def replace_single(message):
    """The message with every number rounded to single precision."""
    from dataclasses import replace

    def single(x):
        return np.asarray(x).astype(np.float32).astype(float)

    return replace(
        message,
        mean=single(message.mean),
        info=single(message.info),
        prior_mean=single(message.prior_mean),
        prior_info=single(message.prior_info),
    )


@pytest.mark.parametrize("n", [2, 3])
def test_objects_no_prior_holds_are_summed_on_a_complete_graph(n):
    """Robots that start without objects all initialise the same objects from their own
    measurements: no prior holds any of them, so one exchange on a complete graph gives every
    robot the sum of all robots' information (the centralised filter without a prior), with
    no fallback to the plain average."""
    rng = np.random.default_rng(50 + n)
    truth = rng.standard_normal(3 * OBJECTS)
    agents, _, _ = _team(n, rng, False, [np.zeros(0, dtype=int)] * n, increments=True)
    adjacency = complete(n).adjacency
    protocols = _protocols(agents, adjacency)
    info, eta = np.zeros((3 * OBJECTS, 3 * OBJECTS)), np.zeros(3 * OBJECTS)
    for a in agents:
        for k in range(OBJECTS):
            piece, piece_eta = _initialise(a, 10 + k, truth, np.random.default_rng([a.robot, k]))
            info, eta = info + piece, eta + piece_eta
    _exchange(protocols, adjacency, 1)
    cov = np.linalg.inv(info)
    for a in agents:
        order = _object_order(a)
        own_mean, own_cov = _marginal(a)
        np.testing.assert_allclose(own_cov, cov[np.ix_(order, order)], rtol=1e-8, atol=1e-12)
        np.testing.assert_allclose(own_mean, (cov @ eta)[order], rtol=1e-8, atol=1e-10)
        assert a.counters["hybrid_fallbacks"] == 0
