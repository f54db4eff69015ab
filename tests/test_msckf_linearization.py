"""Linearisation policies of the MSCKF: where Jacobians are evaluated, and what that keeps."""

from __future__ import annotations

import numpy as np
import pytest

import teamslam.msckf.agent as agent_module
from teamslam.gaussian import NotPositiveDefiniteError
from teamslam.geometry import se3
from teamslam.msckf import MsckfAgent, MsckfState, config_for, run_team
from teamslam.msckf.filter.linearization import GroundTruth, annihilate, unobservable_directions
from teamslam.msckf.filter.models import observe, observe_jacobians
from teamslam.sim import lissajous_team
from teamslam.sim.lissajous import T_CAM_BODY
from teamslam.testing import numerical_jacobian, se3_minus, se3_plus


@pytest.fixture(scope="module")
def small_team():
    return lissajous_team(robots=1, steps=30, seed=3, landmarks=400, objects=120)


def _agent(team, linearization):
    cfg = config_for(team, {"filter.window": 6, "filter.linearization": linearization})
    robot = team.robots[0]
    return MsckfAgent(0, team.calibration, robot, cfg, truth=GroundTruth(robot.T_world_body, team))


@pytest.mark.parametrize("linearization", ["std", "fej", "ideal"])
def test_jacobians_are_analytic_derivatives_at_the_policys_point(
    small_team, linearization, monkeypatch
):
    """Propagation and object rows: the filter's Jacobians equal finite differences of the
    models, evaluated at the current estimate (std), the first-estimate poses and the current
    objects, compensated to annihilate the first estimates' directions (fej), or the truth."""
    agent = _agent(small_team, linearization)
    t0 = 20
    for t in range(t0):
        agent.step(t)
    state = agent.state
    assert state.n_objects > 3
    truth_poses = small_team.robots[0].T_world_body
    # the estimate has moved away from its first estimates and from the truth
    assert np.abs(state.objects - state.object_fe).max() > 1e-3
    # --- propagation
    fe_last, last = state.pose_fe[-1].copy(), state.poses[-1].copy()
    last_cols = slice(6 * (state.n_poses - 1), 6 * state.n_poses)
    before = state.cov[last_cols, last_cols].copy()
    odometry = small_team.robots[0].odometry[t0 - 1]
    agent._propagate(t0)
    new_pose = last @ odometry
    step = {
        "std": odometry,
        "fej": se3.inverse(fe_last) @ new_pose,
        "ideal": se3.inverse(truth_poses[t0 - 1]) @ truth_poses[t0],
    }[linearization]
    at = {"std": last, "fej": fe_last, "ideal": truth_poses[t0 - 1]}[linearization]
    jac = numerical_jacobian(lambda T: T @ step, at, 6, plus=se3_plus, minus=se3_minus)
    new_cols = slice(6 * (state.n_poses - 1), 6 * state.n_poses)
    np.testing.assert_allclose(state.cov[new_cols, last_cols], jac @ before, atol=1e-9)
    np.testing.assert_allclose(state.pose_fe[-1], new_pose)  # its first estimate: T̂_{k+1|k}
    # --- object rows
    calls = []
    original = agent_module.observe_jacobians

    def recording(camera, T_cam_body, poses, points):
        calls.append((np.array(poses), np.array(points)))
        return original(camera, T_cam_body, poses, points)

    monkeypatch.setattr(agent_module, "observe_jacobians", recording)
    ids, _ = small_team.robots[0].objects.frame(t0)
    slots = state.object_slots(ids)
    seen = ids[slots >= 0]
    rows, _ = agent._object_rows(t0)
    # fej also evaluates the current-estimate Jacobians, for its compensation noise
    assert rows.rows > 0 and len(calls) == (2 if linearization == "fej" else 1)
    pose_at, points_at = calls[0]
    slots = state.object_slots(seen)
    expected_pose = {
        "std": state.poses[-1],
        "fej": state.pose_fe[-1],
        "ideal": truth_poses[t0],
    }[linearization]
    expected_points = {
        "std": state.objects[slots],
        "fej": state.objects[slots],
        "ideal": small_team.object_position(seen),
    }[linearization]
    np.testing.assert_allclose(pose_at, expected_pose)
    accepted = rows.rows // 4
    assert accepted >= 1
    h = rows.full(state.dim).reshape(accepted, 4, -1)  # compact rows, widened to check them
    cfg_var = agent.config.filter.object_std**2
    cam = small_team.calibration.camera
    checked = 0
    for p in points_at:
        match = np.flatnonzero(np.all(np.isclose(expected_points, p), axis=1))
        assert match.size == 1
        num_pose = numerical_jacobian(
            lambda T, p=p: observe(cam, T_CAM_BODY, T, p), expected_pose, 6, plus=se3_plus
        )
        num_point = numerical_jacobian(lambda q: observe(cam, T_CAM_BODY, expected_pose, q), p, 3)
        # the row block of this object (rows keep the order of the accepted observations)
        rows_k = [r for r in h if np.any(r[:, state.object_columns(slots[match[0]])] != 0)]
        if not rows_k:
            continue  # rejected by the gate
        if linearization == "fej":
            # compensated to annihilate N at the first estimates (least change in the
            # covariance metric), rows whitened by σ²I + ΔH P ΔHᵀ
            slot = slots[match[0]]
            cols = np.r_[np.arange(new_cols.start, new_cols.stop), state.object_columns(slot)]
            u = unobservable_directions(state.pose_fe[-1], state.object_fe[slot][None])
            local_p = state.cov[np.ix_(cols, cols)]
            current = np.concatenate([num_pose, num_point], axis=1)
            used = annihilate(current[None], u, local_p[None])[0]
            change = used - current
            noise = cfg_var * np.eye(4) + change @ local_p @ change.T
            chol = np.linalg.cholesky(noise / cfg_var)
            num = np.linalg.solve(chol, used)
            num_pose, num_point = num[:, :6], num[:, 6:]
        np.testing.assert_allclose(rows_k[0][:, new_cols], num_pose, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(
            rows_k[0][:, state.object_columns(slots[match[0]])], num_point, rtol=1e-5, atol=1e-7
        )
        checked += 1
    assert checked >= 1


def test_observation_jacobians_annihilate_the_unobservable_directions_at_their_point():
    """The derivation behind FEJ: H(T, p) N(T, p) = 0, but H(T, p) N(T', p') ≠ 0."""
    team = lissajous_team(robots=1, steps=2, landmarks=5, objects=2)
    cam = team.calibration.camera
    rng = np.random.default_rng(0)
    pose = se3.exp(rng.normal(size=6))
    p_body = np.array([12.0, 1.0, -0.5])
    p_world = pose[:3, :3] @ p_body + pose[:3, 3]
    _, d_pose, d_point = observe_jacobians(cam, T_CAM_BODY, pose, p_world)
    h = np.concatenate([d_pose, d_point], axis=-1)
    n = unobservable_directions(pose, p_world)
    assert np.linalg.matrix_rank(n) == 6
    np.testing.assert_allclose(h @ n, 0.0, atol=1e-9 * np.abs(h).max() * np.abs(n).max())
    moved = unobservable_directions(pose @ se3.exp(np.full(6, 0.05)), p_world + 0.5)
    assert np.abs(h @ moved).max() > 1e-3 * np.abs(h).max()
    # propagation with δ = T̄_k⁻¹ T̄_{k+1} carries N(T̄_k) to N(T̄_{k+1}) (pose part)
    nxt = pose @ se3.exp(rng.normal(size=6))
    delta = se3.inverse(pose) @ nxt
    np.testing.assert_allclose(
        se3.adjoint(se3.inverse(delta)) @ n[:6], unobservable_directions(nxt, p_world)[:6]
    )


def test_observability_constrained_rows_annihilate_first_estimate_directions(small_team):
    agent = _agent(small_team, "oc")
    for t in range(21):
        agent.step(t)
    state = agent.state
    cam = small_team.calibration.camera
    _, d_pose, d_point = observe_jacobians(cam, T_CAM_BODY, state.poses[-1], state.objects)
    fe_pose, fe_points = state.pose_fe[-1], state.object_fe
    c_pose, c_point = agent.policy.constrain(d_pose, d_point, fe_pose, fe_points)
    h = np.concatenate([c_pose, c_point], axis=-1)
    h0 = np.concatenate([d_pose, d_point], axis=-1)
    u = unobservable_directions(fe_pose, fe_points)
    np.testing.assert_allclose(h @ u, 0.0, atol=1e-9 * np.abs(h0).max())
    assert np.abs(h0 @ u).max() > 1e-6 * np.abs(h0).max()  # the unconstrained rows do not
    # the smallest change that does it: the correction lies in the span of Uᵀ
    change = h0 - h
    residual = change - change @ u @ np.linalg.pinv(u)
    np.testing.assert_allclose(residual, 0.0, atol=1e-9 * np.abs(h0).max())


def test_first_estimates_stay_through_updates_and_consensus():
    """A pose keeps the value it entered the window with, an object the value it was
    initialised with — also when consensus (Prop. 2) moves it."""
    rng = np.random.default_rng(4)
    state = MsckfState(np.eye(4), 0, np.eye(6) * 0.01)
    step = se3.exp(np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.1]))
    state.augment(step, 1, np.eye(6) * 0.01)
    state.add_object(7, np.array([5.0, 1.0, 0.0]), np.eye(3), np.zeros((3, 12)))
    state.add_object(9, np.array([6.0, -1.0, 0.5]), np.eye(3), np.zeros((3, 15)))
    pose_fe, object_fe = state.pose_fe.copy(), state.object_fe.copy()
    np.testing.assert_allclose(pose_fe[1], step)
    h = rng.normal(size=(5, state.dim))
    state.update(h, rng.normal(size=5), np.eye(5))
    assert np.abs(state.poses - pose_fe).max() > 1e-4
    cols = state.object_columns(np.array([0])).ravel()
    state.replace_marginal(cols, np.array([5.5, 1.2, 0.1]), 0.5 * np.eye(3))
    np.testing.assert_allclose(state.objects[0], [5.5, 1.2, 0.1])
    np.testing.assert_array_equal(state.pose_fe, pose_fe)
    np.testing.assert_array_equal(state.object_fe, object_fe)
    state.marginalize_oldest()
    np.testing.assert_array_equal(state.pose_fe, pose_fe[1:])


