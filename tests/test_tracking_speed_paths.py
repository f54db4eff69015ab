"""The tracker's fast paths name detections exactly as the plain arithmetic they replace."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from teamslam.cli import main
from teamslam.datasets.identity import strip_object_ids
from teamslam.datasets.storage import load_dataset
from teamslam.geometry import so3
from teamslam.geometry.camera import StereoCamera
from teamslam.msckf.agent import MsckfAgent
from teamslam.msckf.configure import config_for
from teamslam.msckf.filter.models import observe_jacobians, points_in_camera
from teamslam.msckf.objects import tracking
from teamslam.sim.lissajous import T_CAM_BODY, lissajous_team


def _assignment_by_solver(allowed: np.ndarray, cost: np.ndarray) -> np.ndarray:
    """The global nearest neighbour with the solver always called."""
    out = np.full(allowed.shape[1], -1, np.int64)
    rows = np.flatnonzero(allowed.any(axis=1))
    if not rows.size:
        return out
    cols = np.flatnonzero(allowed.any(axis=0))
    sub = allowed[np.ix_(rows, cols)]
    ra, ca = linear_sum_assignment(np.where(sub, cost[np.ix_(rows, cols)], 0.0))
    keep = sub[ra, ca]
    out[cols[ca[keep]]] = rows[ra[keep]]
    return out


def test_nearest_neighbour_shortcuts_agree_with_the_solver():
    rng = np.random.default_rng(0)
    for trial in range(600):
        t, d = rng.integers(1, 6, size=2)
        if trial % 3 == 0:
            t = 1
        elif trial % 3 == 1:
            d = 1
        cost = rng.uniform(-5.0, 1.0, size=(t, d))
        cost[rng.random((t, d)) < 0.1] = -1.0  # ties
        allowed = (rng.random((t, d)) < 0.6) & (cost <= 0)
        got = np.full(d, -1, np.int64)
        tracking._nearest_neighbour(allowed, cost, got)
        np.testing.assert_array_equal(got, _assignment_by_solver(allowed, cost))


def _predict_reference(camera, T_cam_body, pose, points, p, min_depth, noise_var):
    """The batched numpy arithmetic the compiled prediction replaced."""
    _, p_cam = points_in_camera(pose, points, T_cam_body)
    in_front = p_cam[:, 2] > min_depth
    safe = np.where(in_front[:, None], points, pose[:3, 3] + pose[:3, :3] @ [10.0, 0, 0])
    pred, d_pose, d_point = observe_jacobians(camera, T_cam_body, pose, safe)
    h = np.concatenate([d_pose, d_point], axis=2)
    s = h @ p @ np.swapaxes(h, 1, 2) + noise_var * np.eye(4)
    return pred, 0.5 * (s + np.swapaxes(s, 1, 2)), d_point, in_front


def _distances_reference(s, pred, z):
    chol = np.linalg.cholesky(s)
    r = z[None, :, :] - pred[:, None, :]
    y = np.linalg.solve(chol[:, None], r[..., None])[..., 0]
    return np.einsum("tdi,tdi->td", y, y)


def _random_covariances(rng, n, size):
    a = rng.normal(size=(n, size, size)) * 0.3
    return a @ np.swapaxes(a, 1, 2) + 1e-3 * np.eye(size)


def test_compiled_prediction_and_gate_match_the_numpy_arithmetic():
    rng = np.random.default_rng(1)
    # a rig whose right camera is also slightly rotated, and a camera off the body axes
    t_left_right = np.eye(4)
    t_left_right[:3, :3] = so3.exp(np.array([0.01, -0.02, 0.005]))
    t_left_right[:3, 3] = [0.54, 0.01, -0.002]
    camera = StereoCamera(np.array([[700.0, 0, 600], [0, 690.0, 180], [0, 0, 1]]), t_left_right)
    pose = np.eye(4)
    pose[:3, :3] = so3.exp(np.array([0.1, -0.2, 1.3]))
    pose[:3, 3] = [5.0, -3.0, 1.0]
    ahead = pose[:3, :3] @ (T_CAM_BODY[:3, :3].T @ np.array([0.0, 0.0, 1.0]))
    points = pose[:3, 3] + rng.uniform(3, 60, size=(40, 1)) * ahead + rng.normal(size=(40, 3)) * 4
    points[:5] = pose[:3, 3] - 10.0 * ahead  # behind the camera
    p = _random_covariances(rng, 40, 9)
    args = (np.ascontiguousarray(pose), _rig(camera), points, p, 0.3, 2.0**2)
    got = tracking._predict_targets(*args)
    want = _predict_reference(camera, T_CAM_BODY, pose, points, p, 0.3, 2.0**2)
    np.testing.assert_array_equal(got[3], want[3])
    assert (~got[3]).sum() == 5
    for a, b in zip(got[:3], want[:3], strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * np.abs(b).max())
    z = want[0][rng.integers(0, 40, size=7)] + rng.normal(size=(7, 4)) * 5
    # both are backward-stable Cholesky solves: they agree to the condition of S times ε
    d2_got = tracking._squared_distances(want[1], want[0], z)
    d2_want = _distances_reference(want[1], want[0], z)
    bound = 1e-14 * np.linalg.cond(want[1])[:, None] * d2_want
    assert np.all(np.abs(d2_got - d2_want) <= bound)
    with pytest.raises(np.linalg.LinAlgError, match="positive definite"):
        tracking._squared_distances(-want[1], want[0], z)


def _rig(camera):
    rig = np.zeros((3, 4, 4))
    rig[0] = T_CAM_BODY
    rig[1, :3, :3] = camera.intrinsics
    rig[2] = camera.T_left_right
    return rig


def _plain(monkeypatch, camera):
    """Swap the fast paths for the numpy arithmetic and the solver they replaced."""

    def predict(pose, rig, points, p, min_depth, noise_var):
        return _predict_reference(camera, rig[0], pose, points, p, min_depth, noise_var)

    def nearest(allowed, cost, assigned):
        got = _assignment_by_solver(allowed, cost)
        assigned[got >= 0] = got[got >= 0]

    monkeypatch.setattr(tracking, "_predict_targets", predict)
    monkeypatch.setattr(tracking, "_squared_distances", _distances_reference)
    monkeypatch.setattr(tracking, "_nearest_neighbour", nearest)


def _named(dataset, config, frames=None):
    """Every robot's tracker output: ids per detection and its re-identifications."""
    out = []
    for i, robot in enumerate(dataset.robots):
        agent = MsckfAgent(i, dataset.calibration, robot, config)
        for t in range(robot.frames if frames is None else min(frames, robot.frames)):
            agent.step(t)
        out.append((agent.tracker.hypotheses(), list(agent.tracker.revisits), agent.tracker.points))
    return out


