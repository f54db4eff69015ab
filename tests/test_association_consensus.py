"""Consensus over correspondences: robots that name their own objects (``association.mode = own``).

Each link keeps a correspondence table computed alike at both ends; round-2 marginals travel in
the sender's ids and are translated by the receiver; a pair whose consensus innovation fails its
``χ²`` test is revoked. With a table that holds exactly the equal ids the path is the oracle
one, bit for bit; on a stripped team the association finds only right pairs; a wrong pair is
revoked; a lying member is no longer averaged; too few objects give no correspondence.
"""

from __future__ import annotations

import os
from dataclasses import replace

import numpy as np
import pytest

from teamslam import api
from teamslam.datasets import save_dataset
from teamslam.datasets.identity import strip_object_ids
from teamslam.errors import InputError
from teamslam.eval.metrics import team_metrics, trajectory_rmse
from teamslam.graph import complete, ring
from teamslam.msckf import build_settings, config_for, run_team
from teamslam.msckf.consensus.messages import MapIdsMessage
from teamslam.msckf.consensus.protocol import ConsensusProtocol
from teamslam.msckf.consensus.transport import LyingNetwork, MemoryNetwork
from teamslam.msckf.settings.values import MsckfConfig
from teamslam.msckf.team import lockstep_drivers, run_drivers
from teamslam.runtime.team_file import write_team_file
from teamslam.runtime.wire import WireError, decode, encode, team_id
from teamslam.sim import lissajous_team, scenario_team
from test_protocol import _threads_over_memory  # the robot-process driver in threads


@pytest.fixture(scope="module")
def team3():
    return lissajous_team(robots=3, steps=40, seed=4, landmarks=500)


@pytest.fixture(scope="module")
def stripped3(team3):
    return strip_object_ids(team3, seed=2)


@pytest.fixture(scope="module")
def oracle3(team3):
    """The oracle-id consensus run of ``team3`` (window 6), read by several tests."""
    return run_team(team3, config_for(team3, {"filter.window": 6}), progress=False)


def _rmse(result, dataset) -> float:
    return float(
        np.mean(
            [
                trajectory_rmse(p, r.T_world_body)
                for p, r in zip(result.poses, dataset.robots, strict=True)
            ]
        )
    )


def _drivers(dataset, config, network, graph=None):
    n = dataset.n_robots
    return lockstep_drivers(dataset, [config] * n, network, graph or complete(n))


def test_association_settings_are_recorded_by_group():
    assert MsckfConfig().to_json()["association"]["mode"] == "oracle"
    own = MsckfConfig.from_settings({"association.mode": "own"}).to_json()
    assert own["association"]["mode"] == "own" and own["association"]["interval"] == 5
    with pytest.raises(InputError, match=r"association\.mode must be oracle or own"):
        MsckfConfig.from_settings({"association.mode": "ids"})


def test_own_with_a_table_of_equal_ids_is_the_oracle_run_bit_for_bit(team3, oracle3, monkeypatch):
    """Translation, reordering and the moved flags in own ids reproduce the oracle path."""
    config = config_for(team3, {"filter.window": 6})
    oracle = oracle3

    def equal_ids(self, j, request):
        table = self.tables[j]
        for i in np.intersect1d(request.ids, self._summary.ids):
            if int(i) not in table._theirs:
                table._theirs[int(i)] = int(i)
                table._ours[int(i)] = int(i)
        return True

    monkeypatch.setattr(ConsensusProtocol, "_associate", equal_ids)
    own = config.with_(
        {
            "association.mode": "own",
            "association.interval": 1,
            "association.revoke_probability": 1 - 1e-15,
        }
    )
    result = run_team(team3, own, progress=False)
    for a, b in zip(result.poses, oracle.poses, strict=True):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(result.objects, oracle.objects, strict=True):
        np.testing.assert_array_equal(a, b)
    assert result.counters[0]["objects_averaged"] == oracle.counters[0]["objects_averaged"] > 0


