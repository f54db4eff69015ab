"""Alignment (Umeyama/Horn), APE and RPE against closed-form cases."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from teamslam.errors import InputError
from teamslam.eval.trajectory import (
    Similarity,
    Trajectory,
    absolute_errors,
    alignment,
    associate,
    error_statistics,
    evaluate_team,
    relative_errors,
    rpe_pairs,
    umeyama,
)
from teamslam.geometry import se3


def _random_path(n: int, seed: int) -> np.ndarray:
    """A smooth non-planar path of ``(n, 4, 4)`` poses."""
    rng = np.random.default_rng(seed)
    xi = 0.05 * rng.standard_normal((n, 6)) + np.array([0.5, 0.0, 0.1, 0.0, 0.05, 0.1])
    poses = np.empty((n, 4, 4))
    poses[0] = se3.exp(rng.standard_normal(6))
    for k in range(1, n):
        poses[k] = poses[k - 1] @ se3.exp(xi[k])
    return poses


def _similarity(seed: int, scale: float) -> Similarity:
    rng = np.random.default_rng(seed)
    return Similarity(
        Rotation.random(random_state=seed).as_matrix(), 10 * rng.standard_normal(3), scale
    )


@pytest.mark.parametrize("seed", range(5))
def test_umeyama_recovers_a_known_similarity(seed):
    rng = np.random.default_rng(100 + seed)
    source = rng.uniform(-20, 20, (50, 3))
    truth = _similarity(seed, scale=float(rng.uniform(0.2, 5.0)))
    found = umeyama(source, truth.apply_points(source), with_scale=True)
    np.testing.assert_allclose(found.rotation, truth.rotation, atol=1e-10, rtol=0)
    np.testing.assert_allclose(found.translation, truth.translation, atol=1e-10, rtol=0)
    assert abs(found.scale - truth.scale) < 1e-10


@pytest.mark.parametrize("seed", range(3))
def test_umeyama_recovers_a_known_rigid_transform(seed):
    rng = np.random.default_rng(200 + seed)
    source = rng.uniform(-5, 5, (20, 3))
    truth = _similarity(seed, scale=1.0)
    found = umeyama(source, truth.apply_points(source), with_scale=False)
    np.testing.assert_allclose(found.matrix(), truth.matrix(), atol=1e-10, rtol=0)
    assert found.scale == 1.0


def test_umeyama_planar_points_and_a_quarter_turn():
    # closed form: the unit square's corners turned 90° about z, scaled by 3, shifted
    square = np.array([[1.0, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]])
    quarter = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    target = 3.0 * square @ quarter.T + np.array([1.0, 2.0, 3.0])
    found = umeyama(square, target, with_scale=True)
    np.testing.assert_allclose(found.rotation, quarter, atol=1e-14)
    np.testing.assert_allclose(found.translation, [1.0, 2.0, 3.0], atol=1e-14)
    assert found.scale == pytest.approx(3.0, abs=1e-14)


def test_umeyama_never_returns_a_reflection_and_is_optimal():
    # the target is the mirror image of the source: the best *rotation* is not the reflection
    rng = np.random.default_rng(3)
    source = rng.standard_normal((30, 3))
    target = source * np.array([1.0, 1.0, -1.0]) + 0.01 * rng.standard_normal((30, 3))
    for with_scale in (False, True):
        found = umeyama(source, target, with_scale)
        assert np.linalg.det(found.rotation) == pytest.approx(1.0, abs=1e-12)

        def cost(sim):
            return np.sum((target - sim.apply_points(source)) ** 2)

        best = cost(found)
        # every small perturbation of rotation, translation (and scale) costs more
        for k in range(200):
            d = 1e-3 * np.random.default_rng(k).standard_normal(7)
            other = Similarity(
                found.rotation @ Rotation.from_rotvec(d[:3]).as_matrix(),
                found.translation + d[3:6],
                found.scale * (1 + d[6]) if with_scale else 1.0,
            )
            assert cost(other) >= best


def test_umeyama_rejects_degenerate_input():
    line = np.outer(np.arange(10.0), [1.0, 2.0, 3.0])
    with pytest.raises(InputError, match="collinear"):
        umeyama(line, line + 1.0, with_scale=False)
    with pytest.raises(InputError, match="at least 3"):
        umeyama(line[:2], line[:2], with_scale=False)
    with pytest.raises(InputError, match=r"\(n, 3\)"):
        umeyama(line, line[:, :2], with_scale=False)


def test_first_pose_alignment_puts_first_poses_together():
    ref = _random_path(30, 0)
    offset = se3.exp(np.array([3.0, -1.0, 2.0, 0.3, -0.2, 1.0]))
    est = offset @ ref
    transform = alignment([est], [ref], "first-pose")
    aligned = transform.apply_poses(est)
    np.testing.assert_allclose(aligned, ref, atol=1e-12)


@pytest.mark.parametrize("method", ["se3", "sim3"])
def test_alignment_undoes_a_global_transform_of_poses(method):
    ref = _random_path(40, 1)
    truth = _similarity(7, 0.4 if method == "sim3" else 1.0)
    est = truth.apply_poses(ref)
    transform = alignment([est], [ref], method)
    aligned = transform.apply_poses(est)
    np.testing.assert_allclose(aligned, ref, atol=1e-10)
    ape = absolute_errors(aligned, ref)
    assert ape["translation_m"].max() < 1e-10
    assert ape["rotation_deg"].max() < 1e-8


def test_ape_closed_form():
    ref = _random_path(25, 2)
    est = ref.copy()
    offset = np.array([0.3, -0.4, 1.2])  # |offset| = 1.3
    est[:, :3, 3] += offset
    angle = 0.2
    est[:, :3, :3] = (
        ref[:, :3, :3] @ Rotation.from_rotvec(angle * np.array([0, 0.6, 0.8])).as_matrix()
    )
    ape = absolute_errors(est, ref)
    np.testing.assert_allclose(ape["translation_m"], 1.3, rtol=1e-14)
    np.testing.assert_allclose(ape["rotation_deg"], np.degrees(angle), rtol=1e-12)


def test_rpe_is_blind_to_a_global_rigid_transform_and_sees_scale():
    ref = _random_path(60, 3)
    rigid = _similarity(4, 1.0)
    est = rigid.apply_poses(ref)
    rpe = relative_errors(est, ref, delta=5)
    assert rpe["translation_m"].max() < 1e-10
    assert rpe["rotation_deg"].max() < 1e-8
    assert np.all(absolute_errors(est, ref)["translation_m"] > 0.1)
    # positions doubled about the origin: each relative translation error is the step length
    doubled = ref.copy()
    doubled[:, :3, 3] *= 2.0
    rpe = relative_errors(doubled, ref, delta=3)
    steps = np.linalg.norm(ref[3:, :3, 3] - ref[:-3, :3, 3], axis=1)
    np.testing.assert_allclose(rpe["translation_m"], steps, rtol=1e-12)
    assert rpe["rotation_deg"].max() < 1e-8


def test_rpe_pairs_in_frames_and_metres():
    ref = np.tile(np.eye(4), (21, 1, 1))
    ref[:, 0, 3] = 0.5 * np.arange(21)  # 0.5 m per frame along x
    i, j = rpe_pairs(ref, 4, "frames")
    np.testing.assert_array_equal(j - i, 4)
    assert i[0] == 0 and j[-1] == 20 and len(i) == 17
    i, j = rpe_pairs(ref, 4, "frames", all_pairs=False)
    np.testing.assert_array_equal(i, [0, 4, 8, 12, 16])
    i, j = rpe_pairs(ref, 2.0, "m")
    np.testing.assert_array_equal(j - i, 4)
    assert len(i) == 17
    i, j = rpe_pairs(ref, 2.0, "m", all_pairs=False)
    np.testing.assert_array_equal(i, [0, 4, 8, 12, 16])
    with pytest.raises(InputError, match="positive"):
        rpe_pairs(ref, 0, "frames")
    with pytest.raises(InputError, match="unit"):
        rpe_pairs(ref, 1, "seconds")


def test_error_statistics_closed_form():
    stats = error_statistics(np.array([3.0, 4.0, 0.0, 5.0]))
    assert stats["rmse"] == pytest.approx(np.sqrt(50 / 4), abs=1e-15)
    assert stats["mean"] == 3.0
    assert stats["median"] == 3.5
    assert stats["std"] == pytest.approx(np.sqrt((0 + 1 + 9 + 4) / 4), abs=1e-15)
    assert (stats["max"], stats["min"], stats["count"]) == (5.0, 0.0, 4)


def test_association_by_timestamps():
    ref = Trajectory(_random_path(20, 5), np.arange(20) * 0.1, "ref")
    # every other estimate, stamped 3 ms late, and one far from any reference time
    ts = np.concatenate([np.arange(0, 20, 2) * 0.1 + 0.003, [5.0]])
    est = Trajectory(np.tile(np.eye(4), (len(ts), 1, 1)), ts, "est")
    i_est, i_ref = associate(est, ref, max_time_diff=0.01)
    np.testing.assert_array_equal(i_est, np.arange(10))
    np.testing.assert_array_equal(i_ref, np.arange(0, 20, 2))
    with pytest.raises(InputError, match="no poses within"):
        associate(est, Trajectory(ref.poses, ref.timestamps + 100.0), 0.01)
    with pytest.raises(InputError, match="no timestamps"):
        associate(Trajectory(ref.poses[:5]), Trajectory(ref.poses))


def test_team_alignment_differs_from_per_robot_alignment():
    # two robots, each moved by its own rigid transform: per-robot alignment removes both
    # errors, one team alignment cannot
    refs = [_random_path(30, 10), _random_path(30, 11)]
    ests = [_similarity(1, 1.0).apply_poses(refs[0]), _similarity(2, 1.0).apply_poses(refs[1])]
    est_t = [Trajectory(e, np.arange(30.0)) for e in ests]
    ref_t = [Trajectory(r, np.arange(30.0)) for r in refs]
    per_robot = evaluate_team(est_t, ref_t, align="se3", scope="robot").statistics()
    team = evaluate_team(est_t, ref_t, align="se3", scope="team").statistics()
    assert per_robot["team"]["ape_translation_m"]["rmse"] < 1e-9
    assert team["team"]["ape_translation_m"]["rmse"] > 1.0
    assert "alignment" in team["team"]
    # and with the same transform for both robots the team alignment removes it exactly
    same = _similarity(3, 1.0)
    est_t = [Trajectory(same.apply_poses(r), np.arange(30.0)) for r in refs]
    team = evaluate_team(est_t, ref_t, align="se3", scope="team").statistics()
    assert team["team"]["ape_translation_m"]["rmse"] < 1e-9


def test_align_none_is_the_metrics_rmse_bit_for_bit():
    from teamslam.eval.metrics import trajectory_rmse

    refs = [_random_path(30, 20), _random_path(25, 21)]
    ests = [
        r @ se3.exp(0.1 * np.random.default_rng(i).standard_normal((len(r), 6)))
        for i, r in enumerate(refs)
    ]
    stats = evaluate_team(
        [Trajectory(e) for e in ests], [Trajectory(r) for r in refs], align="none"
    ).statistics()
    expected = [trajectory_rmse(e, r) for e, r in zip(ests, refs, strict=True)]
    assert [r["ape_translation_m"]["rmse"] for r in stats["robots"]] == expected
    assert stats["team"]["ape_translation_rmse_avg_m"] == float(np.mean(expected))


def test_evaluate_team_rejects_mismatched_input():
    ref = Trajectory(_random_path(10, 0))
    with pytest.raises(InputError, match="one reference per robot"):
        evaluate_team([ref, ref], [ref])
    with pytest.raises(InputError, match="unknown alignment"):
        evaluate_team([ref], [ref], align="affine")
    bad = _random_path(10, 0)
    bad[3, 0, 3] = np.nan
    with pytest.raises(InputError, match="NaN"):
        Trajectory(bad, name="robot 1")


def test_nees_band_holds_95_percent_of_consistent_nees():
    from teamslam.eval.figures import nees_band

    rng = np.random.default_rng(0)
    for dof in (6, 30):
        lo, hi = nees_band(dof)
        nees = rng.chisquare(dof, 200_000) / dof
        inside = np.mean((nees >= lo) & (nees <= hi))
        assert abs(inside - 0.95) < 0.003
        assert np.mean(nees < lo) == pytest.approx(0.025, abs=0.002)
