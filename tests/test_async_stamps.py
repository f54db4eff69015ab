"""Asynchronous live robots that drop different frames keep averaging: their steps are not
comparable, so their messages carry their frame's stamp and are aged by it
(:class:`~teamslam.msckf.consensus.messages.MessageAge`); without a network, in one thread."""

from __future__ import annotations

import time

import numpy as np
import pytest

from teamslam.msckf.consensus.messages import (
    CommonMarginalMessage,
    MapIdsMessage,
    MessageAge,
    MessageLags,
)
from teamslam.msckf.consensus.transport import Mailbox
from teamslam.runtime import wire
from teamslam.runtime.team_file import TeamFileError, load_team_file

S = 1_000_000_000  # ns per second


def ids_message(sender: int, step: int, stamp_ns: int | None) -> MapIdsMessage:
    return MapIdsMessage(sender, 0, step, np.array([1, 4, 9]), None, None, stamp_ns)


def test_an_age_by_stamp_accepts_neighbours_ahead_and_refuses_old_or_unstamped_messages():
    age = MessageAge(step=10, max_age=3, stamp_ns=100 * S, max_age_ns=3 * S)
    # steps say nothing here: a neighbour that dropped fewer frames is many steps ahead
    assert age.problem(ids_message(1, 60, 100 * S)) is None
    assert age.problem(ids_message(1, 2, 97 * S)) is None
    assert age.problem(ids_message(1, 70, 104 * S)) is None  # ahead in time: fresher
    assert "older than 3 s" in age.problem(ids_message(1, 9, 97 * S - 1))
    assert "without a frame stamp" in age.problem(ids_message(1, 10, None))
    # by step, as before: steps 7 to 10 only
    by_step = MessageAge(step=10, max_age=3)
    assert by_step.problem(ids_message(1, 7, None)) is None
    assert by_step.problem(ids_message(1, 11, None)) == "message of step 11 at 10"
    assert by_step.problem(ids_message(1, 6, None)) == "message of step 6 at 10"
    with pytest.raises(ValueError, match="stamp"):
        MessageAge(step=1, max_age=1, max_age_ns=S)


def test_a_mailbox_hands_over_each_senders_newest_message_by_stamp_and_discards_expired_ones():
    box = Mailbox()
    for message in (
        ids_message(1, 5, 90 * S),  # expired
        ids_message(1, 6, 98 * S),
        ids_message(1, 7, 99 * S),  # newest of robot 1
        ids_message(2, 40, 101 * S),  # robot 2, ahead in steps and in time
        ids_message(3, 8, None),  # no stamp: handed over once, for the checks to name
    ):
        box.put(message)
    got = box.newest(MapIdsMessage, {1, 2, 3}, 3, 10, 100 * S, 3 * S)
    assert [(m.sender, m.step) for m in got] == [(1, 7), (2, 40), (3, 8)]
    again = box.newest(MapIdsMessage, {1, 2, 3}, 3, 11, 102 * S, 3 * S)
    assert [(m.sender, m.step) for m in again] == [(1, 7), (2, 40)]
    assert box.newest(MapIdsMessage, {1, 2, 3}, 3, 12, 110 * S, 3 * S) == []
    # by step, a neighbour 30 steps ahead is expired for nobody, and one 4 steps behind is
    box.put(ids_message(1, 6, None))
    assert [m.step for m in box.newest(MapIdsMessage, {1}, 3, 10)] == []