def _assert_same_names(fast, plain):
    for (h_fast, r_fast, p_fast), (h_plain, r_plain, p_plain) in zip(fast, plain, strict=True):
        np.testing.assert_array_equal(h_fast, h_plain)
        assert r_fast == r_plain
        np.testing.assert_allclose(p_fast, p_plain, rtol=1e-12)


def test_a_cluttered_team_is_named_exactly_as_by_the_plain_arithmetic(monkeypatch):
    team = lissajous_team(robots=3, steps=120, seed=4, clutter=0.05, miss=0.1, classes=3)
    none = strip_object_ids(team, to="none")
    config = config_for(team, calibrate="never")
    fast = _named(none, config)
    assert sum(h.size for h, _, _ in fast) > 500 and any((h >= 0).any() for h, _, _ in fast)
    _plain(monkeypatch, none.calibration.camera)
    _assert_same_names(fast, _named(none, config))


def test_a_kitti_slice_is_named_exactly_as_by_the_plain_arithmetic(
    kitti00_dir, tmp_path, monkeypatch
):
    assert main(["data", "import-reference", str(kitti00_dir), str(tmp_path / "k")]) == 0
    kitti = load_dataset(tmp_path / "k")
    none = strip_object_ids(kitti, to="none")
    config = config_for(kitti, {"filter.object_std": 12.7}, calibrate="never")
    fast = _named(none, config, frames=400)
    assert sum((h >= 0).sum() for h, _, _ in fast) > 300
    _plain(monkeypatch, none.calibration.camera)
    _assert_same_names(fast, _named(none, config, frames=400))
