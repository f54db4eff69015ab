"""Retired objects are consider states: every edit of the state keeps their joint exact."""

from __future__ import annotations

import numpy as np
import pytest

from teamslam.gaussian import replace_marginal_shift
from teamslam.geometry import se3
from teamslam.msckf.filter.state import MsckfState


class Reference:
    """The joint covariance of every variable — window poses and objects, active or retired —
    edited by the textbook formulas on the whole matrix: propagation and new objects as linear
    maps, an update with the Schmidt gain (zero for the retired objects) in Joseph form."""

    def __init__(self, labels: list, cov: np.ndarray) -> None:
        self.labels, self.cov = list(labels), cov.copy()

    def index(self, labels) -> np.ndarray:
        sizes = [6 if lab[0] == "pose" else 3 for lab in self.labels]
        start = np.concatenate([[0], np.cumsum(sizes)])
        pos = {lab: k for k, lab in enumerate(self.labels)}
        return np.concatenate(
            [start[pos[lab]] + np.arange(6 if lab[0] == "pose" else 3) for lab in labels]
        )

    def append(self, label, rows: np.ndarray, block: np.ndarray) -> None:
        n = self.cov.shape[0]
        k = block.shape[0]
        cov = np.zeros((n + k, n + k))
        cov[:n, :n] = self.cov
        cov[n:, :n] = rows
        cov[:n, n:] = rows.T
        cov[n:, n:] = block
        self.cov, self.labels = cov, [*self.labels, label]

    def drop(self, label) -> None:
        keep = np.setdiff1d(np.arange(self.cov.shape[0]), self.index([label]))
        self.cov = self.cov[np.ix_(keep, keep)]
        self.labels.remove(label)

    def schmidt_update(self, touched, h: np.ndarray, noise: np.ndarray, consider) -> None:
        n = self.cov.shape[0]
        full = np.zeros((h.shape[0], n))
        full[:, self.index(touched)] = h
        s = full @ self.cov @ full.T + noise
        active = self.index([lab for lab in self.labels if lab not in consider])
        gain = np.zeros((n, h.shape[0]))
        gain[active] = self.cov[active] @ full.T @ np.linalg.inv(s)
        a = np.eye(n) - gain @ full
        self.cov = a @ self.cov @ a.T + gain @ noise @ gain.T


def _labels(state: MsckfState) -> list:
    poses = [("pose", int(r), int(f)) for r, f in zip(state.robots, state.frames, strict=True)]
    return poses + [("obj", int(i)) for i in state.object_ids]


def _random_state(rng, poses: int, objects: int) -> MsckfState:
    dim = 6 * poses + 3 * objects
    a = rng.standard_normal((dim, dim))
    ids = np.arange(10, 10 + objects)
    return MsckfState.from_arrays(
        np.stack([se3.exp(0.3 * rng.standard_normal(6)) for _ in range(poses)]),
        np.arange(poses),
        ids,
        rng.standard_normal((objects, 3)),
        a @ a.T / dim + 0.5 * np.eye(dim),
        debug=True,
    )


def _compare(state: MsckfState, ref: Reference) -> None:
    cov, retired = state.with_consider()
    labels = _labels(state) + [("obj", int(i)) for i in retired]
    np.testing.assert_allclose(
        cov, ref.cov[np.ix_(ref.index(labels), ref.index(labels))], rtol=1e-9, atol=1e-11
    )


