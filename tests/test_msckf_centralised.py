"""The centralised MSCKF: one state for the whole team, the reference of the distributed one."""

from __future__ import annotations

import json

import numpy as np
import pytest

from teamslam.cli import main
from teamslam.datasets import save_dataset
from teamslam.eval.metrics import team_metrics
from teamslam.geometry import se3
from teamslam.msckf import MsckfState, config_for
from teamslam.msckf.centralised import run_centralised
from teamslam.sim import lissajous_team


def test_team_state_windows_evolve_like_separate_states():
    """Uncorrelated robots in one state: each window equals the robot's own filter."""
    rng = np.random.default_rng(0)
    starts = se3.exp(rng.normal(size=(2, 6)))
    cov0 = np.diag(rng.uniform(0.01, 0.1, 6))
    team = MsckfState.team(starts, 0, cov0, debug=True)
    alone = [MsckfState(starts[i], 0, cov0, debug=True) for i in range(2)]
    windows = [team.window(0), team.window(1)]
    for t in range(1, 5):
        for i in (1, 0):  # order does not matter
            step = se3.exp(rng.normal(size=6) * 0.3)
            w = np.diag(rng.uniform(0.001, 0.01, 6))
            windows[i].augment(step, t, w)
            alone[i].augment(step, t, w)
            if windows[i].n_poses > 3:
                windows[i].marginalize_oldest()
                alone[i].marginalize_oldest()
    for i in range(2):
        np.testing.assert_allclose(windows[i].poses, alone[i].poses)
        np.testing.assert_array_equal(windows[i].frames, alone[i].frames)
        block = windows[i].window_columns
        np.testing.assert_allclose(team.cov[block, block], alone[i].cov, atol=1e-15)
        np.testing.assert_allclose(windows[i].current_pose_cov(), alone[i].current_pose_cov())
    np.testing.assert_allclose(team.cov[windows[0].window_columns, windows[1].window_columns], 0)
    np.testing.assert_array_equal(team.robots, [0, 0, 0, 1, 1, 1])


def test_centralised_is_at_least_as_accurate_as_consensus(drifting_team, drifting_runs):
    """On conftest's drifting team (objects only, noisy odometry: shared objects are what
    corrects the drift), against its separate and consensus runs."""
    cfg = config_for(drifting_team, {"filter.window": 10, "filter.use_geometric_features": False})
    metrics = {
        "separate": team_metrics(drifting_team, drifting_runs["separate"]),
        "consensus": team_metrics(drifting_team, drifting_runs["consensus"]),
        "centralised": team_metrics(drifting_team, run_centralised(drifting_team, cfg)),
    }
    rmse = {k: m["trajectory_rmse_avg_m"] for k, m in metrics.items()}
    assert rmse["centralised"] <= min(rmse["consensus"], rmse["separate"])
    central = metrics["centralised"]
    assert central["object_disagreement_avg_m"] == 0.0  # one map
    assert central["object_error_avg_m"] <= metrics["consensus"]["object_error_avg_m"]
    assert central["objects_in_map"][0] >= max(metrics["separate"]["objects_in_map"])
    assert set(central) == set(metrics["consensus"])


def test_run_centralised_from_the_command_line(tmp_path, capsys):
    team = lissajous_team(robots=2, steps=25, seed=4, landmarks=300)
    save_dataset(team, tmp_path / "team")
    for mode in ("--separate", "--centralised"):
        out = tmp_path / mode.strip("-")
        argv = ["run", str(tmp_path / "team"), mode, "--set", "filter.window=6", "--out", str(out)]
        assert main(argv) == 0
    text = capsys.readouterr().out
    assert "centralised" in text and "pose NEES / 6 (std)" in text
    separate = json.loads((tmp_path / "separate" / "metrics.json").read_text())
    central = json.loads((tmp_path / "centralised" / "metrics.json").read_text())
    assert set(central) == set(separate)
    assert central["graph"] == "centralised" and central["robots"] == 2
    assert (tmp_path / "centralised" / "robot_1.tum").exists()  # robots 0 and 1
    assert not (tmp_path / "centralised" / "robot_2.tum").exists()
    with pytest.raises(SystemExit) as exc:
        main(["run", str(tmp_path / "team"), "--centralised", "--compare"])
    assert exc.value.code == 2