def test_own_on_a_stripped_team_matches_right_pairs_at_both_ends(team3, stripped3, oracle3):
    config = config_for(team3, {"filter.window": 6})
    oracle = oracle3
    separate = run_team(team3, config, consensus=False, progress=False)
    result = run_team(stripped3, config.with_({"association.mode": "own"}), progress=False)
    metrics = team_metrics(stripped3, result)["association"]
    team = metrics["team"]
    assert team["accepted"] > 0 and team["wrong"] == 0 and team["precision"] == 1.0
    assert team["recall"] > 0.5
    # the shared rule: both ends of every link hold the same pairs, mirrored
    assert all(link["ends_agree"] for link in metrics["links"].values())
    assert len(metrics["links"]) == 3
    assert all(link["summary_bytes_per_step"][0] > 0 for link in metrics["links"].values())
    # consensus over the found pairs helps like the oracle's
    own_rmse = _rmse(result, stripped3)
    assert own_rmse < _rmse(separate, team3)
    assert own_rmse <= 1.3 * _rmse(oracle, team3)


def test_oracle_is_refused_on_per_robot_ids_which_default_to_own(stripped3):
    with pytest.raises(InputError, match=r"association\.mode=oracle needs team-wide object ids"):
        build_settings(stripped3, flags={"association.mode": "oracle"}, calibrate="never")
    effective = build_settings(stripped3, calibrate="never")
    assert effective.config.association.mode == "own"
    assert effective.sources["association.mode"] == "dataset"
    with pytest.raises(InputError, match="association oracle needs team-wide object ids"):
        api.run(stripped3, "consensus", settings={"filter.window": 6}, association="oracle")


def _cross(table, first: tuple[int, int], second: tuple[int, int]) -> list[tuple[int, int]]:
    """Replace two held pairs of ``table`` by the two wrong pairs that cross them."""
    (a0, b0), (a1, b1) = first, second
    for own_id, their_id in (first, second):
        del table._theirs[own_id], table._ours[their_id]
    wrong = [(a0, b1), (a1, b0)]
    for own_id, their_id in wrong:
        table._theirs[own_id] = their_id
        table._ours[their_id] = own_id
    return wrong


def test_a_wrong_pair_is_revoked_and_not_readded(stripped3):
    config = config_for(stripped3, {"filter.window": 6}).with_(
        {"association.mode": "own", "association.interval": 1}
    )
    drivers = _drivers(stripped3, config, MemoryNetwork(3))
    injected = {}

    def inject(t, running):
        if t != 20:
            return
        table = drivers[0].protocol.tables[2]
        pairs = [tuple(int(v) for v in p) for p in table.pairs()]
        assert len(pairs) >= 4
        state = drivers[0].agent.state
        position = dict(zip(state.object_ids.tolist(), state.objects, strict=True))
        # the two held pairs farthest apart, crossed at both ends of link 0–1
        first, second = max(
            ((p, q) for p in pairs for q in pairs if p < q),
            key=lambda pq: np.linalg.norm(position[pq[0][0]] - position[pq[1][0]]),
        )
        injected[0] = _cross(table, first, second)
        mirrored = [(b, a) for a, b in (first, second)]
        injected[2] = _cross(drivers[2].protocol.tables[0], *mirrored)

    run_drivers(drivers, "complete", 0.0, inject, progress=False)
    assert injected
    for robot, other in ((0, 2), (2, 0)):
        table = drivers[robot].protocol.tables[other]
        assert table.revoked >= 2
        for pair in injected[robot]:
            assert pair not in table
    assert drivers[0].agent.counters["consensus_innovation_failures"] >= 2