def test_a_neighbour_whose_messages_arrive_late_is_heard_up_to_its_learned_lag():
    """A fast robot (1 s frames, floor 3 s) and a slow neighbour sending one message every 2 s
    of stamps, each reaching the robot 4 or 5 s of stamps after it was sent: by the robot's own
    steps alone every message of the neighbour is too old (counted); with the lags learned the
    neighbour's newest message is used at every exchange, up to the lags' quantile plus the
    neighbour's interval."""
    # message k: sent at a frame stamped 96 + 2k s, first found at our frame t_k = 2k + k % 2
    # (stamped 100 + t_k s): a lag of 4 s for even k, 5 s for odd k
    arrives = {2 * k + k % 2: k for k in range(30)}

    def exchanges(lags: MessageLags | None, floor: int = 3 * S) -> list[int | None]:
        box = Mailbox()
        used = []
        for t in range(60):
            if t in arrives:
                box.put(ids_message(1, arrives[t], 96 * S + 2 * arrives[t] * S))
            got = box.newest(MapIdsMessage, {1}, 3, t, 100 * S + t * S, floor, lags)
            used.append(got[0].step if got else None)
        return used

    own = MessageLags(quantile=None)  # the floor alone: what is found too old is counted
    assert exchanges(own) == [None] * 60
    assert own.too_old == {1: 30}
    lags = MessageLags(quantile=0.9)  # ten lags to estimate the quantile
    assert lags.needed == 10
    newest = [max(k for t_k, k in arrives.items() if t_k <= t) for t in range(60)]
    # the newest message at every exchange, but for the first's second one: one lag (4 s) and
    # no interval known, it expired at 5 s
    assert exchanges(lags) == [0, None, None, *newest[3:]]
    assert lags.too_old == {1: 1}
    # the limit: the lags' 0.9-quantile (5 s) plus the neighbour's interval (2 s)
    assert lags.limit_ns(1, MapIdsMessage, 3 * S) == 7 * S
    assert lags.limit_ns(1, MapIdsMessage, 8 * S) == 8 * S  # never below the floor
    assert lags.limit_ns(2, MapIdsMessage, 3 * S) == 3 * S  # a neighbour never heard
    assert not lags.stale(1, MapIdsMessage, MessageAge(59, 3, 159 * S, 3 * S, lags))
    # the neighbour falls silent: its last message (stamp 154 s) expires 7 s after it was sent
    assert not lags.stale(1, MapIdsMessage, MessageAge(61, 3, 161 * S, 3 * S, lags))
    assert lags.stale(1, MapIdsMessage, MessageAge(62, 3, 161 * S + 1, 3 * S, lags))
    # before ten lags are known, the largest one stands for the quantile
    early = MessageLags(quantile=0.9)
    box = Mailbox()
    box.put(ids_message(1, 0, 96 * S))
    box.put(ids_message(1, 1, 97 * S))
    assert [m.step for m in box.newest(MapIdsMessage, {1}, 3, 0, 101 * S, 3 * S, early)] == [1]
    assert early.limit_ns(1, MapIdsMessage, 3 * S) == 5 * S + S  # lags 5 s and 4 s, 1 s apart
    with pytest.raises(ValueError, match="quantile"):
        MessageLags(quantile=1.0)


def test_a_resumed_robot_keeps_the_lags_it_learned(tmp_path):
    """The lags learned go into the checkpoint: restored from it, a robot has the same age limit
    for every neighbour (not the floor a new robot starts from), and the same after the next
    messages (the lags and intervals kept go on, window and all)."""
    from types import SimpleNamespace

    from teamslam.runtime.agent_process import LAGS, _restore_lags

    def feed(lags: MessageLags, ks: range) -> None:
        for k in ks:  # neighbour 1: 4 or 5 s late every 2 s; neighbour 2: 1 s late every 3 s
            t_k = 2 * k + k % 2
            lags.seen(ids_message(1, k, 96 * S + 2 * k * S), 100 * S + t_k * S)
            lags.seen(ids_message(2, k, 10 * S + 3 * k * S), 11 * S + 3 * k * S)

    lags = MessageLags(quantile=0.9, window=12)
    feed(lags, range(20))
    before = {j: lags.limit_ns(j, MapIdsMessage, 3 * S) for j in (1, 2)}
    assert before == {1: 7 * S, 2: 4 * S}  # quantile of the lags plus the interval
    np.savez_compressed(
        tmp_path / "c.npz", **{f"{LAGS}{k}": v for k, v in lags.state_dict().items()}
    )
    with np.load(tmp_path / "c.npz", allow_pickle=False) as c:
        snapshot = {k: c[k] for k in c.files}
    resumed = SimpleNamespace(lags=MessageLags(quantile=0.9, window=12))
    assert resumed.lags.limit_ns(1, MapIdsMessage, 3 * S) == 3 * S  # nothing learned yet
    _restore_lags(resumed, snapshot)
    for j in (1, 2):
        for floor in (0, 3 * S):
            assert resumed.lags.limit_ns(j, MapIdsMessage, floor) == lags.limit_ns(
                j, MapIdsMessage, floor
            )
        assert resumed.lags.limit_ns(j, CommonMarginalMessage, 0) == 0  # no such lags
    # the next messages: the same lags kept (the window of 12 slides the same way); a resumed
    # robot has not seen the neighbours' last messages before it went down, so their first
    # interval after it is not known to it, the lags are
    feed(lags, range(20, 40))
    feed(resumed.lags, range(20, 40))
    for j in (1, 2):
        assert resumed.lags.limit_ns(j, MapIdsMessage, 0) == lags.limit_ns(j, MapIdsMessage, 0)
    bad = dict(snapshot, **{f"{LAGS}kinds": np.array(["Nothing", "Nothing"])})
    with pytest.raises(ValueError, match="unknown message kind"):
        _restore_lags(SimpleNamespace(lags=MessageLags()), bad)


