"""The consensus hot path (and the compiled triangulation) against straightforward references.

The reference is the textbook form of each step, written densely and with explicit inverses:
eq. 42 with every neighbour's term completed by our own conditional (each sub-marginal's
information by inverting its covariance block), then Proposition 2 as the dense rank-``|y|``
correction ``Σ + G (Σ̄ʸ − Σʸ) Gᵀ``, ``G = Σ[:, y] Σʸ⁻¹``, and the window poses corrected with
``exp`` (eq. 21).
"""

from __future__ import annotations

import copy
from types import SimpleNamespace

import numpy as np
import pytest

from teamslam.gaussian import (
    Gaussian,
    completed_geometric_average,
    kl_divergence,
    replace_marginal_arrays,
    replace_marginal_shift,
)
from teamslam.geometry import se3
from teamslam.geometry.camera import StereoCamera
from teamslam.msckf.consensus import ReceivedMarginal, consensus_average
from teamslam.msckf.consensus.protocol import ConsensusProtocol, _members
from teamslam.msckf.filter.models import observe_jacobians, points_in_camera
from teamslam.msckf.filter.state import MsckfState
from teamslam.msckf.filter.update import stereo_point, triangulate
from teamslam.msckf.settings.values import MsckfConfig


def _spd(rng: np.random.Generator, n: int, scale: float = 1.0) -> np.ndarray:
    a = rng.standard_normal((n, n + 3))
    return scale * (a @ a.T / (n + 3) + 0.05 * np.eye(n))


def _random_state(rng: np.random.Generator, poses: int, objects: int) -> MsckfState:
    xi = 0.3 * rng.standard_normal((poses, 6))
    ids = rng.permutation(np.arange(100, 100 + 2 * objects))[:objects]
    means = rng.standard_normal((objects, 3))
    cov = _spd(rng, 6 * poses + 3 * objects, 0.1)
    return MsckfState.from_arrays(se3.exp(xi), np.arange(poses), ids, means, cov)


def _neighbour(rng, state, ids, sender):
    """A neighbour's marginal of ``ids``: ours, perturbed (mean and covariance)."""
    k = ids.size
    mean = state.objects[state.object_slots(ids)].ravel() + 0.05 * rng.standard_normal(3 * k)
    cov = _spd(rng, 3 * k, 0.05)
    info = np.linalg.inv(cov)
    info = 0.5 * (info + info.T)
    return ReceivedMarginal(sender, np.asarray(ids, dtype=np.int64), info, info @ mean)


def _reference_consensus(state, self_weight, received):
    """Eq. 42 + Prop. 2 + eq. 21, densely, with explicit inverses."""
    y_ids = np.unique(np.concatenate([m.ids for _, m in received]))
    slots = state.object_slots(y_ids)
    iy = state.object_columns(slots).ravel()
    sigma = state.cov
    sigma_y = sigma[np.ix_(iy, iy)]
    mu_y = state.objects[slots].ravel()
    omega = np.linalg.inv(sigma_y)
    info_bar = omega.copy()
    eta_bar = omega @ mu_y
    for w, m in received:
        pos = np.searchsorted(y_ids, m.ids)
        sub = (3 * pos[:, None] + np.arange(3)).ravel()
        own_sub = np.linalg.inv(sigma_y[np.ix_(sub, sub)])
        info_bar[np.ix_(sub, sub)] += w * (m.info - own_sub)
        eta_bar[sub] += w * (m.info_vector - own_sub @ mu_y[sub])
    cov_bar = np.linalg.inv(info_bar)
    mean_bar = cov_bar @ eta_bar
    gain = sigma[:, iy] @ np.linalg.inv(sigma_y)
    new_cov = sigma + gain @ (cov_bar - sigma_y) @ gain.T
    delta = gain @ (mean_bar - mu_y)
    c = state.n_poses
    poses = state.poses @ se3.exp(delta[: 6 * c].reshape(c, 6))
    objects = state.objects + delta[6 * c :].reshape(-1, 3)
    return poses, objects, 0.5 * (new_cov + new_cov.T)


