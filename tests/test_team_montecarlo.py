"""``teamslam montecarlo``: Monte Carlo NEES/RMSE of the 3D team filter."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import stats

from teamslam.cli import main
from teamslam.eval.team_montecarlo import MonteCarloSpec, one_run
from teamslam.sim import lissajous_team

KEYS = {
    "anees_pose",
    "anees_object",
    "band",
    "position_rmse_m",
    "heading_rmse_rad",
    "runs_above_band",
}


def test_runs_share_paths_and_map_but_not_noise():
    a = lissajous_team(2, 10, seed=5, noise_seed=0, landmarks=50)
    b = lissajous_team(2, 10, seed=5, noise_seed=1, landmarks=50)
    np.testing.assert_array_equal(a.robots[1].T_world_body, b.robots[1].T_world_body)
    np.testing.assert_array_equal(a.object_positions, b.object_positions)
    assert not np.allclose(a.robots[1].odometry, b.robots[1].odometry)
    c = lissajous_team(2, 10, seed=5, landmarks=50)  # without noise_seed: as before
    np.testing.assert_array_equal(
        c.robots[0].odometry, lissajous_team(2, 10, seed=5, landmarks=50).robots[0].odometry
    )


def test_long_route_runs_share_the_route_and_map_but_not_noise():
    spec = MonteCarloSpec(robots=2, steps=12, runs=2, route="long", seed=4)
    a, b = spec.team(0), spec.team(1)
    assert a.metadata["simulation"]["route"] == b.metadata["simulation"]["route"] == "long"
    np.testing.assert_array_equal(a.robots[1].T_world_body, b.robots[1].T_world_body)
    np.testing.assert_array_equal(a.object_positions, b.object_positions)
    assert not np.allclose(a.robots[1].odometry, b.robots[1].odometry)
    other = MonteCarloSpec(robots=2, steps=12, runs=2, route="long", seed=5).team(0)
    assert not np.allclose(other.robots[0].T_world_body, a.robots[0].T_world_body)


def test_montecarlo_command_runs_the_long_route(tmp_path, capsys):
    argv = ["montecarlo", "--route", "long", "--robots", "2", "--steps", "12", "--runs", "2"]
    argv += ["--filters", "fej", "--modes", "separate", "--workers", "1", "--json"]
    assert main([*argv, "--out", str(tmp_path)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["route"] == "long" and summary["steps"] == 12
    result = summary["results"]["fej"]["separate"]
    assert len(result["anees_pose_per_frame"]) == 12 and np.isfinite(result["anees_pose"])


def test_montecarlo_command_json_figures_and_ideal_consistency(tmp_path, capsys):
    argv = [
        "montecarlo",
        "--robots",
        "2",
        "--steps",
        "20",
        "--runs",
        "3",
        "--filters",
        "ideal,std",
        "--modes",
        "separate,centralised",
        "--objects-only",
        "--workers",
        "1",
        "--json",
        "--out",
        str(tmp_path),
    ]
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary == json.loads((tmp_path / "montecarlo.json").read_text())
    assert (tmp_path / "nees.png").stat().st_size > 0 and (tmp_path / "rmse.png").exists()
    assert set(summary["results"]) == {"ideal", "std"}
    lo, hi = stats.chi2.ppf([0.025, 0.975], 3 * 6) / (3 * 6)
    for filt in ("ideal", "std"):
        assert set(summary["results"][filt]) == {"separate", "centralised"}
        for r in summary["results"][filt].values():
            assert KEYS <= set(r)
            np.testing.assert_allclose(r["band"], [lo, hi])
            assert 0 <= r["runs_above_band"] <= 3
            assert len(r["anees_pose_per_frame"]) == 20
    for r in (
        summary["results"][f][m] for f in ("ideal", "std") for m in ("separate", "centralised")
    ):
        per_run = np.asarray(r["position_rmse_per_run_m"])
        assert per_run.shape == (3,)
        # every run has the same robots and frames: the RMSE over runs is the runs' RMS
        assert r["position_rmse_m"] == pytest.approx(np.sqrt(np.mean(per_run**2)), rel=1e-12)
    for mode in ("separate", "centralised"):
        paired = summary["paired_rmse"]["ideal-std"][mode]
        diff = np.subtract(
            summary["results"]["ideal"][mode]["position_rmse_per_run_m"],
            summary["results"]["std"][mode]["position_rmse_per_run_m"],
        )
        assert paired["mean_difference_m"] == pytest.approx(diff.mean(), abs=1e-15)
        low, high = paired["interval_m"]
        half = stats.t.ppf(0.975, 2) * diff.std(ddof=1) / np.sqrt(3)
        assert (low, high) == pytest.approx((diff.mean() - half, diff.mean() + half))
        assert paired["runs_lower"] == int(np.sum(diff < 0))
    ideal = summary["results"]["ideal"]
    for mode in ("separate", "centralised"):
        # the ideal filter is consistent: its average pose NEES inside the band of 3 runs
        assert lo < ideal[mode]["anees_pose"] < hi
        assert ideal[mode]["frames_inside_band"] > 0.8


def test_one_run_nees_is_the_pose_error_in_the_filters_own_metric():
    spec = MonteCarloSpec(
        robots=1, steps=8, runs=1, filters=("std",), modes=("separate",), objects_only=True
    )
    out = one_run(0, spec)["std/separate"]
    assert out["nees_pose"].shape == (1, 9) and out["position_error"].shape == (1, 9)
    assert np.all(out["nees_pose"] >= 0) and out["heading_error"][0, 0] < 1e-6


def test_hybrid_mode_is_consistent_and_less_conservative_than_consensus(tmp_path, capsys):
    """The ideal filter isolates what consensus does: plain averaging is conservative (object
    NEES well below 1), hybrid consensus brings it back without leaving the band."""
    argv = ["montecarlo", "--robots", "3", "--steps", "50", "--runs", "3", "--filters", "ideal"]
    argv += ["--modes", "consensus,hybrid", "--objects-only", "--workers", "1", "--json"]
    argv += ["--set", "filter.window=6", "--out", str(tmp_path)]
    assert main(argv) == 0
    ideal = json.loads(capsys.readouterr().out)["results"]["ideal"]
    lo, hi = ideal["hybrid"]["band"]
    assert lo < ideal["hybrid"]["anees_pose"] < hi
    assert ideal["hybrid"]["anees_object"] > 1.15 * ideal["consensus"]["anees_object"]
    lo, hi = ideal["hybrid"]["band_object"]
    assert lo < ideal["hybrid"]["anees_object"] < hi


@pytest.mark.parametrize(
    "bad",
    [
        ["--filters", "std,best"],
        ["--modes", "everyone"],
        ["--route", "moon"],
        ["--filters", ","],
        ["--set", "no_such_setting=1"],
        ["--set", "consensus.rule=maybe"],
        ["--set", "consensus_hybrid=true"],
    ],
)
def test_bad_arguments_exit_2(tmp_path, bad):
    assert main(["montecarlo", *bad, "--out", str(tmp_path)]) == 2