def test_noisy_odometry_right_pairs_are_not_revoked():
    """Noisy odometry (3 cm, 0.01 rad a step): the robots' maps are overconfident against each
    other, which each link learns (its frame scale) from pairs a transform identified. The
    consensus pair check tests the same hypothesis with that scale: of the right pairs it held,
    it revokes at most 1% (without the scale, 57 of about 270 pairs, each at both ends), and it
    holds no wrong pair."""
    team = scenario_team("odometry-3cm-0.01rad-objects")
    stripped = strip_object_ids(team, seed=0)
    config = config_for(stripped, {"filter.window": 10})
    drivers = _drivers(stripped, config, MemoryNetwork(3))
    run_drivers(drivers, "complete", 0.0, progress=False)

    def truth(robot: int) -> dict[int, int]:
        keys, values = stripped.true_objects(robot)
        return dict(zip(keys.tolist(), values.tolist(), strict=True))

    right_revoked = accepted = wrong_held = 0
    for robot, driver in enumerate(drivers):
        ours = truth(robot)
        for j, table in driver.protocol.tables.items():
            theirs = truth(j)
            accepted += table.accepted
            right_revoked += sum(ours.get(a, -1) == theirs.get(b, -2) for a, b in table._revoked)
            wrong_held += sum(
                ours.get(a, -1) != theirs.get(b, -2) for a, b in table.pairs().tolist()
            )
    assert accepted > 400  # both ends of three links
    assert right_revoked <= 0.01 * accepted
    assert wrong_held == 0


@pytest.mark.parametrize("mode", ["own", "oracle-default"])
def test_a_lying_member_is_no_longer_averaged(mode):
    """Robot 2 lies to everyone; with the default settings the others end as well as a team
    without it (the best any check can do: the liar sends nothing true), and without the check
    they would be tens of metres off."""
    team = lissajous_team(robots=4, steps=40, seed=4, landmarks=500)
    config = config_for(team, {"filter.window": 6})  # the check is on by default
    if mode == "own":
        team = strip_object_ids(team, seed=2)
        config = config.with_({"association.mode": "own", "association.interval": 1})
    honest = [0, 1, 3]
    without = team.subset(honest)
    alone = run_team(without, config, progress=False)
    lied = run_drivers(_drivers(team, config, LyingNetwork(4, 2)), "c", 0.0, progress=False)
    rmse_without = _rmse(alone, without)

    def honest_rmse(result) -> float:
        return float(
            np.mean([trajectory_rmse(result.poses[i], team.robots[i].T_world_body) for i in honest])
        )

    assert honest_rmse(lied) <= 1.1 * rmse_without
    # caught by the χ² test of the consensus innovation, at every robot it lied to that
    # shares objects with it
    assert lied.counters[0]["consensus_innovation_failures"] > 0
    if mode == "own":  # the liar's pairs are revoked at the honest end
        assert lied.extra["association"][0]["2"]["revoked"] > 0
        assert lied.extra["association"][0]["2"]["held"] == 0
    else:  # its marginals are left out whole, and the attack would work without the check
        assert lied.counters[0]["consensus_marginals_left_out"] > 0
        unchecked = config.with_({"consensus.innovation_check": False})
        fooled = run_drivers(
            _drivers(team, unchecked, LyingNetwork(4, 2)), "c", 0.0, progress=False
        )
        assert honest_rmse(fooled) > 100 * rmse_without


def test_the_default_check_leaves_an_honest_run_as_it_was(team3, oracle3):
    """With honest robots no marginal has most of its objects failing: the default run (check
    on) is the run without the check, bit for bit."""
    unchecked = run_team(
        team3,
        config_for(team3, {"filter.window": 6, "consensus.innovation_check": False}),
        progress=False,
    )
    assert all(c.get("consensus_marginals_left_out", 0) == 0 for c in oracle3.counters)
    for a, b in zip(oracle3.poses, unchecked.poses, strict=True):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(oracle3.objects, unchecked.objects, strict=True):
        np.testing.assert_array_equal(a, b)