@pytest.mark.parametrize("kind", ["ids", "marginal"])
def test_a_stamped_message_travels_with_its_stamp_and_an_unstamped_one_is_unchanged(kind):
    team = wire.team_id("stamps")
    if kind == "ids":
        plain = MapIdsMessage(0, 1, 7, np.array([3, 4, 9]), np.array([True, False, True]))
    else:
        plain = CommonMarginalMessage(
            0, 1, 7, np.array([3]), np.arange(3.0), None, 2, info=2.0 * np.eye(3)
        )
    stamped = type(plain)(**{**plain.__dict__, "stamp_ns": 1_700_000_000_123_456_789})
    a, b = wire.encode(plain, team), wire.encode(stamped, team)
    assert len(b) == len(a) + 8 == stamped.nbytes() and len(a) == plain.nbytes()
    assert b[5] == a[5] | wire.STAMPED and b[:5] == a[:5] and b[6:36] == a[6:36]
    assert b[44:] == a[36:]  # the payload, after the stamp
    back = wire.decode(b, team, 2)
    assert back.stamp_ns == stamped.stamp_ns and back.step == 7
    assert np.array_equal(back.ids, plain.ids)
    assert wire.decode(a, team, 2).stamp_ns is None
    with pytest.raises(wire.WireError, match=r"length|truncated"):
        wire.decode(b[:40], team, 2)


def test_max_age_s_in_a_team_file_is_checked(tmp_path):
    path = tmp_path / "team.yaml"
    base = "team: t\nsync: async\nrobots:\n  - {id: 0}\n"
    path.write_text(base + "max_age_s: 0.5\n")
    assert load_team_file(path).max_age_s == 0.5
    path.write_text(base)
    assert load_team_file(path).max_age_s is None
    for bad in ("-1", ".inf", "soon"):
        path.write_text(base + f"max_age_s: {bad}\n")
        with pytest.raises(TeamFileError, match="max_age_s"):
            load_team_file(path)
    path.write_text(base)
    assert load_team_file(path).max_age_quantile == 0.95
    path.write_text(base + "max_age_quantile: null\n")
    assert load_team_file(path).max_age_quantile is None
    path.write_text(base + "max_age_quantile: 0.8\n")
    assert load_team_file(path).max_age_quantile == 0.8
    for bad in ("0", "1", "1.5", "often"):
        path.write_text(base + f"max_age_quantile: {bad}\n")
        with pytest.raises(TeamFileError, match="max_age_quantile"):
            load_team_file(path)


# ---------------------------------------------------------------------- live robots, in process
ROBOTS, STEPS, OBJECTS, SEED = 3, 45, 40, 1


@pytest.fixture(scope="module")
def team_bag(tmp_path_factory):
    """A 3-robot team's bag of odometry, observations and ground truth, and its import."""
    pytest.importorskip("rosbags", reason="the ros2 extra (rosbags) is not installed")
    from teamslam.msckf.configure import build_settings
    from teamslam.ros2 import messages as m
    from teamslam.ros2.bags import RobotTopics, export_bag, import_bag
    from teamslam.ros2.live import Received
    from teamslam.sim import lissajous_team

    tmp = tmp_path_factory.mktemp("async_team")
    team = lissajous_team(robots=ROBOTS, steps=STEPS, objects=OBJECTS, seed=SEED)
    bag, camera = tmp / "team.mcap", tmp / "camera.json"
    export_bag(team, bag, camera=camera)
    names = [
        RobotTopics(f"robot_{i}", f"/robot_{i}/odom", f"/robot_{i}/ground_truth")
        for i in range(ROBOTS)
    ]
    dataset = import_bag(bag, names, "/{name}/stereo_observations", camera)
    config = build_settings(dataset, calibrate="never").config
    highlevel = m.rosbags("highlevel")
    items = []
    with highlevel.AnyReader([bag], default_typestore=m.typestore()) as reader:
        for conn, _, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            stamp = m.stamp_ns(msg.header.stamp)
            items.append(Received(conn.topic, conn.msgtype, stamp, msg, time.monotonic_ns()))
    return dataset, config, items


