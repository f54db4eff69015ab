"""The consensus protocol exists once: both drivers schedule the same object and agree.

The in-process runner (:func:`teamslam.msckf.team.run_team`) and the robot-process driver
(:func:`teamslam.runtime.agent_process.run_agent`, here on an in-memory network in threads)
give the same estimates bit for bit, also when links fail; and the protocol's weights are the
doubly-stochastic Metropolis–Hastings weights of the links that worked.
"""

from __future__ import annotations

import dataclasses
import threading

import numpy as np
import pytest

from teamslam.datasets import save_dataset
from teamslam.graph import EdgeLoss, complete, metropolis_weights, ring
from teamslam.msckf import config_for, run_team
from teamslam.msckf.agent import MsckfAgent
from teamslam.msckf.consensus.messages import CommonMarginalMessage, MapIdsMessage
from teamslam.msckf.consensus.protocol import ConsensusProtocol
from teamslam.msckf.consensus.transport import LyingNetwork, MemoryNetwork
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


@pytest.mark.parametrize(
    ("graph", "loss", "hybrid"),
    [("complete", 0.0, False), ("complete", 0.4, False), ("ring", 0.3, False), ("ring", 0.3, True)],
)
def test_process_driver_equals_in_process_runner_under_link_loss(
    team4, tmp_path, graph, loss, hybrid
):
    dataset, directory = team4
    n = dataset.n_robots
    g = complete(n) if graph == "complete" else ring(n)
    draws = EdgeLoss(g, loss, seed=5)
    schedule = [draws.step()[0] for _ in range(dataset.robots[0].frames)]
    if loss > 0:
        assert any(not np.array_equal(a, g.adjacency) for a in schedule[1:])
    config = config_for(
        dataset, {"filter.window": 8, "consensus.rule": "hybrid" if hybrid else "average"}
    )
    reference = run_team(dataset, config, graph=g, loss=loss, seed=5, progress=False)
    team_path = write_team_file(
        tmp_path / "team.yaml",
        "memory",
        directory,
        g.adjacency,
        timeout_s=60.0,
        settings={"filter.window": 8, "consensus.rule": "hybrid" if hybrid else "average"},
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
    config = config_for(dataset, {"filter.window": 8})
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
        # joint marginals travel in information form, what the receiver averages
        assert all(m.info is not None and m.cov is None for m in replies[i])
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
    # map ids that are not strictly increasing (repeated or out of order) are refused
    assert ids.size == 2
    for bad in (np.sort(ids)[::-1], np.repeat(ids[:1], 2)):
        assert protocol.answer([MapIdsMessage(1, 0, 15, bad)]) == []
    assert agents[0].counters["rejected_messages"] == 7
    np.testing.assert_array_equal(state.cov, before[0])
    np.testing.assert_array_equal(state.objects, before[1])
    np.testing.assert_array_equal(state.poses, before[2])


def test_wire_carries_moved_flags_and_degree_and_refuses_version_1():
    from teamslam.runtime.wire import WireError, decode, encode, team_id

    team = team_id("flags")
    moved = np.array([True, False, False, True, True, False, True, False, True])
    ids = MapIdsMessage(0, 3, 5, np.arange(9) * 7, moved)
    back = decode(encode(ids, team), team, 4)
    np.testing.assert_array_equal(back.moved, moved)
    assert decode(encode(MapIdsMessage(0, 3, 5, np.arange(9)), team), team, 4).moved is None
    marginal = CommonMarginalMessage(1, 2, 3, np.array([4]), np.zeros(3), np.eye(3), degree=7)
    assert decode(encode(marginal, team), team, 4).degree == 7
    old = bytearray(encode(marginal, team))
    old[4] = 1
    with pytest.raises(WireError, match="format version 1 is no longer read"):
        decode(bytes(old), team, 4)


def _exchange(protocols, ends, step):
    """One lock-step consensus round between every pair; the objects each robot averaged."""
    n = len(protocols)
    for i in range(n):
        for m in protocols[i].requests(step):
            ends[i].send(m)
    for i in range(n):
        for m in protocols[i].answer(ends[i].collect(step, MapIdsMessage, set(range(n)), 0.0)):
            ends[i].send(m)
    return [
        protocols[i].average(ends[i].collect(step, CommonMarginalMessage, set(range(n)), 0.0))
        for i in range(n)
    ]


def test_robots_that_agree_exchange_nothing_until_an_object_moves(team4):
    dataset, _ = team4
    agents = _agents(dataset, 2)
    protocols = [ConsensusProtocol(a, [1 - a.robot], kl_threshold=1e-3) for a in agents]
    network = MemoryNetwork(2)
    ends = [network.endpoint(i) for i in range(2)]
    first = _exchange(protocols, ends, 15)
    assert first[0] == first[1] == 2  # objects 1000 and 1001 are new to the pair
    # repeated averaging converges; once the pair agrees, nothing is exchanged
    rounds = [_exchange(protocols, ends, 16 + k) for k in range(30)]
    assert rounds[-1] == [0, 0], rounds
    sent = ends[0].messages_sent
    state = agents[0].state
    before = state.snapshot()
    assert _exchange(protocols, ends, 50) == [0, 0]
    assert ends[0].messages_sent == sent + 1  # the map ids only
    for k, v in state.snapshot().items():
        np.testing.assert_array_equal(v, before[k])
    # robot 1 moves object 1001 (as an update would): exactly that object is averaged again
    slot = agents[1].state.object_slots(np.array([1001]))[0]
    agents[1].state.objects[slot] += 0.3
    assert _exchange(protocols, ends, 51) == [1, 1]


def test_consensus_on_what_moved_equals_full_averaging_on_a_team():
    """Skipping the objects that moved less than the threshold since the last exchange keeps
    the team within 2% trajectory and object error, and 2 cm on every pose, of averaging every
    common object at every step (objects only, where whole objects go unobserved for a while),
    while averaging fewer objects."""
    from teamslam.eval.metrics import team_metrics

    dataset = lissajous_team(robots=3, steps=80, seed=3)
    runs, metrics = {}, {}
    for threshold in (0.0, 1e-2):
        config = config_for(
            dataset,
            {
                "filter.window": 8,
                "filter.use_geometric_features": False,
                "consensus.kl_threshold": threshold,
            },
        )
        runs[threshold] = run_team(dataset, config, progress=False)
        metrics[threshold] = team_metrics(dataset, runs[threshold])
    full, moved = runs[0.0], runs[1e-2]
    averaged = [sum(c["objects_averaged"] for c in r.counters) for r in (full, moved)]
    assert averaged[1] < 0.9 * averaged[0], averaged
    assert metrics[1e-2]["bytes_per_robot_step"] < metrics[0.0]["bytes_per_robot_step"]
    sent = sum(c["bytes"] for c in moved.counters)
    steps = dataset.n_robots * (dataset.robots[0].frames - 1)
    assert metrics[1e-2]["bytes_per_robot_step"] == pytest.approx(sent / steps)
    for r in range(dataset.n_robots):
        assert np.abs(moved.poses[r][:, :3, 3] - full.poses[r][:, :3, 3]).max() < 0.02
    for key in ("trajectory_rmse_avg_m", "object_error_avg_m"):
        assert metrics[1e-2][key] == pytest.approx(metrics[0.0][key], rel=0.02), key


@pytest.mark.parametrize(
    ("per_object", "information"), [(False, False), (True, False), (False, True)]
)
@pytest.mark.parametrize("float32", [False, True])
def test_compact_marginals_cross_the_wire_exactly(team4, per_object, float32, information):
    from teamslam.msckf.consensus import common_marginal_message, receive_marginal
    from teamslam.msckf.consensus.messages import encoded_ids_size
    from teamslam.runtime.wire import decode, encode, team_id

    dataset, _ = team4
    agents = _agents(dataset, 1)
    state = agents[0].state
    ids = state.object_ids[-4:]
    kept = {}
    msg = common_marginal_message(
        state, 0, 1, 15, ids, 2, per_object, float32, information=information, keep=kept
    )
    assert msg.per_object == per_object and msg.single_precision == float32
    assert (msg.info is not None) == information and (msg.cov is None) == information
    data = encode(msg, team_id("w"))
    assert len(data) == msg.nbytes()
    back = decode(data, team_id("w"), 2)
    np.testing.assert_array_equal(back.mean, msg.mean)
    np.testing.assert_array_equal(back.matrix, msg.matrix)
    assert (back.info is not None) == information
    if information:
        # the information matrix is the inverse of the moment-form marginal; the sender keeps
        # the exact one (not rounded) under the message's ids
        moment = common_marginal_message(state, 0, 1, 15, ids, 2)
        exact = kept[msg.ids.astype(np.int64).tobytes()]
        np.testing.assert_allclose(exact @ moment.cov, np.eye(exact.shape[0]), atol=1e-8)
        if not float32:
            np.testing.assert_array_equal(msg.info, exact)
        # received in either form, the neighbour's marginal is the same
        _, from_info = receive_marginal(state, back)
        _, from_cov = receive_marginal(state, moment)
        scale = np.abs(from_cov.info).max()
        tol = (1e-5 if float32 else 1e-9) * scale
        np.testing.assert_allclose(from_info.info, from_cov.info, rtol=0, atol=tol)
    else:
        assert kept == {}
    k = ids.size
    full = 36 + encoded_ids_size(back.ids) + 8 * (3 * k + 3 * k * (3 * k + 1) // 2)
    assert len(data) < full or not (per_object or float32)
    # the per-object message is each object's own block of the joint one
    problem, received = receive_marginal(state, back)
    assert problem is None
    joint = common_marginal_message(state, 0, 1, 15, ids, 2, False, float32)
    if per_object:
        for i in range(k):
            block = slice(3 * i, 3 * i + 3)
            want = np.linalg.inv(joint.cov[block, block])
            np.testing.assert_allclose(received.info[block, block], want, rtol=1e-9)
        off = received.info.copy()  # no cross-object information
        for i in range(k):
            off[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] = 0
        assert not off.any()


def test_with_one_common_object_per_object_averaging_is_the_joint_one(team4):
    from teamslam.msckf.consensus import common_marginal_message, consensus_average

    dataset, _ = team4
    a, b = _agents(dataset, 2)
    twin = _agents(dataset, 2)[0]
    ids = np.array([1000])
    for per_object, target in ((False, a), (True, twin)):
        msg = common_marginal_message(b.state, 1, 0, 15, ids, 1, per_object)
        consensus_average(target.state, 0.5, [(0.5, msg)])
    np.testing.assert_allclose(twin.state.cov, a.state.cov, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(twin.state.objects, a.state.objects, rtol=1e-12, atol=1e-15)


def test_each_neighbour_not_averaged_with_is_counted_with_why(team4):
    """Every (exchange, neighbour) pair not averaged has one reason: a neighbour not heard,
    one with nothing to average, one whose marginal did not come, was refused or failed the
    consensus innovation check."""
    dataset, _ = team4
    agents = _agents(dataset, 4)
    protocols = [ConsensusProtocol(a, [j for j in range(4) if j != a.robot]) for a in agents]
    network = LyingNetwork(4, liar=3)  # robot 3's marginals are far off and overconfident
    ends = [network.endpoint(i) for i in range(4)]
    for i in range(4):  # robot 2's map ids to robot 0 are lost
        for m in protocols[i].requests(15):
            if (m.sender, m.receiver) != (2, 0):
                ends[i].send(m)
    for i in range(4):
        heard = ends[i].collect(15, MapIdsMessage, set(range(4)), 0.0)
        for m in protocols[i].answer(heard):
            ends[i].send(m)
    marginals = ends[0].collect(15, CommonMarginalMessage, set(range(4)), 0.0)
    assert sorted(m.sender for m in marginals) == [1, 2, 3]
    # robot 1's marginal goes missing on its way, robot 2's answers a request it heard
    protocols[0].average([m for m in marginals if m.sender == 3])
    assert protocols[0].averaged_with == []
    assert protocols[0].not_averaged == {1: "no_marginal", 2: "not_heard", 3: "inconsistent"}
    assert agents[0].counters["consensus_marginals_left_out"] == 1
    # robot 1 gets robot 0's marginal broken: refused, and counted as a rejected message
    broken = [
        dataclasses.replace(m, mean=np.full_like(m.mean, np.nan))
        for m in ends[1].collect(15, CommonMarginalMessage, set(range(4)), 0.0)
        if m.sender == 0
    ]
    rejected = agents[1].counters["rejected_messages"]
    protocols[1].average(broken)
    assert protocols[1].not_averaged[0] == "refused"
    assert agents[1].counters["rejected_messages"] == rejected + 1


def test_a_neighbour_with_nothing_to_average_is_counted_so(team4):
    dataset, _ = team4
    agents = _agents(dataset, 2)
    protocols = [ConsensusProtocol(a, [1 - a.robot], kl_threshold=1e-3) for a in agents]
    network = MemoryNetwork(2)
    ends = [network.endpoint(i) for i in range(2)]
    assert _exchange(protocols, ends, 15) == [2, 2]
    assert protocols[0].not_averaged == {}
    for k in range(30):  # until the pair agrees and nothing moves
        if _exchange(protocols, ends, 16 + k) == [0, 0]:
            break
    assert protocols[0].not_averaged == {1: "nothing_common"}
    assert protocols[1].not_averaged == {0: "nothing_common"}