@pytest.fixture(scope="module")
def exact_pair():
    return lissajous_team(robots=2, steps=30, seed=1, noise_free=True, landmarks=600)


def test_first_estimate_equals_standard_on_a_noise_free_run(exact_pair):
    """Without noise every estimate is the truth, so all policies linearise at the same point."""
    runs = {
        lin: run_team(
            exact_pair,
            config_for(exact_pair, {"filter.window": 6, "filter.linearization": lin}),
            consensus=False,
            progress=False,
        )
        for lin in ("std", "fej", "ideal")
    }
    for lin in ("fej", "ideal"):
        for a, b in zip(runs["std"].poses, runs[lin].poses, strict=True):
            np.testing.assert_allclose(a, b, atol=1e-9)
        for a, b in zip(runs["std"].pose_covs, runs[lin].pose_covs, strict=True):
            np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-14)


def test_annihilate_is_the_least_change_in_the_covariance_metric():
    """``H* = annihilate(H, U, P)``: ``H* U = 0``; the change ``Δ`` satisfies the optimality
    condition of ``min tr(Δ P Δᵀ)`` (``Δ P`` in the row span of ``Uᵀ``), so any other
    ``H*`` + ``Z`` with ``Z U = 0`` costs more; ``P = I`` is the Frobenius minimum (OC-EKF)."""
    rng = np.random.default_rng(11)
    k = 5
    h = rng.normal(size=(k, 4, 9))
    u = rng.normal(size=(k, 9, 6))
    a = rng.normal(size=(k, 9, 9))
    cov = a @ np.swapaxes(a, 1, 2) + 0.1 * np.eye(9)
    out = annihilate(h, u, cov)
    np.testing.assert_allclose(out @ u, 0.0, atol=1e-10 * np.abs(h).max())
    change = out - h
    # Δ P = Λ Uᵀ: its projection off the row span of Uᵀ vanishes
    dp = change @ cov
    off = dp - dp @ u @ np.linalg.pinv(u)
    np.testing.assert_allclose(off, 0.0, atol=1e-9 * np.abs(dp).max())

    def cost(d):
        return np.einsum("kij,kjl,kil->k", d, cov, d)

    # a feasible competitor: add rows that annihilate U (project random rows off span U)
    z = rng.normal(size=(k, 4, 9))
    z = z - z @ u @ np.linalg.pinv(u)
    np.testing.assert_allclose(z @ u, 0.0, atol=1e-10)
    assert np.all(cost(change + 0.1 * z) > cost(change))
    # identity metric: the unweighted projection
    frob = annihilate(h, u)
    np.testing.assert_allclose(frob, h - h @ u @ np.linalg.pinv(u), atol=1e-10)
    # rows that already annihilate U are left alone, with any metric
    np.testing.assert_allclose(annihilate(out, u, cov), out, atol=1e-10)
    np.testing.assert_allclose(annihilate(frob, u, cov), frob, atol=1e-10)
    bad = cov.copy()
    bad[0] = -np.eye(9)
    with pytest.raises(NotPositiveDefiniteError):
        annihilate(h, u, bad)