def run_team(tmp_path, team_bag, speeds, queue, consensus=True, quantile=0.95):
    """The team's robots in one thread: messages fed in recorded order and, at each of the last
    robot's camera frames, robot ``i`` processes ``speeds[i]`` frames on average (a slower robot
    falls behind and its queue, ``queue`` or ``queue[i]`` frames, drops its oldest frames; the
    longer its queue, the older the frames it processes). Position RMSE over every frame
    processed (robots pooled), frames processed per robot, and the robots."""
    queues = [queue] * ROBOTS if np.isscalar(queue) else list(queue)
    from teamslam.live import LiveInputs, LiveRobot
    from teamslam.msckf.consensus.transport import MemoryNetwork
    from teamslam.runtime.team_file import RobotEntry, TeamFile

    dataset, config, items = team_bag
    entries = [
        RobotEntry(i, "tcp/127.0.0.1:0", [j for j in range(ROBOTS) if j != i] if consensus else [])
        for i in range(ROBOTS)
    ]
    team = TeamFile(
        "async",
        None,
        entries,
        sync="async",
        max_age_steps=3,
        max_age_quantile=quantile,
        checkpoint_every=0,
    )
    network = MemoryNetwork(ROBOTS)
    robots = [
        LiveRobot(
            team,
            i,
            LiveInputs(
                f"/robot_{i}/odom",
                observations=f"/robot_{i}/stereo_observations",
                ground_truth=f"/robot_{i}/ground_truth",
                queue=queues[i],
            ),
            config,
            tmp_path,
            calibration=dataset.calibration,
            transport=network.endpoint(i) if consensus else None,
            say=lambda text: None,
        )
        for i in range(ROBOTS)
    ]
    credit = np.zeros(ROBOTS)

    def tick() -> None:
        credit[:] += speeds
        for i, robot in enumerate(robots):
            while credit[i] >= 1 and robot.process_queued():
                credit[i] -= 1
            credit[i] = min(credit[i], 1.0)

    last = f"/robot_{ROBOTS - 1}/stereo_observations"
    for item in items:
        robots[int(item.topic.split("/")[1].rsplit("_", 1)[1])].feed(item)
        if item.topic == last:
            tick()
    for robot in robots:
        robot.finish()
    while any(robot.process_queued() for robot in robots):
        pass
    origin = int(dataset.metadata["ros2"]["stamp_origin_ns"])
    errors = []
    for robot, sequence in zip(robots, dataset.robots, strict=True):
        index = {origin + round(t * 1e9): k for k, t in enumerate(sequence.timestamps)}
        frames = [index[int(s)] for s in robot.sequence.stamps_ns[: robot.sequence.frames]]
        estimate = robot.driver.poses[: robot.driver.done, :3, 3]
        errors.append(estimate - sequence.T_world_body[frames, :3, 3])
    e = np.concatenate(errors)
    rmse = float(np.sqrt(np.mean(np.sum(e**2, axis=1))))
    return rmse, [robot.sequence.frames for robot in robots], robots


def test_asynchronous_robots_that_drop_different_frames_keep_averaging(team_bag, tmp_path):
    speeds = np.array([1.0, 0.55, 0.75])
    rmse, frames, robots = run_team(tmp_path / "drops", team_bag, speeds, queue=2)
    nodrop, nodrop_frames, full = run_team(tmp_path / "nodrop", team_bag, np.ones(3), 10_000)
    alone, _, _ = run_team(tmp_path / "alone", team_bag, speeds, queue=2, consensus=False)
    # the robots dropped different frames: their steps drifted far apart
    assert nodrop_frames == [STEPS + 1] * ROBOTS
    assert frames[0] == STEPS + 1 and frames[0] - frames[2] > 5 and frames[2] - frames[1] > 5
    assert [robot.counts.dropped["queue"] for robot in robots] == [STEPS + 1 - n for n in frames]
    # every message was accepted, and each pair that averages without drops averages on about
    # as large a share of its frames with them
    for robot, reference, n in zip(robots, full, frames, strict=True):
        assert robot.driver.agent.counters["rejected_messages"] == 0
        for j, steps in reference.driver.averaged_with.items():
            share = len(steps) / (STEPS + 1)
            assert len(robot.driver.averaged_with.get(j, [])) >= 0.5 * share * n, (robot.robot, j)
    # consensus keeps its benefit: near the run without drops, well below robots alone
    assert rmse < 1.25 * nodrop and rmse < 0.8 * alone
    # the default age limit, max_age_steps of a robot's steps: longer steps when it drops
    steps = [
        robot.sequence.step_interval_ns(n - 1) for robot, n in zip(robots, frames, strict=True)
    ]
    assert steps[0] == S  # the bag's 1 Hz camera: a robot that drops nothing
    assert steps[1] > steps[2] > S  # the slowest robot takes the longest steps
    with pytest.raises(ValueError, match="no step interval"):
        robots[0].sequence.step_interval_ns(0)