@pytest.mark.parametrize("consensus", ["gains", "loses"])
def test_every_edit_keeps_the_joint_with_the_consider_states(consensus):
    """Retire, propagate, update, initialise, marginalise, average, retire and re-enter: the
    joint of the active and the retired objects is at every edit the one the formulas give on
    the whole matrix; re-entering every object gives back that joint whole; the retired means
    never move."""
    rng = np.random.default_rng(7)
    state = _random_state(rng, 3, 6)
    ref = Reference(_labels(state), state.cov)
    state.retire_objects(state.object_slots(np.array([11, 13, 14])))
    _compare(state, ref)
    retired_means = state.retired.get(np.array([11, 13, 14]))[0]

    # propagation: ε_new = Ad(δ⁻¹) ε_last + w
    odometry, noise = se3.exp(0.1 * rng.standard_normal(6)), 0.01 * np.eye(6)
    last = ref.index([("pose", 0, 2)])
    phi = se3.adjoint(se3.inverse(odometry))
    rows = phi @ ref.cov[last]
    ref.append(("pose", 0, 3), rows, phi @ ref.cov[np.ix_(last, last)] @ phi.T + noise)
    state.augment(odometry, 3, noise)
    _compare(state, ref)

    # an update whose rows touch window poses and an active object
    active = [("pose", 0, 1), ("pose", 0, 3), ("obj", 12)]
    h = rng.standard_normal((5, 15))
    noise = 0.2 * np.eye(5)
    cols = state.pose(np.array([1, 3])).columns.ravel()
    cols = np.concatenate([cols, state.object(state.object_slots(np.array([12]))).columns.ravel()])
    ref.schmidt_update(active, h, noise, [("obj", 11), ("obj", 13), ("obj", 14)])
    state.update(h, rng.standard_normal(5), noise, columns=cols)
    _compare(state, ref)

    # a new object from two poses: δp = G δx[cols] + n
    gain = rng.standard_normal((3, 12))
    cols = state.pose(np.array([2, 3])).columns.ravel()
    sources = ref.index([("pose", 0, 2), ("pose", 0, 3)])
    cov_pp = gain @ ref.cov[np.ix_(sources, sources)] @ gain.T + 0.05 * np.eye(3)
    ref.append(("obj", 40), gain @ ref.cov[sources], cov_pp)
    with pytest.raises(Exception, match="from_columns"):
        state.add_object(40, np.zeros(3), cov_pp, gain @ state.cross_covariance(cols))
    state.add_object(
        40, np.zeros(3), cov_pp, gain @ state.cross_covariance(cols), from_columns=(gain, cols)
    )
    _compare(state, ref)

    # the oldest pose leaves the window
    ref.drop(("pose", 0, 0))
    state.marginalize_oldest()
    _compare(state, ref)

    # a neighbour's average of two active objects: Prop. 2 on the whole joint, the retired
    # block kept where the average adds information, grown as Prop. 2 grows it where it loses
    y = state.object(state.object_slots(np.array([10, 12]))).columns.ravel()
    ry = ref.index([("obj", 10), ("obj", 12)])
    factor = 0.5 if consensus == "gains" else 2.0
    new_cov = factor * ref.cov[np.ix_(ry, ry)]
    retired = ref.index([("obj", 11), ("obj", 13), ("obj", 14)])
    kept = ref.cov[np.ix_(retired, retired)].copy()
    _, ref.cov = replace_marginal_shift(ref.cov, ry, np.zeros(6), new_cov)
    if consensus == "gains":
        ref.cov[np.ix_(retired, retired)] = kept
    state.replace_marginal(y, state.objects.ravel()[y - 6 * state.n_poses], new_cov)
    _compare(state, ref)

    # one more retires (correlated with those retired before), one re-enters, an update
    state.retire_objects(state.object_slots(np.array([15])))
    state.reenter_objects(np.array([13]), 3)
    _compare(state, ref)
    h = rng.standard_normal((4, 9))
    cols = np.concatenate(
        [
            state.pose(np.array([2])).columns.ravel(),
            state.object(state.object_slots(np.array([13]))).columns.ravel(),
        ]
    )
    ref.schmidt_update(
        [("pose", 0, 3), ("obj", 13)], h, 0.1 * np.eye(4), [("obj", 11), ("obj", 14), ("obj", 15)]
    )
    state.update(h, rng.standard_normal(4), 0.1 * np.eye(4), columns=cols)
    _compare(state, ref)

    # Schmidt: a retired mean never moved
    np.testing.assert_array_equal(state.retired.get(np.array([11, 14]))[0], retired_means[[0, 2]])
    # everything back: the joint whole
    state.reenter_objects(np.array([15, 11, 14]), 3)
    assert len(state.retired) == 0
    _compare(state, ref)


def test_a_snapshot_carries_the_consider_states_and_checks_the_joint():
    rng = np.random.default_rng(2)
    state = _random_state(rng, 2, 5)
    state.retire_objects(np.array([0, 3]))
    state.augment(se3.exp(0.1 * rng.standard_normal(6)), 2, 0.01 * np.eye(6))
    snapshot = state.snapshot()
    other = _random_state(rng, 1, 0)
    other.restore(snapshot)
    for a, b in zip(state.with_consider(), other.with_consider(), strict=True):
        np.testing.assert_array_equal(a, b)
    # a cross-covariance that does not fit the joint is refused, the state left as it was
    bad = dict(snapshot)
    bad["retired_cross"] = 50.0 * bad["retired_cross"]
    with pytest.raises(Exception, match="not positive definite"):
        other.restore(bad)
    np.testing.assert_array_equal(other.with_consider()[0], state.with_consider()[0])