def test_too_few_objects_give_no_correspondence_and_the_separate_run():
    team = strip_object_ids(lissajous_team(robots=2, steps=30, seed=3, objects=4), seed=0)
    config = config_for(team, {"filter.window": 6})
    separate = run_team(team, config, consensus=False, progress=False)
    result = run_team(
        team, config.with_({"association.mode": "own", "association.interval": 1}), progress=False
    )
    assert all(e["held"] == 0 for a in result.extra["association"] for e in a.values())
    for a, b in zip(result.poses, separate.poses, strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)


def test_summaries_cross_the_wire_and_threads_equal_in_process(stripped3, tmp_path):
    """Robot-process drivers (in threads, over memory) give the in-process own run."""
    reference_config = config_for(stripped3, {"filter.window": 6, "association.mode": "own"})
    reference = run_team(stripped3, reference_config, ring(3), progress=False)
    directory = tmp_path / "data"
    save_dataset(stripped3, directory)
    team_path = write_team_file(
        tmp_path / "team.yaml",
        f"own-{os.getpid()}",
        directory,
        ring(3).adjacency,
        base_port=27500,
        timeout_s=60.0,
        settings={"filter.window": 6, "association.mode": "own"},
    )
    _threads_over_memory(team_path, tmp_path / "out", lambda t: np.ones((3, 3), bool), 3)
    from teamslam.msckf.team import load_result

    for r in range(3):
        part = load_result(tmp_path / "out" / f"robot_{r}")
        np.testing.assert_array_equal(part.poses[0], reference.poses[r])
        np.testing.assert_array_equal(part.objects[0], reference.objects[r])
    # a summary survives the wire exactly
    ids = np.array([3, 9, 40])
    from teamslam.association import ObjectSummary

    summary = ObjectSummary(2, ids, np.arange(9.0).reshape(3, 3), np.stack([np.eye(3)] * 3))
    team = team_id("own")
    back = decode(encode(MapIdsMessage(2, 0, 7, ids, None, summary), team), team, 3)
    np.testing.assert_array_equal(back.summary.means, summary.means)
    np.testing.assert_array_equal(back.summary.covs, summary.covs)
    assert back.summary.robot == 2 and back.summary.classes is None
    np.testing.assert_array_equal(back.summary.views, np.zeros((3, 3)))  # none known
    # where the cameras were: float32 on the wire, the sender's own summary rounded alike
    seen = replace(summary, views=np.array([[0.1, 0.2, 0.97], [0.0, 0.0, 0.0], [1 / 3, 0, 0]]))
    assert seen.views[2, 0] == np.float32(1 / 3)
    back = decode(encode(MapIdsMessage(2, 0, 7, ids, None, seen), team), team, 3)
    np.testing.assert_array_equal(back.summary.views, seen.views)
    data = bytearray(encode(MapIdsMessage(2, 0, 7, ids, None, seen), team))
    at = len(data) - 3 * 3 * 4  # the first view's x, float32
    data[at : at + 4] = np.float32(np.nan).tobytes()
    with pytest.raises(WireError, match="non-finite camera positions"):
        decode(bytes(data), team, 3)
    with_classes = replace(summary, classes=np.array([1, 2, 1]))
    back = decode(encode(MapIdsMessage(2, 0, 7, ids, None, with_classes), team), team, 3)
    np.testing.assert_array_equal(back.summary.classes, [1, 2, 1])
    assert (
        len(encode(MapIdsMessage(2, 0, 7, ids, None, summary), team))
        == MapIdsMessage(2, 0, 7, ids, None, summary).nbytes()
    )