def test_robots_aged_by_stamp_answer_a_summary_out_of_their_phase_once():
    """Own association: a neighbour's object summary comes at its own steps (every
    ``association.interval``); a robot aged by stamp answers it with its own summary made then
    — once, though the same newest request comes back (aged by step, the request of a later
    step is refused)."""
    from teamslam.datasets.identity import strip_object_ids
    from teamslam.msckf import config_for
    from teamslam.msckf.agent import MsckfAgent
    from teamslam.msckf.consensus.protocol import ConsensusProtocol
    from teamslam.sim import lissajous_team

    team = strip_object_ids(lissajous_team(robots=2, steps=12, seed=4, landmarks=300), seed=2)
    config = config_for(team, {"association.mode": "own", "filter.window": 6}, "never")
    agents = [MsckfAgent(i, team.calibration, team.robots[i], config) for i in range(2)]
    for agent in agents:
        for t in range(11):
            agent.step(t)

    def associations(by_stamp: bool) -> list[int]:
        age = {"max_age_ns": 3 * S} if by_stamp else {}
        a, b = (ConsensusProtocol(agent, [1 - agent.robot], max_age=3) for agent in agents)
        (request,) = a.requests(10, stamp_ns=10 * S, **age)  # a summary step of robot 0 ...
        assert request.summary is not None and request.stamp_ns == 10 * S
        counts = []
        for step in (7, 8):  # ... at steps of robot 1 that are not, the request seen twice
            b.requests(step, stamp_ns=(step + 3) * S, **age)
            b.answer([request])
            assert b.heard == ({0} if by_stamp else set())
            stats = b.link_stats[0]
            counts.append(stats["full_associations"] + stats["extensions"])
        return counts

    assert associations(by_stamp=True) == [1, 1]
    assert associations(by_stamp=False) == [0, 0]


def test_a_fast_robot_keeps_averaging_with_a_neighbour_that_lags_behind(team_bag, tmp_path):
    """Robots 0 and 1 process every frame; robot 2, at half their speed with a long queue,
    processes frames up to eight of their frames old. By a robot's own steps
    (``max_age_steps`` of them, 3 s) robot 2's messages are too old for robot 0 once its queue
    filled — counted — and robot 0's marginals never reach robot 2 in answer; with the age
    limit learned from the lags, robot 0 and robot 2 keep averaging with each other."""
    speeds, queues = np.array([1.0, 1.0, 0.5]), [2, 2, 8]
    _, frames, own = run_team(tmp_path / "own", team_bag, speeds, queues, quantile=None)
    _, learned_frames, learned = run_team(tmp_path / "learned", team_bag, speeds, queues)
    assert frames == learned_frames and frames[2] < 0.7 * frames[0]
    assert own[0].counts.dropped["queue"] == 0 < own[2].counts.dropped["queue"]
    late = range(2 * frames[0] // 3, frames[0])  # robot 2 is 8 frames behind

    def averaged(robots, i, j, frames=None) -> int:
        steps = robots[i].driver.averaged_with.get(j, [])
        return len(steps) if frames is None else len(set(steps) & set(frames))

    assert averaged(own, 0, 2, late) == 0 and averaged(own, 2, 0) == 0
    assert averaged(learned, 0, 2, late) > 0.5 * len(late)
    assert averaged(learned, 2, 0) > 0.3 * frames[2]
    # robot 2's messages robot 0 found too old are counted, and the pairs they cost
    fast_own, fast = own[0].driver, learned[0].driver
    assert fast_own.agent.counters["messages_too_old"] > fast.agent.counters["messages_too_old"]
    assert fast_own.not_averaged["too_old"] > 0.5 * len(late)
    assert fast.not_averaged["too_old"] < 0.5 * fast_own.not_averaged["too_old"]
