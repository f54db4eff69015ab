"""Re-anchoring (``objects.reanchor_probability``): a `fej` object whose first estimate its data
rule out is marginalised out and enters again from later observations, at a fresh first estimate,
keeping the rigid motions of the world unobservable and using no observation twice."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import scipy.linalg

from teamslam.errors import InputError
from teamslam.gaussian import chi2_quantile
from teamslam.geometry import se3
from teamslam.msckf import config_for
from teamslam.msckf.agent import MsckfAgent
from teamslam.msckf.filter.linearization import first_estimate_distance
from teamslam.msckf.filter.observability import NullspaceAudit
from teamslam.msckf.filter.state import MsckfState
from teamslam.msckf.settings.values import MsckfConfig
from teamslam.msckf.team import run_team
from teamslam.sim import long_route_team


def _random_cov(rng: np.random.Generator, n: int) -> np.ndarray:
    a = rng.normal(size=(n, n))
    return a @ a.T + 0.1 * np.eye(n)


def test_the_first_estimate_distance_is_the_mahalanobis_distance_and_chi2():
    """Against the textbook formula (explicit inverses, in the test only), and χ²(3) in
    distribution: first estimates drawn from the object's distribution give a mean of 3 and
    exceed the 0.99 quantile about 1 % of the time."""
    rng = np.random.default_rng(0)
    k = 4000
    cov = np.repeat(np.stack([_random_cov(rng, 3) for _ in range(5)]), k // 5, axis=0)
    current = rng.normal(size=(k, 3))
    first = current + (np.linalg.cholesky(cov) @ rng.normal(size=(k, 3, 1)))[..., 0]
    got = first_estimate_distance(current, first, cov)
    d = current - first
    want = np.einsum("ki,kij,kj->k", d, np.linalg.inv(cov), d)
    np.testing.assert_allclose(got, want, rtol=1e-9)
    assert abs(got.mean() - 3.0) < 0.2
    assert abs((got > chi2_quantile(0.99, 3)).mean() - 0.01) < 0.006


def _state_with_objects() -> MsckfState:
    state = MsckfState(np.eye(4), 0, 1e-2 * np.eye(6))
    rng = np.random.default_rng(3)
    for t in range(1, 4):
        state.augment(se3.exp(0.1 * rng.normal(size=6)), t, 1e-3 * np.eye(6))
    for oid in (40, 41, 42):
        gain = 0.1 * rng.normal(size=(3, state.dim))
        cov_ps = gain @ state.cov
        cov_pp = gain @ state.cov @ gain.T + 0.01 * np.eye(3)
        cols = np.arange(state.dim)
        state.add_object(oid, rng.normal(size=3), cov_pp, cov_ps, from_columns=(gain, cols))
    return state


def test_marginalising_objects_keeps_the_rest_exactly_and_the_map_whole():
    """The state without the objects is the marginal of the one with them; the map still lists
    them with their marginals as they left, until one enters again; a snapshot keeps them."""
    state = _state_with_objects()
    assert not any(k.startswith("dropped_") for k in state.snapshot())  # as before
    cov = state.cov.copy()
    covs = state.object_covs()
    before_ids, before_means, before_covs = state.full_map()
    state.marginalize_objects(np.array([1]))
    keep = np.r_[0:24, 24:27, 30:33]
    np.testing.assert_array_equal(state.cov, cov[np.ix_(keep, keep)])
    np.testing.assert_array_equal(state.object_ids, [40, 42])
    ids, means, map_covs = state.full_map()
    np.testing.assert_array_equal(ids, before_ids)
    np.testing.assert_array_equal(means, before_means)
    np.testing.assert_array_equal(map_covs, before_covs)
    np.testing.assert_array_equal(state.dropped_covs[0], covs[1])
    # a snapshot carries the dropped object; an older snapshot (without them) restores too
    copy = MsckfState(np.eye(4), 0, np.eye(6))
    copy.restore(state.snapshot())
    np.testing.assert_array_equal(copy.full_map()[1], means)
    old = {k: v for k, v in state.snapshot().items() if not k.startswith("dropped_")}
    copy.restore(old)
    assert copy.full_map()[0].tolist() == [40, 42]
    # a snapshot whose dropped objects do not match is refused, and the state left as it was
    bad = state.snapshot()
    bad["dropped_means"] = bad["dropped_means"][:, :2]
    with pytest.raises(InputError, match="dropped objects"):
        copy.restore(bad)
    assert copy.full_map()[0].tolist() == [40, 42] and copy.dropped_ids.size == 0
    # entering again: listed once, with its new estimate
    state.add_object(41, np.array([5.0, 5.0, 5.0]), np.eye(3), np.zeros((3, state.dim)))
    ids, means, _ = state.full_map()
    np.testing.assert_array_equal(ids, [40, 41, 42])
    np.testing.assert_array_equal(means[1], [5.0, 5.0, 5.0])
    assert state.dropped_ids.size == 0


def _reanchoring_run(steps: int, settings: dict, checkpoints=()):
    dataset = long_route_team(robots=1, steps=steps, seed=43, miss=0.3)
    config = config_for(dataset, {"filter.linearization": "fej", **settings})
    agent = MsckfAgent(0, dataset.calibration, dataset.robots[0], config)
    audit = NullspaceAudit(agent.state, information=True)
    entered: dict[int, list[tuple[int, np.ndarray]]] = {}
    left: dict[int, list[int]] = {}
    add, drop = agent.state.add_object, agent.state.marginalize_objects

    def add_object(object_id, *args, **kwargs):
        add(object_id, *args, **kwargs)
        entered.setdefault(int(object_id), []).append((agent.state.frames[-1], args))

    def marginalize_objects(slots):
        for oid in agent.state.object_ids[np.asarray(slots)].tolist():
            left.setdefault(oid, []).append(int(agent.state.frames[-1]))
        drop(slots)

    agent.state.add_object, agent.state.marginalize_objects = add_object, marginalize_objects
    information = [audit.rigid_information()]
    for t in range(dataset.robots[0].frames):
        agent.step(t)
        if t in checkpoints:
            information.append(audit.rigid_information())
    return agent, audit, entered, left, information


def test_reanchoring_keeps_the_nullspace_along_the_long_route():
    """`fej` with re-anchoring on the long route (window 20, an active-map budget so that
    objects also retire and re-enter): objects are re-anchored, and some enter again; every
    edit keeps the six rigid motions at the first estimates — a re-anchored object enters again
    with a cross-covariance that carries the directions of its new first estimate — and none
    gives information along them: re-anchoring only loses some (an exact marginalisation), and
    at each third of the route the state knows no more along them than before."""
    settings = {"objects.max_active": 12, "objects.reanchor_probability": 0.99}
    agent, audit, entered, _, information = _reanchoring_run(60, settings, (20, 40, 60))
    counters = agent.counters
    assert counters["objects_reanchored"] > 10 and counters["objects_reentered"] > 10
    again = [oid for oid, times in entered.items() if len(times) > 1]
    assert len(again) > 5
    assert len(audit.information["re-anchoring"]) > 5
    for edit, error in audit.worst().items():
        assert error < 1e-10, (edit, error)
    for edit, gained in audit.most_information().items():
        if edit != "consensus":  # a lone robot: no consensus
            assert gained < 1e-9, (edit, gained)
    for before, after in itertools.pairwise(information):
        assert scipy.linalg.eigh(after, before, eigvals_only=True)[-1] < 1 + 1e-9


def test_a_reanchored_object_enters_again_from_later_observations_only():
    """No observation counts twice: each re-anchored object that enters again does so at a
    later frame than it left, from observations made after it left (its history starts
    again), and a first estimate its data then allow; with the setting off nothing is
    re-anchored, and `std` never re-anchors (its rows follow the current estimate)."""
    settings = {"objects.reanchor_probability": 0.99}
    agent, _, entered, left, _ = _reanchoring_run(40, settings)
    assert sum(len(v) for v in left.values()) == agent.counters["objects_reanchored"] > 5
    need = agent.config.objects.init_observations
    checked = 0
    for oid, frames in left.items():
        # each time it left, the next time it entered (if it did: it may not have been observed
        # often enough since) is at least `init_observations` frames later
        entries = [int(f) for f, _ in entered[oid]]
        for out in frames:
            after = [f for f in entries if f > out]
            assert not any(out - 1 < f < out + need for f in entries), (oid, out, entries)
            checked += bool(after)
    assert checked > 3
    off, _, _, left_off, _ = _reanchoring_run(40, {"objects.reanchor_probability": 0})
    assert off.counters["objects_reanchored"] == 0 and not left_off
    dataset = long_route_team(robots=1, steps=20, seed=43, miss=0.3)
    config = config_for(dataset, {"filter.linearization": "std", **settings})
    std = MsckfAgent(0, dataset.calibration, dataset.robots[0], config)
    for t in range(dataset.robots[0].frames):
        std.step(t)
    assert std.counters["objects_reanchored"] == 0


@pytest.mark.parametrize("value", [-0.1, 1.0, 1.5, "x"])
def test_reanchor_probability_is_validated(value):
    with pytest.raises(InputError, match=r"objects\.reanchor_probability"):
        MsckfConfig.from_settings({"objects.reanchor_probability": value})


def _team_counters(settings: dict, consensus: bool) -> list[dict[str, int]]:
    dataset = long_route_team(robots=2, steps=30, seed=43, miss=0.3)
    config = config_for(dataset, {"filter.linearization": "fej", **settings})
    return run_team(dataset, config, consensus=consensus, progress=False).counters


def test_a_lone_robot_reanchors_by_default_and_a_team_only_when_asked():
    """The default re-anchors a robot running alone (the separate filters), as 0.99 does; a
    robot that averages with neighbours keeps its objects unless
    ``objects.reanchor_with_consensus`` is set, and then re-anchors too."""
    alone = _team_counters({}, consensus=False)
    assert all(c.get("objects_reanchored", 0) > 0 for c in alone)
    explicit = _team_counters({"objects.reanchor_probability": 0.99}, consensus=False)
    assert [c.get("objects_reanchored") for c in explicit] == [
        c.get("objects_reanchored") for c in alone
    ]
    team = _team_counters({}, consensus=True)
    assert all(c.get("objects_reanchored", 0) == 0 for c in team)
    asked = _team_counters({"objects.reanchor_with_consensus": True}, consensus=True)
    assert all(c.get("objects_reanchored", 0) > 0 for c in asked)


@pytest.mark.parametrize("value", [1, "yes", None])
def test_reanchor_with_consensus_is_validated(value):
    with pytest.raises(InputError, match=r"objects\.reanchor_with_consensus"):
        MsckfConfig.from_settings({"objects.reanchor_with_consensus": value})
