"""Hybrid consensus (``consensus.rule = hybrid``): new information at full weight, never twice.

On a linear model — robots that measure the common objects directly, ``z_i = H_i x + v_i`` —
every marginal is a sum of information pieces, so the properties are exact:

* on a complete graph with every link up, one exchange gives every robot the centralised
  fusion of all robots' new information (the plain average keeps ``1/N`` of it);
* on any graph, over any number of exchanges, no robot's information exceeds the centralised
  one (no piece counted twice: consistency), and it is at least that of the plain average.
"""

from __future__ import annotations

from collections import defaultdict
from types import SimpleNamespace

import numpy as np
import pytest

from teamslam.errors import InputError, InternalError
from teamslam.msckf.consensus import hybrid_marginal, prior_information, shared_prior
from teamslam.msckf.consensus.messages import CommonMarginalMessage, MapIdsMessage
from teamslam.msckf.consensus.protocol import ConsensusProtocol
from teamslam.msckf.filter.state import MsckfState
from teamslam.msckf.settings.values import MsckfConfig

OBJECTS = 4


def _agent(
    robot: int,
    mean: np.ndarray,
    cov: np.ndarray,
    hybrid: bool,
    held: np.ndarray | None = None,
    increments: bool = False,
) -> SimpleNamespace:
    """A robot with one window pose (independent of the map) and the objects ``held`` (all);
    ``increments``: consensus on information increments instead of the hybrid rule."""
    held = np.arange(OBJECTS) if held is None else np.asarray(held)
    coords = (3 * held[:, None] + np.arange(3)).ravel()
    full = np.zeros((6 + coords.size, 6 + coords.size))
    full[:6, :6] = 1e-2 * np.eye(6)
    full[6:, 6:] = cov[np.ix_(coords, coords)]
    ids = (10 + held).astype(np.int64)
    state = MsckfState.from_arrays(np.eye(4), [0], ids, mean[coords].reshape(-1, 3), full)
    rule = "increments" if increments else "hybrid" if hybrid else "average"
    return consensus_agent(robot, state, rule)


def consensus_agent(robot: int, state: MsckfState, rule: str) -> SimpleNamespace:
    """What the consensus protocol reads of a robot: its ``state`` and a configuration with
    ``consensus.rule = rule`` that sends every marginal in float64; the reasons of rejected
    messages are kept in ``rejected``."""
    config = MsckfConfig.from_settings(
        {"consensus.kl_threshold": 0.0, "consensus.float32": False, "consensus.rule": rule}
    )
    rejected = []
    return SimpleNamespace(
        robot=robot,
        state=state,
        config=config,
        counters=defaultdict(int),
        timings=defaultdict(float),
        rejected=rejected,
        reject=lambda what, count=1, reason="": rejected.append(reason),
    )


def _rows(rng, agent, truth) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A direct linear measurement of some of the robot's object coordinates, applied to the
    robot's filter; returns ``(H, R, z)`` over all ``OBJECTS`` objects for the reference."""
    coords = (3 * (agent.state.object_ids - 10)[:, None] + np.arange(3)).ravel()
    rows = int(rng.integers(2, coords.size))
    h = np.zeros((rows, 3 * OBJECTS))
    h[:, coords] = rng.standard_normal((rows, coords.size))
    noise = np.diag(rng.uniform(0.05, 0.5, rows))
    z = h @ truth + rng.multivariate_normal(np.zeros(rows), noise)
    jacobian = np.zeros((rows, agent.state.dim))
    jacobian[:, 6:] = h[:, coords]
    agent.state.update(jacobian, z - h[:, coords] @ agent.state.objects.ravel(), noise)
    return h, noise, z


