"""Objects leave the filter state for a persistent map and come back: exact, bounded, resumable."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import block_diag

from teamslam.errors import InputError, InternalError
from teamslam.msckf import MsckfConfig, config_for
from teamslam.msckf.agent import MsckfAgent
from teamslam.msckf.filter.persistent_map import PersistentMap
from teamslam.msckf.filter.state import MsckfState
from teamslam.sim import lissajous_team, long_route_team


def _random_state(n_poses: int, n_objects: int, seed: int = 0) -> MsckfState:
    rng = np.random.default_rng(seed)
    dim = 6 * n_poses + 3 * n_objects
    a = rng.standard_normal((dim, dim))
    ids = rng.permutation(1000)[:n_objects].astype(np.int64)
    objects = rng.standard_normal((n_objects, 3))
    return MsckfState.from_arrays(
        np.tile(np.eye(4), (n_poses, 1, 1)),
        np.arange(n_poses),
        ids,
        objects,
        a @ a.T / dim + np.eye(dim),
        object_fe=objects + 0.1,
        object_last_seen=np.zeros(n_objects, dtype=np.int64),
    )


def test_retirement_and_reentry_keep_the_marginals_exactly():
    state = _random_state(4, 7)
    before = state.snapshot()
    cov0, ids0 = before["cov"], before["object_ids"]
    gone = np.array([1, 4, 5])
    state.retire_objects(gone)
    # the remaining state's marginal: the same rows and columns of the joint covariance
    keep = np.ones(cov0.shape[0], dtype=bool)
    keep[state.object_columns(gone).ravel() + 0] = False
    np.testing.assert_array_equal(state.cov, cov0[np.ix_(keep, keep)])
    np.testing.assert_array_equal(state.object_ids, np.delete(ids0, gone))
    np.testing.assert_array_equal(state.objects, np.delete(before["objects"], gone, axis=0))
    assert len(state.retired) == 3 and state.n_objects == 4
    # the stored marginal is the in-state one
    means, covs, fe = state.retired.get(ids0[gone])
    cols = 24 + 3 * gone[:, None] + np.arange(3)
    np.testing.assert_array_equal(means, before["objects"][gone])
    np.testing.assert_array_equal(covs, cov0[cols[:, :, None], cols[:, None, :]])
    np.testing.assert_array_equal(fe, before["object_fe"][gone])

    # the map keeps every number of the joint: theirs, and with the state that stays
    stored = state.retired.consider_arrays()
    order = np.searchsorted(ids0[gone], stored["consider_ids"], sorter=np.argsort(ids0[gone]))
    coords = cols[np.argsort(ids0[gone])[order]].ravel()
    np.testing.assert_array_equal(stored["joint"], cov0[np.ix_(coords, coords)])
    np.testing.assert_array_equal(stored["cross"], cov0[np.ix_(coords, np.flatnonzero(keep))])

    # one comes back: with its covariance with the state and with the objects still retired
    state.reenter_objects(ids0[gone[1:2]], frame=9)
    assert len(state.retired) == 2 and state.n_objects == 5
    slot = state.object_slots(ids0[gone[1:2]])[0]
    np.testing.assert_array_equal(state.objects[slot], before["objects"][gone[1]])
    np.testing.assert_array_equal(state.object_fe[slot], before["object_fe"][gone[1]])
    assert state.object_last_seen[slot] == 9
    # every other one too: the joint is the one before retirement, in the new order, exactly
    state.reenter_objects(ids0[gone[[2, 0]]], frame=9)
    assert len(state.retired) == 0
    old_slot = {int(i): k for k, i in enumerate(ids0)}
    order = np.array([old_slot[int(i)] for i in state.object_ids])
    perm = np.concatenate([np.arange(24), (24 + 3 * order[:, None] + np.arange(3)).ravel()])
    np.testing.assert_array_equal(state.cov, cov0[np.ix_(perm, perm)])
    np.testing.assert_array_equal(state.objects, before["objects"][order])


@pytest.mark.parametrize("form", ["joint", "per_object", "information"])
def test_a_late_marginal_naming_retired_objects_is_marginalised_to_the_state(form):
    """Asynchronous exchanges can deliver a marginal older than a retirement."""
    from teamslam.msckf.consensus import receive_marginal
    from teamslam.msckf.consensus.messages import CommonMarginalMessage

    state = _random_state(2, 5, seed=3)
    ids = np.sort(state.object_ids)
    rng = np.random.default_rng(4)
    a = rng.standard_normal((15, 15))
    cov = a @ a.T / 15 + np.eye(15)
    mean = rng.standard_normal(15)
    per_object = form == "per_object"
    if per_object:
        cov = np.stack([cov[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] for i in range(5)])
    if form == "information":  # marginalising in information form is not taking a sub-block
        message = CommonMarginalMessage(7, 0, 3, ids, mean, None, 1, info=np.linalg.inv(cov))
    else:
        message = CommonMarginalMessage(7, 0, 3, ids, mean, cov, 1)
    state.retire_objects(state.object_slots(ids[[1, 3]]))
    problem, marginal = receive_marginal(state, message)
    assert problem is None
    keep = np.array([0, 2, 4])
    np.testing.assert_array_equal(marginal.ids, ids[keep])
    coords = (3 * keep[:, None] + np.arange(3)).ravel()
    sub = block_diag(*cov[keep]) if per_object else cov[np.ix_(coords, coords)]
    np.testing.assert_allclose(np.linalg.inv(marginal.info), sub, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(marginal.info @ mean[coords], marginal.info_vector, rtol=1e-12)
    # only retired objects: nothing to average; an id never held: unusable
    state.retire_objects(state.object_slots(ids[[0, 2, 4]]))
    assert "retired" in receive_marginal(state, message)[0]
    other = CommonMarginalMessage(
        7, 0, 3, np.append(ids[:4], 5000), mean, message.cov, 1, info=message.info
    )
    assert receive_marginal(state, other)[0] == "ids not in this robot's map"


def test_the_persistent_map_reuses_rows_and_grows_by_doubling():
    store = PersistentMap(capacity=2)
    rng = np.random.default_rng(1)
    covs = np.tile(np.eye(3), (5, 1, 1))
    store.store(np.arange(5), rng.standard_normal((5, 3)), covs, np.zeros((5, 3)))
    assert len(store) == 5 and store.capacity == 8
    store.take(np.array([0, 3]))
    store.store(np.array([10, 11]), np.ones((2, 3)), covs[:2], np.ones((2, 3)))
    assert store.capacity == 8  # freed rows reused
    np.testing.assert_array_equal(store.contains(np.array([0, 1, 10, 99])), [0, 1, 1, 0])
    np.testing.assert_array_equal(store.arrays()["ids"], [1, 2, 4, 10, 11])
    with pytest.raises(InternalError, match="not in the persistent map"):
        store.take(np.array([3]))


@pytest.fixture(scope="module")
def long_route():
    return long_route_team(robots=1, steps=160, seed=2)


def test_retirement_bounds_the_state_on_a_long_route(long_route):
    """Every object in the state was seen within the last N frames; none is lost."""
    retire = 8
    config = config_for(long_route, {"filter.window": 6, "objects.retire_after": retire})
    agent = MsckfAgent(0, long_route.calibration, long_route.robots[0], config)
    seen_by = {}
    in_state = []
    for t in range(long_route.robots[0].frames):
        agent.step(t)
        state = agent.state
        assert np.all(t - state.object_last_seen < retire)
        # no more objects in the state than were observed over the last N frames
        recent = set()
        for k in range(max(0, t - retire + 1), t + 1):
            recent.update(long_route.robots[0].objects.frame(k)[0].tolist())
        assert set(state.object_ids.tolist()) <= recent
        seen_by[t] = len(state.retired)
        in_state.append(state.n_objects)
    counters = agent.counters
    assert counters["objects_retired"] > 50
    # every object initialised is in the state or in the persistent map
    assert counters["objects_initialised"] == agent.state.n_objects + len(agent.state.retired)
    assert max(in_state[80:]) <= 2 * max(in_state[:80])
    ids, means, covs = agent.state.full_map()
    assert ids.size == agent.state.n_objects + len(agent.state.retired)
    assert np.all(np.diff(ids) > 0)
    stored = agent.state.retired.arrays()
    pos = np.searchsorted(ids, stored["ids"])
    np.testing.assert_array_equal(means[pos], stored["means"])
    np.testing.assert_array_equal(covs[pos], stored["covs"])


def test_retired_objects_re_enter_when_observed_again():
    """The Lissajous arena revisits objects: they come back with the estimate they left with."""
    dataset = lissajous_team(robots=1, steps=120, seed=3)
    config = config_for(dataset, {"filter.window": 6, "objects.retire_after": 4})
    agent = MsckfAgent(0, dataset.calibration, dataset.robots[0], config)
    state = agent.state
    reenter = state.reenter_objects
    checked = []

    def spy(ids, frame):
        means, covs, _ = state.retired.get(ids)
        reenter(ids, frame)
        slots = state.object_slots(ids)
        np.testing.assert_array_equal(state.objects[slots], means)
        np.testing.assert_array_equal(state.object_covs()[slots], covs)
        observed = dataset.robots[0].objects.frame(frame)[0]
        assert np.isin(ids, observed).all() and frame == agent.frame + 1
        checked.append(ids.size)

    state.reenter_objects = spy
    for t in range(dataset.robots[0].frames):
        agent.step(t)
    assert sum(checked) == agent.counters["objects_reentered"] > 0
    assert agent.counters["objects_retired"] > 0


def _team_run(dataset, retire):
    from teamslam.msckf import run_team

    return run_team(
        dataset, config_for(dataset, {"filter.window": 6, "objects.retire_after": retire})
    )


def test_retirement_that_never_triggers_changes_nothing():
    """``objects.retire_after`` longer than the run gives bit-for-bit the run without it."""
    dataset = lissajous_team(robots=2, steps=25, seed=5)
    off, never = _team_run(dataset, 0), _team_run(dataset, 10_000)
    for a, b in zip(off.poses, never.poses, strict=True):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(off.objects, never.objects, strict=True):
        np.testing.assert_array_equal(a, b)
    assert "objects_retired" not in off.counters[0]


def test_snapshot_carries_the_persistent_map(long_route):
    config = config_for(long_route, {"filter.window": 6, "objects.retire_after": 5})
    sequence = long_route.robots[0]
    original = MsckfAgent(0, long_route.calibration, sequence, config)
    for t in range(60):
        original.step(t)
    assert len(original.state.retired) > 0
    assert np.any(original.state.retired.cross != 0)  # consider states: correlated with the state
    snapshot = original.snapshot()
    assert all(isinstance(v, np.ndarray) and v.dtype != object for v in snapshot.values())
    resumed = MsckfAgent(0, long_route.calibration, sequence, config)
    resumed.restore({k: v.copy() for k, v in snapshot.items()})
    for name, value in original.state.retired.arrays().items():
        np.testing.assert_array_equal(resumed.state.retired.arrays()[name], value)
    np.testing.assert_array_equal(resumed.state.object_last_seen, original.state.object_last_seen)
    for t in range(60, 90):
        original.step(t)
        resumed.step(t)
    np.testing.assert_array_equal(resumed.state.poses, original.state.poses)
    np.testing.assert_array_equal(resumed.state.cov, original.state.cov)
    for name, value in original.state.retired.arrays().items():
        np.testing.assert_array_equal(resumed.state.retired.arrays()[name], value)

    # a corrupt persistent map is refused and leaves the agent as it was
    bad = dict(snapshot)
    bad["state_retired_covs"] = -bad["state_retired_covs"]
    before = resumed.state.snapshot()
    with pytest.raises(InputError, match="persistent map"):
        resumed.restore(bad)
    for k, v in resumed.state.snapshot().items():
        np.testing.assert_array_equal(v, before[k])


@pytest.mark.parametrize("value", [-1, -100, 2.5, True, "10"])
def test_bad_retirement_settings_are_refused(value):
    with pytest.raises(InputError, match=r"objects\.retire_after"):
        MsckfConfig.from_settings({"objects.retire_after": value})


def test_the_long_route_keeps_discovering_objects():
    team = long_route_team(robots=2, steps=120, seed=1)
    again = long_route_team(robots=2, steps=120, seed=1)
    np.testing.assert_array_equal(team.object_positions, again.object_positions)
    robot = team.robots[0]
    early = np.unique(np.concatenate([robot.objects.frame(k)[0] for k in range(20)]))
    late = np.unique(np.concatenate([robot.objects.frame(k)[0] for k in range(100, 121)]))
    assert early.size > 10 and late.size > 10
    assert np.intersect1d(early, late).size == 0  # left behind, never seen again
    # the two robots share what they see
    other = np.unique(np.concatenate([team.robots[1].objects.frame(k)[0] for k in range(20)]))
    assert np.intersect1d(early, other).size > 5
    # about 1.2 objects per metre of route: ≥ 5,000 objects on a 5,000-step route
    assert team.metadata["simulation"]["objects"] == len(team.object_positions)
    route = team.robots[0].T_world_body[:, :3, 3]
    assert len(team.object_positions) >= 1.2 * np.linalg.norm(np.diff(route, axis=0), axis=1).sum()


def test_simulate_a_long_route_from_the_command_line(tmp_path, capsys):
    import json

    from teamslam.cli import main
    from teamslam.datasets import load_dataset

    out = tmp_path / "long"
    argv = ["simulate", "--route", "long", "--robots", "2", "--steps", "40", "--out", str(out)]
    assert main(argv) == 0
    capsys.readouterr()
    assert main(["data", "info", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["frames_per_robot"] == [41, 41]
    assert info["objects_observed"] >= info["objects_shared"] > 0
    expected = long_route_team(robots=2, steps=40)
    np.testing.assert_array_equal(load_dataset(out).object_positions, expected.object_positions)
    assert main([*argv[:-1], str(tmp_path / "x"), "--objects", "5"]) != 0
    assert "--objects" in capsys.readouterr().err


def test_max_active_bounds_the_state_by_size():
    """``objects.max_active``: the state never holds more objects than the bound plus those
    observed in the frame; the least recently observed leave first, re-enter when seen again,
    and no object is lost."""
    dataset = lissajous_team(robots=1, steps=120, seed=3)
    bound = 12
    config = config_for(dataset, {"filter.window": 6, "objects.max_active": bound})
    agent = MsckfAgent(0, dataset.calibration, dataset.robots[0], config)
    last_seen: dict[int, int] = {}
    for t in range(dataset.robots[0].frames):
        before = set(agent.state.retired.arrays()["ids"].tolist())
        agent.step(t)
        state = agent.state
        now = state.object_last_seen == t
        assert state.n_objects <= max(bound, int(now.sum()))
        retired = set(state.retired.arrays()["ids"].tolist()) - before
        kept = state.object_last_seen[~now]
        if retired and kept.size:
            # the objects retired this frame were seen no later than any unobserved one kept
            assert max(last_seen[i] for i in retired) <= kept.min()
        last_seen.update(
            zip(state.object_ids.tolist(), state.object_last_seen.tolist(), strict=True)
        )
    counters = agent.counters
    assert counters["objects_retired"] > 0 and counters["objects_reentered"] > 0
    assert counters["objects_initialised"] == agent.state.n_objects + len(agent.state.retired)
    with pytest.raises(InputError, match="max_active"):
        config_for(dataset, {"objects.max_active": -1})


def test_the_budget_learned_from_the_data_follows_the_objects_seen_per_window():
    """``objects.active_windows = k``: the budget is ``k`` times the most objects of the state
    observed within one window so far — it grows while the robot meets more objects per
    window, never shrinks, and bounds the state as ``max_active`` does; with both set the
    smaller bound holds; a snapshot carries it."""
    dataset = lissajous_team(robots=1, steps=120, seed=3)
    window, k = 6, 1
    config = config_for(dataset, {"filter.window": window, "objects.active_windows": k})
    agent = MsckfAgent(0, dataset.calibration, dataset.robots[0], config)
    peak, budgets = 0, []
    for t in range(dataset.robots[0].frames):
        agent.step(t)
        state = agent.state
        now = state.object_last_seen == t
        # an object observed within the window is never retired by a budget of k ≥ 1 times
        # their most: they are all in the state now
        peak = max(peak, int(np.sum(state.object_last_seen > t - window)))
        assert agent.window_objects_peak == peak
        budget = agent.active_budget(t)
        assert budget == k * peak
        budgets.append(budget)
        assert state.n_objects <= max(budget, int(now.sum()))
    assert np.all(np.diff(budgets) >= 0) and budgets[-1] > budgets[0]
    assert agent.counters["objects_retired"] > 0
    # a snapshot carries the learned peak: a restored robot keeps the same budget
    again = MsckfAgent(0, dataset.calibration, dataset.robots[0], config)
    again.restore(agent.snapshot())
    assert again.window_objects_peak == agent.window_objects_peak > 0
    # with a fixed budget too: the smaller one holds
    both = config_for(
        dataset,
        {"filter.window": window, "objects.active_windows": k, "objects.max_active": 5},
    )
    agent = MsckfAgent(0, dataset.calibration, dataset.robots[0], both)
    for t in range(dataset.robots[0].frames):
        agent.step(t)
        assert agent.active_budget(t) == min(5, k * agent.window_objects_peak) or (
            agent.window_objects_peak == 0
        )
    with pytest.raises(InputError, match="active_windows"):
        config_for(dataset, {"objects.active_windows": -1})


# ---------------------------------------------------------------- the persistent map in consensus


def _spd(rng, k: int) -> np.ndarray:
    a = rng.standard_normal((k, 3, 3))
    return a @ np.swapaxes(a, 1, 2) + 0.5 * np.eye(3)


def test_persistent_average_is_eq_19_object_by_object():
    """Each retired object: Ω ← Ω_i + Σ_j A_ij (Ω_j − Ω_i) over the neighbours that sent it,
    η likewise; an object nobody sent and its first estimate stay as they were."""
    from teamslam.msckf.consensus.average import persistent_average

    rng = np.random.default_rng(4)
    ids = np.array([3, 8, 11, 20])
    means, covs, fe = rng.standard_normal((4, 3)), _spd(rng, 4), rng.standard_normal((4, 3))
    state = _random_state(1, 0)
    state.retired.store(ids, means, covs, fe)
    stored = state.retired
    sent = {1: np.array([3, 11]), 2: np.array([11, 20])}
    weights = {1: 0.25, 2: 0.3}
    theirs = {j: (_spd(rng, s.size), rng.standard_normal((s.size, 3))) for j, s in sent.items()}
    received = []
    for j, s in sent.items():
        cov, mean = theirs[j]
        info = np.linalg.inv(cov)
        received.append((weights[j], (s, info, np.einsum("kij,kj->ki", info, mean))))
    assert persistent_average(state, received) == 3
    for k, i in enumerate(ids):
        own_info = np.linalg.inv(covs[k])
        info, vector = own_info.copy(), own_info @ means[k]
        for j, s in sent.items():
            if i in s:
                cov, mean = theirs[j][0][s == i][0], theirs[j][1][s == i][0]
                info += weights[j] * (np.linalg.inv(cov) - own_info)
                vector += weights[j] * (np.linalg.inv(cov) @ mean - own_info @ means[k])
        mean, cov, first = stored.get(np.array([i]))
        np.testing.assert_allclose(cov[0], np.linalg.inv(info), rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(mean[0], np.linalg.solve(info, vector), rtol=1e-10, atol=1e-12)
        np.testing.assert_array_equal(first[0], fe[k])
    assert persistent_average(state, [(0.5, None)]) == 0


def test_a_neighbours_marginal_of_objects_we_retired_is_kept_apart_per_object():
    """A receiver holding some of a marginal's objects in its persistent map gets each one's
    own marginal apart (information form) and the rest as before; without the persistent map
    in consensus they are dropped."""
    from teamslam.msckf.consensus.checks import receive_marginal
    from teamslam.msckf.consensus.marginals import common_marginal_message

    sender = _random_state(3, 6, seed=1)
    asked = np.sort(sender.object_ids)
    receiver = MsckfState.from_arrays(
        np.tile(np.eye(4), (2, 1, 1)),
        np.arange(2),
        asked,
        np.zeros((asked.size, 3)),
        np.eye(12 + 3 * asked.size),
        object_last_seen=np.zeros(asked.size, dtype=np.int64),
    )
    receiver.retire_objects(np.array([0, 3, 4]))
    away = receiver.retired.contains(asked)
    index = 3 * np.arange(asked.size)[:, None] + np.arange(3)
    for per_object in (False, True):
        message = common_marginal_message(
            sender, 0, 1, 7, asked, per_object=per_object, information=not per_object
        )
        cov = sender.covariance(sender.object(sender.object_slots(asked)).columns.ravel())
        blocks = cov[index[:, :, None], index[:, None, :]]
        problem, marginal = receive_marginal(receiver, message, persistent=True)
        assert problem is None
        np.testing.assert_array_equal(marginal.ids, asked[~away])
        r_ids, r_info, r_vector = marginal.retired
        np.testing.assert_array_equal(r_ids, asked[away])
        np.testing.assert_allclose(np.linalg.inv(r_info), blocks[away], rtol=1e-8, atol=1e-12)
        means = sender.objects[sender.object_slots(asked)]
        np.testing.assert_allclose(
            np.linalg.solve(r_info, r_vector[..., None])[..., 0], means[away], rtol=1e-8
        )
        # the objects still in the state: the marginal of those, as without the persistent map
        problem, plain = receive_marginal(receiver, message)
        assert problem is None and plain.retired is None
        np.testing.assert_array_equal(plain.ids, asked[~away])
        np.testing.assert_array_equal(plain.info, marginal.info)
        np.testing.assert_array_equal(plain.info_vector, marginal.info_vector)
    # a marginal of retired objects only: kept apart whole; without: refused
    only = common_marginal_message(sender, 0, 1, 7, asked[away], information=True)
    problem, marginal = receive_marginal(receiver, only, persistent=True)
    assert problem is None and marginal.ids.size == 0 and marginal.retired[0].size == away.sum()
    problem, _ = receive_marginal(receiver, only)
    assert "retired" in problem


def _budget_team(persistent: bool):
    from teamslam.eval.metrics import team_metrics
    from teamslam.msckf import run_team
    from teamslam.msckf.consensus.protocol import ConsensusProtocol

    dataset = lissajous_team(robots=3, steps=60, seed=2)
    config = config_for(
        dataset,
        {
            "filter.window": 6,
            "objects.max_active": 20,
            "consensus.persistent_map": persistent,
        },
    )
    sent_retired = []
    answer = ConsensusProtocol._answer

    def checked(protocol, received):
        replies = answer(protocol, received)
        for reply in replies:  # what is sent: objects of the state only
            sent_retired.append(int(protocol.agent.state.retired.contains(reply.ids).sum()))
        return replies

    ConsensusProtocol._answer = checked
    try:
        result = run_team(dataset, config, progress=False)
    finally:
        ConsensusProtocol._answer = answer
    assert sent_retired and not any(sent_retired)
    return result, team_metrics(dataset, result)


def test_the_persistent_map_in_consensus_keeps_a_budget_accurate():
    """With a budget, retired objects averaged with the neighbours' in-state marginals: the
    robots' maps agree better and are closer to the truth than when retired objects wait for
    re-entry; a robot never sends an object it holds retired."""
    on, with_map = _budget_team(True)
    off, without = _budget_team(False)
    assert all(c["objects_retired"] > 0 for c in on.counters)
    assert sum(c.get("retired_averaged", 0) for c in on.counters) > 0
    assert all("retired_averaged" not in c for c in off.counters)
    for a, b in zip(on.object_ids, off.object_ids, strict=True):
        np.testing.assert_array_equal(a, b)  # the same objects mapped, in state or retired
    assert with_map["object_error_avg_m"] < without["object_error_avg_m"]
    assert with_map["object_disagreement_avg_m"] < without["object_disagreement_avg_m"]


@pytest.mark.parametrize("value", [2, "yes", None])
def test_a_bad_persistent_map_consensus_setting_is_refused(value):
    with pytest.raises(InputError, match=r"consensus\.persistent_map"):
        MsckfConfig.from_settings({"consensus.persistent_map": value})


def test_a_listening_robot_asks_for_a_retired_object_again_only_once_it_moved():
    """Retired objects are flagged in round 1 as the state's are: a neighbour's marginal of one,
    once averaged in, goes on record with that neighbour (our marginal before the average), and
    the object is asked for again only when its stored marginal moved beyond
    ``consensus.kl_threshold`` since (the neighbour flags its own side)."""
    from teamslam.gaussian import kl_divergence
    from teamslam.msckf import run_team
    from teamslam.msckf.consensus.protocol import ConsensusProtocol

    dataset = lissajous_team(robots=3, steps=60, seed=2)
    config = config_for(
        dataset,
        {"filter.window": 6, "objects.max_active": 20, "consensus.persistent_map": True},
    )
    threshold = config.consensus.kl_threshold
    counts = {"recorded": 0, "asked_again": 0, "not_asked": 0}
    requests, average = ConsensusProtocol._requests, ConsensusProtocol._average

    def flags(protocol, to):
        out = requests(protocol, to)
        stored = protocol.agent.state.retired
        for message in out:
            record = protocol._agreed.get(message.receiver)
            if record is None:
                continue
            on_record = stored.contains(message.ids) & np.isin(message.ids, record[0])
            ids = message.ids[on_record]
            pos = np.searchsorted(record[0], ids)
            means, covs, _ = stored.get(ids)
            kl = kl_divergence(means, covs, record[1][pos], record[2][pos])
            asked = np.asarray(message.moved, dtype=bool)[on_record]
            np.testing.assert_array_equal(asked, kl > threshold)
            counts["asked_again"] += int(asked.sum())
            counts["not_asked"] += int((~asked).sum())
        return out

    def averaged(protocol, received):
        before = protocol._own
        got = {m.sender: m.ids for m in received}
        out = average(protocol, received)
        for j, ids in got.items():
            ids = np.asarray(ids)[protocol.agent.state.retired.contains(ids)]
            record = protocol._agreed.get(j)
            if ids.size == 0 or j not in protocol.averaged_with:
                continue
            # each retired object the neighbour sent is on record: our marginal before the average
            assert record is not None and np.isin(ids, record[0]).all()
            mine = np.searchsorted(before[0], ids)
            pos = np.searchsorted(record[0], ids)
            np.testing.assert_array_equal(record[1][pos], before[1][mine])
            np.testing.assert_array_equal(record[2][pos], before[2][mine])
            counts["recorded"] += ids.size
        return out

    ConsensusProtocol._requests, ConsensusProtocol._average = flags, averaged
    try:
        result = run_team(dataset, config, progress=False)
    finally:
        ConsensusProtocol._requests, ConsensusProtocol._average = requests, average
    assert sum(c.get("retired_averaged", 0) for c in result.counters) > 0
    assert counts["recorded"] > 0
    # retired objects on record that did not move are not asked for again
    assert counts["not_asked"] > 0 and counts["asked_again"] > 0