@pytest.mark.parametrize("seed", range(6))
def test_consensus_average_equals_dense_reference(seed):
    rng = np.random.default_rng(seed)
    state = _random_state(rng, poses=int(rng.integers(2, 6)), objects=int(rng.integers(4, 25)))
    neighbours = int(rng.integers(1, 6))
    received = []
    for j in range(neighbours):
        k = int(rng.integers(1, state.n_objects + 1))
        ids = np.sort(rng.choice(state.object_ids, k, replace=False))
        received.append((1.0 / (neighbours + 1), _neighbour(rng, state, ids, j + 1)))
    poses, objects, cov = _reference_consensus(state, 1.0 / (neighbours + 1), received)
    averaged = consensus_average(state, 1.0 / (neighbours + 1), received)
    assert averaged == np.unique(np.concatenate([m.ids for _, m in received])).size
    np.testing.assert_allclose(state.poses, poses, rtol=0, atol=1e-9 * np.abs(poses).max())
    np.testing.assert_allclose(state.objects, objects, rtol=0, atol=1e-9 * np.abs(objects).max())
    np.testing.assert_allclose(state.cov, cov, rtol=0, atol=1e-9 * np.abs(cov).max())
    assert np.array_equal(state.cov, state.cov.T)


@pytest.mark.parametrize("neighbours", [1, 3])
@pytest.mark.parametrize("seed", range(3))
def test_completion_with_the_information_the_sender_kept_equals_the_reference(seed, neighbours):
    """Our own information of each set we sent (kept by ``common_marginal_message``) completes
    the neighbour's marginal of that set: the result is the dense reference's, and the kept
    matrices are what is used (a wrong one changes the result)."""
    from teamslam.msckf.consensus import common_marginal_message

    rng = np.random.default_rng(40 + seed)
    state = _random_state(rng, poses=3, objects=int(rng.integers(8, 20)))
    received, kept = [], {}
    for j in range(neighbours):
        ids = np.sort(rng.choice(state.object_ids, int(rng.integers(1, 5)), replace=False))
        common_marginal_message(state, 0, j + 1, 1, ids, information=True, keep=kept)
        received.append((0.25, _neighbour(rng, state, ids, j + 1)))
    assert len(kept) == neighbours  # with one neighbour its set is y: our Σʸ⁻¹ comes from it
    weight = 1.0 - 0.25 * neighbours
    poses, objects, cov = _reference_consensus(state, weight, received)
    wrong = copy.deepcopy(state)
    consensus_average(state, weight, received, own_information=kept)
    np.testing.assert_allclose(state.poses, poses, rtol=0, atol=1e-9 * np.abs(poses).max())
    np.testing.assert_allclose(state.objects, objects, rtol=0, atol=1e-9 * np.abs(objects).max())
    np.testing.assert_allclose(state.cov, cov, rtol=0, atol=1e-9 * np.abs(cov).max())
    doubled = {key: 2.0 * value for key, value in kept.items()}
    consensus_average(wrong, weight, received, own_information=doubled)
    assert not np.allclose(wrong.objects, objects, rtol=0, atol=1e-6)


@pytest.mark.parametrize("with_info", [False, True])
@pytest.mark.parametrize("seed", range(4))
def test_block_rebuild_equals_dense_rank_correction(seed, with_info):
    rng = np.random.default_rng(10 + seed)
    n = int(rng.integers(3, 40))
    cov = _spd(rng, n)
    iy = np.sort(rng.choice(n, int(rng.integers(1, n + 1)), replace=False))
    shift_y = rng.standard_normal(iy.size)
    cov_y = _spd(rng, iy.size, 0.5)
    sigma_y = cov[np.ix_(iy, iy)]
    info_y = np.linalg.inv(sigma_y) if with_info else None
    before = cov.copy()
    shift, new_cov = replace_marginal_shift(cov, iy, shift_y, cov_y, info_y)
    assert np.array_equal(cov, before)  # the input is left alone
    gain = cov[:, iy] @ np.linalg.inv(sigma_y)
    expected = cov + gain @ (cov_y - sigma_y) @ gain.T
    np.testing.assert_allclose(new_cov, expected, rtol=0, atol=1e-9 * np.abs(expected).max())
    np.testing.assert_allclose(shift, gain @ shift_y, rtol=0, atol=1e-9 * np.abs(shift).max())
    assert np.array_equal(new_cov[np.ix_(iy, iy)], cov_y)
    assert np.array_equal(new_cov, new_cov.T)