def test_first_estimate_object_rows_annihilate_first_estimate_directions(small_team):
    """The fej object rows: current-estimate Jacobians, changed by the least amount in the
    covariance metric so that they annihilate the directions at the first estimates."""
    agent = _agent(small_team, "fej")
    for t in range(21):
        agent.step(t)
    state = agent.state
    assert np.abs(state.objects - state.object_fe).max() > 1e-2  # the objects have moved
    cam = small_team.calibration.camera
    _, d_pose, d_point = observe_jacobians(cam, T_CAM_BODY, state.poses[-1], state.objects)
    fe_pose, fe_points = state.pose_fe[-1], state.object_fe
    cols = np.concatenate(
        [
            np.broadcast_to(state.pose_columns(state.n_poses - 1), (state.n_objects, 6)),
            state.object_columns(np.arange(state.n_objects)),
        ],
        axis=1,
    )
    cov = state.cov[cols[:, :, None], cols[:, None, :]]
    c_pose, c_point = agent.policy.constrain(d_pose, d_point, fe_pose, fe_points, cov)
    h = np.concatenate([c_pose, c_point], axis=-1)
    h0 = np.concatenate([d_pose, d_point], axis=-1)
    u = unobservable_directions(fe_pose, fe_points)
    np.testing.assert_allclose(h @ u, 0.0, atol=1e-9 * np.abs(h0).max())
    assert np.abs(h0 @ u).max() > 1e-6 * np.abs(h0).max()  # the unconstrained rows do not
    dp = (h - h0) @ cov
    np.testing.assert_allclose(dp - dp @ u @ np.linalg.pinv(u), 0.0, atol=1e-8 * np.abs(dp).max())
    # a smaller change in that metric than the unweighted (oc) projection
    frob = np.concatenate(agent.policy.constrain(d_pose, d_point, fe_pose, fe_points), axis=-1)
    assert not np.allclose(frob, h)

    def cost(d):
        return np.einsum("kij,kjl,kil->k", d, cov, d)

    assert np.all(cost(h - h0) <= cost(frob - h0) * (1 + 1e-9))
