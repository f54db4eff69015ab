"""Errors follow their cause: a non-finite measurement is an estimation failure that names robot
and frame and leaves the estimate untouched; a broken invariant is an internal error; every
error of a consensus round names robot and frame."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from teamslam.errors import EstimationError, InputError, InternalError
from teamslam.gaussian import NotPositiveDefiniteError
from teamslam.geometry import se3
from teamslam.msckf.consensus import consensus_average
from teamslam.msckf.consensus.protocol import ConsensusProtocol
from teamslam.msckf.filter.persistent_map import PersistentMap
from teamslam.msckf.filter.state import MsckfState
from teamslam.msckf.settings.values import MsckfConfig


def _state(rng: np.random.Generator, robot: int | None = 2, first_frame: int = 35) -> MsckfState:
    """A state of ``robot`` with three window poses (frames 35–37) and four objects."""
    poses, objects = 3, 4
    dim = 6 * poses + 3 * objects
    root = rng.normal(size=(dim, dim))
    ids = np.arange(10, 10 + objects)
    means = rng.normal(size=(objects, 3))
    T = se3.exp(0.3 * rng.normal(size=(poses, 6)))
    return MsckfState.from_arrays(
        T,
        np.arange(first_frame, first_frame + poses),
        ids,
        means,
        root @ root.T / dim + 0.05 * np.eye(dim),
        robot=robot,
    )


def _arrays(state: MsckfState) -> dict[str, bytes]:
    """Every array of the state, as bytes (bit-identity)."""
    return {k: v.tobytes() for k, v in state.snapshot().items()}


@pytest.mark.parametrize("where", ["jacobian", "residual", "noise"])
def test_a_non_finite_update_names_robot_and_frame_and_leaves_the_state_bit_identical(where):
    rng = np.random.default_rng(3)
    state = _state(rng)
    before = _arrays(state)
    rows = 5
    jacobian = rng.normal(size=(rows, state.dim))
    residual = rng.normal(size=rows)
    noise = np.eye(rows)
    {"jacobian": jacobian, "residual": residual, "noise": noise}[where].flat[3] = np.nan
    with pytest.raises(
        EstimationError, match=f"(?i)robot 2, frame 37: non-finite measurement {where}"
    ):
        state.update(jacobian, residual, noise)
    assert _arrays(state) == before
    # the same rows without the NaN go through and move the estimate
    jacobian, residual, noise = np.nan_to_num(jacobian), np.nan_to_num(residual), np.eye(rows)
    state.update(jacobian, residual, noise)
    assert _arrays(state) != before


def test_a_robot_window_in_a_team_state_names_its_own_robot_and_newest_frame():
    state = MsckfState.team(np.tile(np.eye(4), (3, 1, 1)), 0, np.eye(6))
    for t in range(1, 5):
        state.augment(np.eye(4), t, 1e-2 * np.eye(6), robot=1)
    before = _arrays(state)
    window = state.window(1)
    jacobian = np.zeros((2, state.dim))
    jacobian[:, window.window_columns] = 1.0
    with pytest.raises(EstimationError, match="robot 1, frame 4"):
        window.update(jacobian, np.array([0.0, np.inf]), np.eye(2))
    assert _arrays(state) == before


def test_a_non_finite_linearisation_in_an_iterated_update_leaves_the_state_as_it_was():
    rng = np.random.default_rng(4)
    state = _state(rng)
    before = _arrays(state)
    jacobian = rng.normal(size=(4, state.dim))
    calls = []

    def rows_at():
        calls.append(1)
        residual = np.full(4, np.nan if len(calls) == 2 else 0.1)
        return jacobian, residual, np.ones(4)

    with pytest.raises(EstimationError, match="robot 2, frame 37: non-finite measurement rows"):
        state.iterated_update(rows_at, iterations=3)
    assert len(calls) == 2  # the first linearisation moved the mean, the second failed
    assert _arrays(state) == before


def test_a_non_finite_object_initialisation_is_refused_before_any_edit():
    rng = np.random.default_rng(5)
    state = _state(rng)
    before = _arrays(state)
    cov_ps = np.zeros((3, state.dim))
    with pytest.raises(EstimationError, match=r"robot 2, frame 37: .*object 99"):
        state.add_object(99, np.array([1.0, np.nan, 0.0]), np.eye(3), cov_ps)
    assert _arrays(state) == before


def test_broken_invariants_are_internal_errors():
    rng = np.random.default_rng(6)
    state = _state(rng)
    with pytest.raises(InternalError, match="object coordinates"):
        state.replace_marginal(np.arange(3), np.zeros(3), np.eye(3))
    with pytest.raises(InternalError, match="not in the persistent map"):
        PersistentMap().take(np.array([4]))
    with pytest.raises(InternalError, match="no pose"):
        state.augment(np.eye(4), 38, np.eye(6), robot=5)
    cols = state.object_columns(np.arange(1)).ravel()
    with pytest.raises(InternalError, match="weights"):
        consensus_average(state, 0.9, [(0.5, _usable_marginal(state, cols))])
    # a broken invariant is no input error: "fix your input" would be the wrong advice
    assert not issubclass(InternalError, InputError)


def _usable_marginal(state: MsckfState, cols: np.ndarray):
    from teamslam.msckf.consensus import ReceivedMarginal

    info = np.linalg.inv(state.covariance(cols))
    ids = state.object_ids[:1]
    return ReceivedMarginal(1, ids, info, info @ state.objects[0])


def test_consensus_errors_name_robot_and_frame():
    rng = np.random.default_rng(7)
    state = _state(rng, robot=3)
    # the robot's object block loses positive definiteness (a diverged filter): its answer to a
    # neighbour cannot invert its own marginal
    broken = state.snapshot()
    cov = broken["cov"]
    cov[18:21, 18:21] = -np.eye(3)
    state = MsckfState.from_arrays(
        broken["window_poses"],
        broken["window_frames"],
        broken["object_ids"],
        broken["objects"],
        cov,
        robot=3,
        check=False,
    )
    agent = SimpleNamespace(
        robot=3,
        state=state,
        config=MsckfConfig.from_settings(
            {"consensus.kl_threshold": 0.0, "consensus.float32": False}
        ),
        counters={},
        timings={"consensus": 0.0},
        reject=lambda *a, **k: None,
    )
    protocol = ConsensusProtocol(agent, [1])
    protocol.requests(37)
    from teamslam.msckf.consensus.messages import MapIdsMessage

    request = MapIdsMessage(1, 3, 37, state.object_ids.copy())
    with pytest.raises(NotPositiveDefiniteError, match="robot 3, frame 37: consensus: "):
        protocol.answer([request])


@pytest.mark.parametrize("error", [NotPositiveDefiniteError, InternalError])
def test_an_average_that_fails_names_robot_and_frame(monkeypatch, error):
    import teamslam.msckf.consensus.rules as rules_module

    def failing(*args, **kwargs):
        raise error("averaged information is not positive definite")

    monkeypatch.setattr(rules_module, "consensus_average", failing)
    agent = SimpleNamespace(
        robot=4,
        state=_state(np.random.default_rng(8), robot=4),
        config=MsckfConfig.from_settings({"consensus.kl_threshold": 0.0}),
        counters={},
        timings={"consensus": 0.0},
        reject=lambda *a, **k: None,
    )
    protocol = ConsensusProtocol(agent, [1])
    protocol.requests(12)
    with pytest.raises(error, match=r"^robot 4, frame 12: consensus: averaged information"):
        protocol.average([])


def test_a_nan_mid_run_stops_the_robot_naming_it_and_leaves_its_estimate_as_before_the_update(
    monkeypatch,
):
    import teamslam.msckf.agent as agent_module
    from teamslam.msckf import config_for
    from teamslam.msckf.agent import MsckfAgent
    from teamslam.sim import lissajous_team

    team = lissajous_team(robots=2, steps=12, seed=3)
    agent = MsckfAgent(1, team.calibration, team.robots[1], config_for(team, {"filter.window": 6}))
    original = agent_module.compress
    before = {}

    def poisoned(rows):
        out = original(rows)
        if agent.frame + 1 == 9:  # the update of frame 9
            before.update(_arrays(agent.state))
            out.residual[0] = np.nan
        return out

    monkeypatch.setattr(agent_module, "compress", poisoned)
    for t in range(9):
        agent.step(t)
    with pytest.raises(EstimationError, match="robot 1, frame 9: non-finite measurement residual"):
        agent.step(9)
    assert before and _arrays(agent.state) == before