def test_replace_marginal_keeps_the_conditional_with_scattered_indices():
    rng = np.random.default_rng(3)
    n = 12
    joint = Gaussian(rng.standard_normal(n), _spd(rng, n))
    iy = np.array([7, 1, 10, 4])  # unsorted, interleaved with x
    new_mean, new_cov = replace_marginal_arrays(
        joint.mean, joint.cov, iy, rng.standard_normal(4), _spd(rng, 4)
    )
    value = rng.standard_normal(4)
    old = joint.conditional(iy, value)
    new = Gaussian(new_mean, new_cov).conditional(iy, value)
    np.testing.assert_allclose(new.mean, old.mean, atol=1e-10)
    np.testing.assert_allclose(new.cov, old.cov, atol=1e-10)


def test_per_block_average_equals_dense_transform():
    rng = np.random.default_rng(5)
    k = 6
    mean = rng.standard_normal(3 * k)
    cov = _spd(rng, 3 * k)
    terms = []
    for _ in range(3):
        held = np.sort(rng.choice(k, int(rng.integers(1, k + 1)), replace=False))
        sub = (3 * held[:, None] + np.arange(3)).ravel()
        info = np.zeros((sub.size, sub.size))
        eta = np.zeros(sub.size)
        for b in range(held.size):
            s = slice(3 * b, 3 * b + 3)
            info[s, s] = np.linalg.inv(_spd(rng, 3, 0.3))
            eta[s] = info[s, s] @ rng.standard_normal(3)
        terms.append((0.2, sub, info, eta))
    new_mean, new_cov = completed_geometric_average(mean, cov, terms, block=3)
    # reference: every block averaged on its own, T = blockdiag(L̄ L⁻¹) as a dense matrix
    transform = np.zeros((3 * k, 3 * k))
    expected_mean = np.zeros(3 * k)
    for b in range(k):
        s = slice(3 * b, 3 * b + 3)
        own = np.linalg.inv(cov[s, s])
        info, eta = own.copy(), own @ mean[s]
        for w, sub, m_info, m_eta in terms:
            where = np.flatnonzero(sub[::3] == 3 * b)
            if where.size:
                t = slice(3 * where[0], 3 * where[0] + 3)
                info += w * (m_info[t, t] - own)
                eta += w * (m_eta[t] - own @ mean[s])
        block_cov = np.linalg.inv(info)
        expected_mean[s] = block_cov @ eta
        transform[s, s] = np.linalg.cholesky(block_cov) @ np.linalg.inv(
            np.linalg.cholesky(cov[s, s])
        )
    expected = transform @ cov @ transform.T
    np.testing.assert_allclose(new_mean, expected_mean, atol=1e-10)
    np.testing.assert_allclose(new_cov, expected, rtol=0, atol=1e-10 * np.abs(expected).max())


def test_members_is_isin():
    rng = np.random.default_rng(0)
    for _ in range(50):
        values = rng.integers(0, 30, int(rng.integers(0, 20)))
        reference = np.unique(rng.integers(0, 30, int(rng.integers(0, 20))))
        assert np.array_equal(_members(values, reference), np.isin(values, reference))