def _measure(rng, agent, truth) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_rows` as the information and information vector it adds over all ``OBJECTS``
    objects."""
    h, noise, z = _rows(rng, agent, truth)
    return h.T @ np.linalg.solve(noise, h), h.T @ np.linalg.solve(noise, z)


def _exchange(protocols, adjacency, step, lost=frozenset()) -> None:
    """One lock-step consensus round over ``adjacency``; a message ``(round, sender,
    receiver)`` in ``lost`` does not arrive (every other link is up)."""
    n = len(protocols)
    boxes: dict[int, list] = defaultdict(list)
    for i in range(n):
        for m in protocols[i].requests(step, np.flatnonzero(adjacency[i])):
            if (1, m.sender, m.receiver) not in lost:
                boxes[m.receiver].append(m)
    replies: dict[int, list] = defaultdict(list)
    for i in range(n):
        ids = [m for m in boxes[i] if isinstance(m, MapIdsMessage)]
        for m in protocols[i].answer(ids):
            if (2, m.sender, m.receiver) not in lost:
                replies[m.receiver].append(m)
    for i in range(n):
        assert all(isinstance(m, CommonMarginalMessage) for m in replies[i])
        protocols[i].average(replies[i])


def _marginal(agent) -> tuple[np.ndarray, np.ndarray]:
    cov = agent.state.cov[6:, 6:]
    return agent.state.objects.ravel(), cov


def _team(n, rng, hybrid, maps=None, increments=False):
    prior_cov = np.diag(rng.uniform(0.5, 2.0, 3 * OBJECTS))
    prior_mean = rng.standard_normal(3 * OBJECTS)
    maps = maps or [None] * n
    agents = [_agent(i, prior_mean, prior_cov, hybrid, maps[i], increments) for i in range(n)]
    return agents, prior_mean, prior_cov


@pytest.mark.parametrize("n", [2, 4])
def test_hybrid_equals_centralised_fusion_on_a_complete_graph(n):
    rng = np.random.default_rng(n)
    truth = rng.standard_normal(3 * OBJECTS)
    agents, prior_mean, prior_cov = _team(n, rng, hybrid=True)
    plain, _, _ = _team(n, np.random.default_rng(n), hybrid=False)
    protocols = [ConsensusProtocol(a, [j for j in range(n) if j != a.robot]) for a in agents]
    plain_protocols = [ConsensusProtocol(a, [j for j in range(n) if j != a.robot]) for a in plain]
    adjacency = ~np.eye(n, dtype=bool)
    info = np.linalg.inv(prior_cov)
    eta = info @ prior_mean
    for step in (1, 2, 3):  # new measurements, then an exchange, three times
        for a, b in zip(agents, plain, strict=True):
            state = np.random.default_rng([step, a.robot])
            piece, piece_eta = _measure(state, a, truth)
            _measure(np.random.default_rng([step, a.robot]), b, truth)
            info, eta = info + piece, eta + piece_eta
        _exchange(protocols, adjacency, step)
        _exchange(plain_protocols, adjacency, step)
        central_cov = np.linalg.inv(info)
        central_mean = central_cov @ eta
        for a in agents:
            mean, cov = _marginal(a)
            np.testing.assert_allclose(cov, central_cov, rtol=1e-8, atol=1e-12)
            np.testing.assert_allclose(mean, central_mean, rtol=1e-8, atol=1e-10)
            assert a.counters["hybrid_fallbacks"] == 0
        # the plain average is conservative: strictly less information than centralised
        gap = info - np.linalg.inv(_marginal(plain[0])[1])
        assert np.linalg.eigvalsh(gap).max() > 1.0


@pytest.mark.parametrize("partial_maps", [False, True])
def test_hybrid_never_counts_information_twice_on_a_sparse_graph(partial_maps):
    """A path 0–1–2–3–4 plus a chord (Metropolis weights differ per link and robot); with
    partial maps, robots hold different objects, so messages cover different sets."""
    n = 5
    rng = np.random.default_rng(7)
    truth = rng.standard_normal(3 * OBJECTS)
    adjacency = np.zeros((n, n), dtype=bool)
    for i, j in [(0, 1), (1, 2), (2, 3), (3, 4), (1, 3)]:
        adjacency[i, j] = adjacency[j, i] = True
    maps = [[0, 1, 2, 3], [0, 1, 2, 3], [0, 1], [0, 2, 3], [1, 3]] if partial_maps else None
    agents, _, prior_cov = _team(n, rng, True, maps)
    plain, _, _ = _team(n, np.random.default_rng(7), False, maps)
    hybrid_protocols = [ConsensusProtocol(a, np.flatnonzero(adjacency[a.robot])) for a in agents]
    plain_protocols = [ConsensusProtocol(a, np.flatnonzero(adjacency[a.robot])) for a in plain]
    central = np.linalg.inv(prior_cov)
    for step in range(1, 9):
        for a, b in zip(agents, plain, strict=True):
            central = central + _measure(np.random.default_rng([step, a.robot]), a, truth)[0]
            _measure(np.random.default_rng([step, a.robot]), b, truth)
        _exchange(hybrid_protocols, adjacency, step)
        _exchange(plain_protocols, adjacency, step)
        central_cov = np.linalg.inv(central)
        for a, b in zip(agents, plain, strict=True):
            coords = (3 * (a.state.object_ids - 10)[:, None] + np.arange(3)).ravel()
            # the centralised marginal of the objects this robot holds
            central_info = np.linalg.inv(central_cov[np.ix_(coords, coords)])
            hybrid_info = np.linalg.inv(_marginal(a)[1])
            plain_info = np.linalg.inv(_marginal(b)[1])
            scale = np.abs(central_info).max()
            # never more than the centralised information ...
            assert np.linalg.eigvalsh(central_info - hybrid_info).min() > -1e-9 * scale
            if not partial_maps:  # ... and, when all hold everything, never less than plain
                assert np.linalg.eigvalsh(hybrid_info - plain_info).min() > -1e-9 * scale
    gains = [np.trace(np.linalg.inv(_marginal(a)[1])) for a in agents]
    plain_gains = [np.trace(np.linalg.inv(_marginal(b)[1])) for b in plain]
    assert np.mean(np.divide(gains, plain_gains)) > 1.2


def test_hybrid_marginal_scales_the_new_information_and_refuses_a_negative_one():
    rng = np.random.default_rng(3)
    a = rng.standard_normal((6, 9))
    prior = a @ a.T / 9 + 0.1 * np.eye(6)
    b = rng.standard_normal((6, 4))
    info = prior + b @ b.T
    mean = rng.standard_normal(6)
    prior_eta = prior @ rng.standard_normal(6)
    out = hybrid_marginal(mean, info, prior, prior_eta, 3.0)
    assert out is not None
    mean_h, cov_h, info_h = out
    np.testing.assert_allclose(info_h, prior + 3.0 * b @ b.T, atol=1e-12)
    np.testing.assert_allclose(np.linalg.inv(cov_h), info_h, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(
        info_h @ mean_h, prior_eta + 3.0 * (info @ mean - prior_eta), rtol=1e-9, atol=1e-9
    )
    # gain 1 is the plain marginal
    same = hybrid_marginal(mean, info, prior, prior_eta, 1.0)
    np.testing.assert_allclose(same[0], mean, atol=1e-12)
    # information lost since the prior, scaled up, is not a Gaussian: refused
    assert hybrid_marginal(mean, prior, info + 5 * np.eye(6), prior_eta, 4.0) is None
    with pytest.raises(InternalError, match="at least 1"):
        hybrid_marginal(mean, info, prior, prior_eta, 0.5)


def test_prior_information_is_zero_for_objects_initialised_since():
    rng = np.random.default_rng(1)
    agent = _agent(0, rng.standard_normal(3 * OBJECTS), np.diag(rng.uniform(1, 2, 12)), True)
    prior = shared_prior(agent.state)
    ids = np.array([11, 12, 99])  # 99: not in the prior
    info, eta = prior_information(prior, ids)
    held = np.linalg.inv(agent.state.cov[9:15, 9:15])
    np.testing.assert_allclose(info[:6, :6], held, rtol=1e-12)
    np.testing.assert_allclose(eta[:6], held @ agent.state.objects[1:3].ravel(), rtol=1e-12)
    assert not info[6:].any() and not info[:, 6:].any() and not eta[6:].any()


def test_hybrid_settings_are_checked_and_asynchronous_exchanges_stay_plain():
    with pytest.raises(InputError, match="joint marginals"):
        MsckfConfig.from_settings({"consensus.rule": "hybrid", "consensus.per_object": True})
    agent = _agent(0, np.zeros(3 * OBJECTS), np.eye(3 * OBJECTS), True)
    assert ConsensusProtocol(agent, [1]).rule.name == "hybrid"
    assert ConsensusProtocol(agent, [1], max_age=3).rule.name == "average"


def test_each_rule_name_gives_its_strategy_and_an_unknown_one_is_named():
    from teamslam.msckf.consensus.rules import consensus_rule

    rules = {name: consensus_rule(name) for name in ("average", "hybrid", "increments")}
    assert {name: rule.name for name, rule in rules.items()} == {n: n for n in rules}
    assert not rules["average"].keeps_prior
    assert rules["hybrid"].keeps_prior and rules["increments"].keeps_prior
    prior = object()
    assert rules["hybrid"].message_prior(prior) is None  # hybrid messages carry no prior
    assert rules["increments"].message_prior(prior) is prior
    with pytest.raises(InputError, match="average, hybrid, increments, ci, ici"):
        consensus_rule("median")