def test_the_report_shows_the_association_of_a_run():
    from types import SimpleNamespace

    from teamslam.eval.report import _association_section

    team = {
        "proposed": 12,
        "accepted": 10,
        "revoked": 2,
        "held": 8,
        "excluded": 3,
        "correct": 7,
        "wrong": 1,
        "shared": 9,
        "precision": 0.875,
        "recall": 7 / 9,
        "summary_bytes_per_robot_step": 1234.0,
        "association_time_share": 0.125,
    }
    link = {"held": 8, "revoked": 2, "precision": 0.875, "recall": 7 / 9}
    runs = [
        SimpleNamespace(metrics={"association": {"team": team, "links": {"0-1": link}}}),
        SimpleNamespace(metrics={}),
    ]
    html = _association_section(["own", "oracle"], runs)
    assert "<h2>Association</h2>" in html
    for text in ("12 | 10 | 2", "7 | 1", "0.875", "0.778", "1234", "12.5%", "link 0-1"):
        assert text in html
    assert _association_section(["oracle"], [SimpleNamespace(metrics={})]) == ""


def test_a_summary_says_from_where_the_robot_saw_each_object(stripped3):
    # the views the robot records (the measured bearing turned by the camera's estimated
    # orientation) and its summary carries point from each object to the cameras that saw it,
    # as ground truth has them
    config = config_for(stripped3, {"filter.window": 6}).with_({"association.mode": "own"})
    drivers = _drivers(stripped3, config, MemoryNetwork(3))
    run_drivers(drivers, "complete", 0.0, None, progress=False)
    truth = dict(zip(stripped3.object_ids.tolist(), stripped3.object_positions, strict=True))
    t_body_cam = np.linalg.inv(stripped3.calibration.T_cam_body)
    for robot, driver in enumerate(drivers):
        sequence = stripped3.robots[robot]
        ids = driver.protocol.agent.views.ids
        views = driver.protocol.agent.views.of(ids)
        assert ids.size >= 20 and np.all(np.linalg.norm(views, axis=1) <= 1.0 + 1e-6)
        for oid, view in zip(ids.tolist(), views, strict=True):
            toward = []
            for t in range(sequence.frames):
                if oid in sequence.objects.frame(t)[0].tolist():
                    pose = sequence.T_world_body[t]
                    camera = pose[:3, :3] @ t_body_cam[:3, 3] + pose[:3, 3]
                    toward.append((camera - truth[oid]) / np.linalg.norm(camera - truth[oid]))
            expected = np.mean(toward, axis=0)
            cosine = view @ expected / np.linalg.norm(view) / np.linalg.norm(expected)
            assert cosine > 0.99, (robot, oid, cosine)


def test_the_team_matcher_tests_pairs_in_the_shared_frame_unless_set_off():
    from teamslam.msckf.settings.sources import parse_assignments
    from teamslam.msckf.settings.values import MsckfConfig

    team = MsckfConfig.from_settings({}).association
    assert team.matching().frame_probability == team.revoke_probability
    off = MsckfConfig.from_settings(parse_assignments(["association.frame_probability=null"]))
    assert off.association.matching().frame_probability is None
    with pytest.raises(InputError, match="frame_probability"):
        MsckfConfig.from_settings({"association.frame_probability": 1.5})


def _recording(monkeypatch):
    """Record, per (robot, neighbour), each step's map ids and summary sent, and each pair a
    table took with the step it took it at."""
    from teamslam.association import CorrespondenceTable

    sent, taken = {}, {}
    requests = ConsensusProtocol._requests

    def recorded_requests(self, to):
        out = requests(self, to)
        for m in out:
            summary = None if m.summary is None else m.summary.ids.copy()
            sent.setdefault((m.sender, m.receiver), []).append((self.step, m.ids.copy(), summary))
        return out

    def recorder(method):
        def recorded(self, *args):
            added = method(self, *args)
            step = args[-1]
            for a, b in added:
                taken.setdefault((self.own, self.neighbour), []).append((step, int(a), int(b)))
            return added

        return recorded

    monkeypatch.setattr(ConsensusProtocol, "_requests", recorded_requests)
    for name in ("extend", "merge"):
        method = getattr(CorrespondenceTable, name)
        monkeypatch.setattr(CorrespondenceTable, name, recorder(method))
    return sent, taken