def test_moved_flags_equal_per_neighbour_kl():
    rng = np.random.default_rng(1)
    state = _random_state(rng, poses=3, objects=12)
    agent = SimpleNamespace(
        robot=0,
        state=state,
        config=MsckfConfig.from_settings(
            {"consensus.kl_threshold": 1e-3, "consensus.rule": ("hybrid" if False else "average")}
        ),
    )
    protocol = ConsensusProtocol(agent, [1, 2, 3, 4])
    protocol.requests(1)
    ids, means, covs = protocol._own
    # neighbour 1: nothing on record; 2: a few objects, some unchanged; 3: an empty record;
    # 4: every object, all moved a little
    pick = np.sort(rng.choice(ids, 5, replace=False))
    slots = np.array([np.flatnonzero(ids == p)[0] for p in pick])  # rows of _own
    old_means = means[slots] + np.where(np.arange(5)[:, None] < 2, 0.0, 0.01)
    protocol._agreed[2] = (pick, old_means, covs[slots])
    protocol._agreed[3] = (np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros((0, 3, 3)))
    order = np.argsort(ids)
    protocol._agreed[4] = (ids[order], means[order] + 1e-3, 1.01 * covs[order])
    protocol.kl_threshold = 1e-3
    protocol._moved = {}
    for j in (1, 2, 3, 4):
        expected = np.ones(ids.size, dtype=bool)
        a_ids, a_means, a_covs = protocol._agreed.get(j, (np.zeros(0, dtype=np.int64),) * 3)
        for k, oid in enumerate(ids):
            hit = np.flatnonzero(a_ids == oid)
            if hit.size:
                kl = kl_divergence(means[k], covs[k], a_means[hit[0]], a_covs[hit[0]])
                expected[k] = kl > 1e-3
        assert np.array_equal(protocol._moved_for(j), expected), j
    assert not protocol._moved_for(2)[np.isin(ids, pick[:2])].any()


def _reference_triangulate(camera, T_cam_body, poses, z, iterations=8, min_depth=0.1):
    """Gauss–Newton triangulation written with numpy and observe_jacobians."""
    g, n = z.shape[:2]
    points, ok = stereo_point(camera, T_cam_body, poses[:, -1], z[:, -1])
    points = np.where(ok[:, None], points, 0.0)
    for _ in range(iterations):
        pred, _, d_point = observe_jacobians(camera, T_cam_body, poses, points[:, None, :])
        err = (z - pred).reshape(g, 4 * n)
        jac = d_point.reshape(g, 4 * n, 3)
        normal = np.einsum("gki,gkj->gij", jac, jac) + 1e-12 * np.eye(3)
        step = np.linalg.solve(normal, np.einsum("gki,gk->gi", jac, err)[..., None])[..., 0]
        points = points + np.where(ok[:, None], step, 0.0)
    _, p_cam = points_in_camera(poses, points[:, None, :], T_cam_body)
    rms = np.sqrt(np.mean((z - camera.project(p_cam)) ** 2, axis=(1, 2)))
    ok &= np.all(np.isfinite(points), axis=1) & np.all(p_cam[..., 2] > min_depth, axis=1)
    cond = np.linalg.cond(normal)
    return points, ok & np.isfinite(cond) & (cond < 1e12), rms


def test_compiled_triangulation_equals_numpy_reference():
    rng = np.random.default_rng(2)
    camera = StereoCamera(
        np.array([[700.0, 0, 320], [0, 690.0, 240], [0, 0, 1]]),
        se3.exp(np.array([0.5, 0.01, -0.02, 0.01, 0.02, 0.0])),
    )
    T_cam_body = se3.exp(np.array([0.1, -0.05, 0.2, -1.2, 0.1, -1.5]))
    g, n = 7, 4
    poses = se3.exp(0.2 * rng.standard_normal((g, n, 6)))
    # points a few metres in front of the cameras, observed with pixel noise
    p_cam = np.column_stack([rng.uniform(-2, 2, g), rng.uniform(-1, 1, g), rng.uniform(4, 9, g)])
    p_body = (p_cam - T_cam_body[:3, 3]) @ T_cam_body[:3, :3]
    p_world = np.einsum("gij,gj->gi", poses[:, -1, :3, :3], p_body) + poses[:, -1, :3, 3]
    _, seen = points_in_camera(poses, p_world[:, None, :], T_cam_body)
    z = camera.project(seen) + rng.standard_normal((g, n, 4))
    z[0, -1, 2] = z[0, -1, 0] + 5.0  # negative disparity: no initial point
    points, ok, rms = triangulate(camera, T_cam_body, poses, z)
    ref_points, ref_ok, ref_rms = _reference_triangulate(camera, T_cam_body, poses, z)
    assert np.array_equal(ok, ref_ok) and not ok[0] and ok[1:].all()
    np.testing.assert_allclose(points, ref_points, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(rms, ref_rms, rtol=1e-9)
