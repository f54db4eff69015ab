"""The consensus protocol exists once: both drivers schedule the same object and agree.

The in-process runner (:func:`teamslam.msckf.team.run_team`) and the robot-process driver
(:func:`teamslam.runtime.agent_process.run_agent`, here on an in-memory network in threads)
give the same estimates bit for bit, also when links fail; and the protocol's weights are the
doubly-stochastic Metropolis–Hastings weights of the links that worked.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest

from teamslam.datasets import save_dataset
from teamslam.graph import EdgeLoss, complete, metropolis_weights, ring
from teamslam.msckf import config_for, run_team
from teamslam.msckf.agent import MsckfAgent
from teamslam.msckf.messages import CommonMarginalMessage, MapIdsMessage
from teamslam.msckf.protocol import ConsensusProtocol
from teamslam.msckf.transport import MemoryNetwork
from teamslam.runtime.agent_process import load_robot_result, run_agent
from teamslam.runtime.team_file import load_team_file, write_team_file
from teamslam.sim import lissajous_team


@pytest.fixture(scope="module")
def team4(tmp_path_factory):
    directory = tmp_path_factory.mktemp("team4") / "data"
    dataset = lissajous_team(robots=4, steps=30, seed=2, landmarks=600)
    save_dataset(dataset, directory)
    return dataset, directory


def _threads_over_memory(team_path, out, links, n):
    """Every robot's process driver in a thread of this process, over an in-memory network."""
    team = load_team_file(team_path)
    network = MemoryNetwork(n, links=links)
    errors = []

    def one(robot):
        try:
            run_agent(team, robot, out, lost_after=10**6, transport=network.endpoint(robot))
        except BaseException as exc:  # surfaced below
            errors.append(exc)

    threads = [threading.Thread(target=one, args=(r,)) for r in range(n)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=600)
    assert not errors, errors
    assert not any(t.is_alive() for t in threads)


@pytest.mark.parametrize(("graph", "loss"), [("complete", 0.0), ("complete", 0.4), ("ring", 0.3)])
def test_process_driver_equals_in_process_runner_under_link_loss(team4, tmp_path, graph, loss):
    dataset, directory = team4
    n = dataset.n_robots
    g = complete(n) if graph == "complete" else ring(n)
    draws = EdgeLoss(g, loss, seed=5)
    schedule = [draws.step()[0] for _ in range(dataset.robots[0].frames)]
    if loss > 0:
        assert any(not np.array_equal(a, g.adjacency) for a in schedule[1:])
    config = config_for(dataset, window=8)
    reference = run_team(dataset, config, graph=g, loss=loss, seed=5, progress=False)
    team_path = write_team_file(
        tmp_path / "team.yaml",
        "memory",
        directory,
        g.adjacency,
        timeout_s=60.0,
        filter={"window": 8},
    )
    _threads_over_memory(team_path, tmp_path / "out", lambda t: schedule[t], n)
    for r in range(n):
        arrays, summary = load_robot_result(tmp_path / "out", r)
        np.testing.assert_array_equal(arrays["poses"], reference.poses[r])
        np.testing.assert_array_equal(arrays["objects"], reference.objects[r])
        assert summary["counters"]["objects_averaged"] == reference.counters[r]["objects_averaged"]
        assert summary["counters"].get("rejected_messages", 0) == 0
    lost = sum(
        int((~a[np.triu_indices(n, 1)] & g.adjacency[np.triu_indices(n, 1)]).sum())
        for a in schedule[1:]
    )
    links_lost = sum(
        load_robot_result(tmp_path / "out", r)[1]["counters"].get("links_lost", 0) for r in range(n)
    )
    assert links_lost == 2 * lost


def _agents(dataset, n):
    """Agents after a few frames, each also holding objects 1000 and 1001 (shared by all)."""
    config = config_for(dataset, window=8)
    agents = [MsckfAgent(i, dataset.calibration, dataset.robots[i], config) for i in range(n)]
    rng = np.random.default_rng(0)
    for t in range(15):
        for a in agents:
            a.step(t)
    for a in agents:
        for oid in (1000, 1001):
            a.state.add_object(
                oid, rng.normal(size=3), np.eye(3) * rng.uniform(0.5, 2), np.zeros((3, a.state.dim))
            )
    return agents


def test_protocol_weights_are_metropolis_of_the_links_heard(team4):
    dataset, _ = team4
    n = dataset.n_robots
    agents = _agents(dataset, n)
    adjacency = complete(n).adjacency.copy()
    adjacency[0, 2] = adjacency[2, 0] = False  # this step's loss
    protocols = [
        ConsensusProtocol(a, np.flatnonzero(complete(n).adjacency[i])) for i, a in enumerate(agents)
    ]
    network = MemoryNetwork(n, links=lambda t: adjacency)
    ends = [network.endpoint(i) for i in range(n)]
    for i in range(n):
        for m in protocols[i].requests(15):
            ends[i].send(m)
    replies = {}
    for i in range(n):
        heard = ends[i].collect(15, MapIdsMessage, set(range(n)) - {i}, 0.0)
        replies[i] = protocols[i].answer(heard)
        for m in replies[i]:
            ends[i].send(m)
    want = metropolis_weights(adjacency)
    for i in range(n):
        got = ends[i].collect(15, CommonMarginalMessage, set(range(n)) - {i}, 0.0)
        degrees = {m.sender: m.degree for m in got}
        assert set(degrees) == set(np.flatnonzero(adjacency[i]))  # every link shares objects
        self_weight, weights = protocols[i].weights(degrees)
        assert self_weight == pytest.approx(want[i, i], abs=1e-15)
        for j, w in weights.items():
            assert w == pytest.approx(want[i, j], abs=1e-15)
        assert set(weights) == set(np.flatnonzero(adjacency[i]))


def test_protocol_rejects_what_is_not_for_it_and_leaves_the_state_alone(team4):
    dataset, _ = team4
    agents = _agents(dataset, 3)
    protocol = ConsensusProtocol(agents[0], [1])
    protocol.requests(15)
    state = agents[0].state
    before = (state.cov.copy(), state.objects.copy(), state.poses.copy())
    ids = state.object_ids[:2]
    k = ids.size
    assert k > 0
    good = dict(ids=ids, mean=np.zeros(3 * k), cov=np.eye(3 * k), degree=1)
    answered = protocol.answer(
        [
            MapIdsMessage(2, 0, 15, ids),  # robot 2 is not a neighbour of robot 0
            MapIdsMessage(1, 0, 14, ids),  # an old step
            MapIdsMessage(1, 2, 15, ids),  # addressed to another robot
        ]
    )
    assert answered == [] and protocol.heard == set()
    averaged = protocol.average(
        [
            CommonMarginalMessage(1, 0, 15, **good),  # neighbour 1 was not heard in round 1
            CommonMarginalMessage(2, 0, 15, **good),  # not a neighbour
        ]
    )
    assert averaged == 0
    assert agents[0].counters["rejected_messages"] == 5
    np.testing.assert_array_equal(state.cov, before[0])
    np.testing.assert_array_equal(state.objects, before[1])
    np.testing.assert_array_equal(state.poses, before[2])