def test_a_bound_on_the_consider_states_drops_the_earliest_correlations():
    """``max_consider``: beyond it the earliest retired objects keep their marginals only —
    exact marginalisation of the joint — and re-enter without correlations; a snapshot keeps
    which is which."""
    rng = np.random.default_rng(5)
    state = _random_state(rng, 2, 6)
    ref = Reference(_labels(state), state.cov)
    assert state.retire_objects(state.object_slots(np.array([12])), max_consider=2) == 0
    assert state.retire_objects(state.object_slots(np.array([10, 15])), max_consider=2) == 1
    assert state.retire_objects(state.object_slots(np.array([11])), max_consider=2) == 1
    np.testing.assert_array_equal(
        state.retired.is_consider(np.array([12, 10, 15, 11])), [False, False, True, True]
    )
    assert len(state.retired) == 4 and state.retired.n_consider == 2
    # the consider part of the joint is the original's marginal, and so are the loose marginals
    _compare(state, ref)
    for i in (12, 10):
        cov = state.retired.get(np.array([i]))[1][0]
        index = ref.index([("obj", i)])
        np.testing.assert_array_equal(cov, ref.cov[np.ix_(index, index)])
    other = _random_state(rng, 1, 0)
    other.restore(state.snapshot())
    np.testing.assert_array_equal(
        other.retired.is_consider(np.array([12, 10, 15, 11])), [False, False, True, True]
    )
    # a loose object re-enters with its marginal and no correlation; a consider state exactly
    state.reenter_objects(np.array([12, 15]), 2)
    slot = state.object_slots(np.array([12]))[0]
    col = state.object_columns(np.array([slot]))[0]
    rest = np.setdiff1d(np.arange(state.dim), col)
    np.testing.assert_array_equal(state.cov[np.ix_(col, rest)], 0.0)
    cov, retired = state.with_consider()
    labels = [lab for lab in _labels(state) if lab != ("obj", 12)]
    labels += [("obj", int(i)) for i in retired]
    keep = np.setdiff1d(np.arange(cov.shape[0]), col)
    np.testing.assert_allclose(
        cov[np.ix_(keep, keep)], ref.cov[np.ix_(ref.index(labels), ref.index(labels))], rtol=1e-12
    )


@pytest.mark.parametrize("consensus", ["gains", "loses"])
def test_an_average_of_a_retired_object_is_prop_2_with_the_rest_a_consider_state(consensus):
    """``consensus.persistent_map``: a retired object's new marginal with Prop. 2's
    cross-covariances; where the average adds information nothing else changes, where it
    loses some everything else grows as Prop. 2 makes it grow (the joint stays a covariance)."""
    rng = np.random.default_rng(11)
    state = _random_state(rng, 2, 5)
    ref = Reference(_labels(state), state.cov)
    state.retire_objects(state.object_slots(np.array([11, 13])))
    cov, retired = state.with_consider()
    labels = _labels(state) + [("obj", int(i)) for i in retired]
    joint = ref.cov[np.ix_(ref.index(labels), ref.index(labels))]
    np.testing.assert_allclose(cov, joint, rtol=1e-12)
    y = cov.shape[0] - 6 + 3 * list(retired).index(13) + np.arange(3)
    new_cov = (0.5 if consensus == "gains" else 2.0) * joint[np.ix_(y, y)]
    _, want = replace_marginal_shift(joint, y, np.zeros(3), new_cov)
    if consensus == "gains":
        rest = np.setdiff1d(np.arange(joint.shape[0]), y)
        want[np.ix_(rest, rest)] = joint[np.ix_(rest, rest)]
    mean = state.retired.get(np.array([13]))[0] + 0.1
    state.average_retired(np.array([13]), mean, new_cov[None])
    np.testing.assert_allclose(state.with_consider()[0], want, rtol=1e-10, atol=1e-12)
    np.testing.assert_array_equal(state.retired.get(np.array([13]))[0], mean)