def test_a_link_pairs_new_objects_before_the_interval_and_both_ends_agree(
    stripped3, team3, monkeypatch
):
    """``association.sooner``: objects new to a link are summarised at the next step, not at
    the next interval tick; both ends take the same pairs at the same step."""
    config = config_for(team3, {"filter.window": 6}).with_(
        {"association.mode": "own", "association.interval": 5}
    )
    assert config.association.sooner == 1  # on by default
    sent, taken = _recording(monkeypatch)
    result = run_team(stripped3, config, progress=False)
    metrics = team_metrics(stripped3, result)["association"]
    assert metrics["team"]["precision"] == 1.0
    assert all(link["ends_agree"] for link in metrics["links"].values())
    # pairs taken between two ticks of the interval, the same at both ends, at the same step
    between = {k: {(s, a, b) for s, a, b in v if s % 5} for k, v in taken.items()}
    assert sum(len(v) for v in between.values()) > 0
    for (i, j), pairs in between.items():
        assert pairs == {(s, b, a) for s, a, b in between.get((j, i), set())}
    # a summary between the ticks holds exactly the ids the link did not hold yet, and none
    # goes out when there are none
    extra = 0
    for records in sent.values():
        known = np.zeros(0, np.int64)
        for step, ids, summary in records:
            fresh = np.setdiff1d(ids, known)
            if step % 5 == 0:
                np.testing.assert_array_equal(summary, ids)  # the whole map
                known = ids
            elif fresh.size == 0:
                assert summary is None
            else:
                np.testing.assert_array_equal(summary, fresh)
                known = np.union1d(known, fresh)
                extra += 1
    assert extra > 0


def test_summaries_only_at_the_interval_with_sooner_off(stripped3, team3, monkeypatch):
    config = config_for(team3, {"filter.window": 6}).with_(
        {"association.mode": "own", "association.interval": 5, "association.sooner": 0}
    )
    sent, taken = _recording(monkeypatch)
    run_team(stripped3, config, progress=False)
    assert all(
        (summary is not None) == (step % 5 == 0)
        for records in sent.values()
        for step, _, summary in records
    )
    assert all(s % 5 == 0 for pairs in taken.values() for s, _, _ in pairs)
    with pytest.raises(InputError, match=r"association\.sooner must be an integer"):
        MsckfConfig.from_settings({"association.sooner": -1})


def test_a_summary_of_some_ids_crosses_the_wire():
    from teamslam.association import ObjectSummary
    from teamslam.msckf.consensus.messages import summary_wire_bytes

    ids = np.array([3, 9, 40, 41, 50, 77, 80, 90, 91])
    some = ObjectSummary(
        2,
        ids[[1, 4, 8]],
        np.arange(9.0).reshape(3, 3),
        np.stack([np.eye(3)] * 3),
        appearance=np.eye(3, 4),
    )
    team = team_id("own")
    message = MapIdsMessage(2, 0, 7, ids, None, some)
    data = encode(message, team)
    assert len(data) == message.nbytes()
    assert summary_wire_bytes(some, ids.size) == summary_wire_bytes(some) + 2  # the bit mask
    back = decode(data, team, 3)
    np.testing.assert_array_equal(back.ids, ids)
    np.testing.assert_array_equal(back.summary.ids, some.ids)
    np.testing.assert_array_equal(back.summary.means, some.means)
    np.testing.assert_array_equal(back.summary.appearance, some.appearance)
    with pytest.raises(WireError, match=r"length|truncated"):
        decode(data[:-1], team, 3)
    # a link's map after it: the earlier objects with the new ones, ids increasing
    earlier = ObjectSummary(
        2, ids[[0, 1]], np.ones((2, 3)), np.stack([2 * np.eye(3)] * 2), appearance=np.ones((2, 4))
    )
    both = earlier.updated(some)
    np.testing.assert_array_equal(both.ids, [3, 9, 50, 91])
    np.testing.assert_array_equal(both.means[1], some.means[0])  # 9: the newer estimate
    np.testing.assert_array_equal(both.means[0], earlier.means[0])
