"""A team's own data out of the box: teams unlike every default, no noise given anywhere.

Each team of :data:`teamslam.sim.SENSOR_SCENARIOS` is written in the published layout and
imported without a parameter file, so neither the dataset nor anything else says how noisy its
sensors are. Calibration from the data alone must find each σ within a factor 1.5 of the
generator's truth; the run on calibrated σ must reach within 15% of the trajectory RMSE the true
σ gives (consensus, what ``teamslam run`` does by default), and separate filters on calibrated σ
must beat odometry by at least 2× — or, on a team where not even the true σ does that, come
within 15% of what the true σ gives.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from teamslam.cli import main
from teamslam.datasets import export_reference, import_reference, save_dataset
from teamslam.eval.metrics import team_metrics
from teamslam.msckf import MsckfConfig, build_settings, run_team
from teamslam.sim import scenario_team

ROBOTS, STEPS, SEED, WINDOW = 3, 150, 1, 10
#: K = I with σ 0.005 (objects only) and σ 0.02 (features), a 700 px camera with σ 3 px
#: (features), odometry of 3 cm / 0.01 rad (objects only); the benchmark runs every scenario
SCENARIOS = [
    "normalised-0.005-objects",
    "normalised-0.02-features",
    "pixels-700-3px-features",
    "odometry-3cm-0.01rad-objects",
]


def _rmse(team, config, consensus: bool) -> dict:
    return team_metrics(team, run_team(team, config, consensus=consensus, progress=False))


@pytest.fixture(scope="module", params=SCENARIOS)
def calibrated(request, tmp_path_factory):
    truth_team = scenario_team(request.param, ROBOTS, STEPS, SEED)
    published = export_reference(truth_team, tmp_path_factory.mktemp("published"))
    team = import_reference(published)
    assert team.sensor_model is None
    effective = build_settings(team, flags={"filter.window": WINDOW})
    truth = build_settings(truth_team, flags={"filter.window": WINDOW}, calibrate="never")
    return request.param, truth_team, team, effective, truth.config


def test_calibrated_sigma_is_within_a_factor_1_5_of_the_truth(calibrated):
    name, truth_team, _, effective, truth = calibrated
    assert effective.calibration is not None
    for key in ("odometry_std", "object_std", "feature_std"):
        if key == "feature_std" and not any(r.features.ids.size for r in truth_team.robots):
            continue
        assert effective.sources[f"filter.{key}"] == "calibration"
        ratio = np.asarray(getattr(effective.config.filter, key)) / np.asarray(
            getattr(truth.filter, key)
        )
        assert np.all((ratio > 1 / 1.5) & (ratio < 1.5)), (name, key, ratio)


def test_calibrated_run_is_as_good_as_the_true_noise(calibrated):
    name, truth_team, _, effective, truth = calibrated
    with_truth = _rmse(truth_team, truth, consensus=True)["trajectory_rmse_avg_m"]
    with_calibration = _rmse(truth_team, effective.config, consensus=True)
    assert with_calibration["trajectory_rmse_avg_m"] < 1.15 * with_truth, (
        name,
        with_calibration["trajectory_rmse_avg_m"],
        with_truth,
    )
    separate = _rmse(truth_team, effective.config, consensus=False)
    if 2.0 * separate["trajectory_rmse_avg_m"] < separate["odometry_rmse_avg_m"]:
        return
    # not 2× better than odometry: only acceptable where the true σ cannot do it either
    separate_truth = _rmse(truth_team, truth, consensus=False)["trajectory_rmse_avg_m"]
    assert 2.0 * separate_truth >= separate["odometry_rmse_avg_m"], (name, separate_truth)
    assert separate["trajectory_rmse_avg_m"] < 1.15 * separate_truth, (
        name,
        separate["trajectory_rmse_avg_m"],
        separate_truth,
    )


def test_teamslam_run_with_no_noise_given_calibrates_and_says_so(tmp_path, capsys):
    """The command line on a published-layout team in normalised coordinates, no flags."""
    truth_team = scenario_team("normalised-0.005-objects", 2, 80, 3)
    export_reference(truth_team, tmp_path / "published")
    assert main(["data", "import-reference", str(tmp_path / "published"), str(tmp_path / "d")]) == 0
    capsys.readouterr()
    assert main(["run", str(tmp_path / "d"), "--out", str(tmp_path / "run")]) == 0
    out, err = capsys.readouterr()
    assert "sensor model: none in the dataset; calibrated from the data" in out
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["config_sources"]["filter.object_std"] == "calibration"
    assert metrics["config_sources"]["filter.gate_probability"] == "default"
    assert metrics["calibration"]["seconds"] > 0
    assert 0.3 < metrics["nis"]["objects"] < 3.0
    assert metrics["gate_rejection_rate"]["objects"] < 0.3
    assert metrics["trajectory_rmse_avg_m"] < 0.5 * metrics["odometry_rmse_avg_m"]
    # the calibrated σ raise no sensor-health warning (a pose NEES line is the filter's
    # consistency against the truth, not the calibration's)
    assert not [s for s in err.splitlines() if "warning" in s and "pose NEES/6" not in s]


def test_calibrate_write_then_config_show(tmp_path, capsys):
    team = scenario_team("pixels-700-3px-features", 1, 60, 2, sensor_model=False)
    save_dataset(team, tmp_path / "d")
    assert main(["calibrate", str(tmp_path / "d"), "--json", "--write"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["sensor_model"]["origin"] == "calibration"
    assert 2.0 < report["sensor_model"]["feature_std"] < 4.5
    assert main(["config", "show", str(tmp_path / "d"), "--json", "--set", "filter.window=7"]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert shown["config_sources"]["filter.feature_std"] == "dataset"  # stored by --write
    assert shown["config"]["filter"]["window"] == 7
    assert shown["config_sources"]["filter.window"] == "flag"
    rows = {r["key"]: r for r in shown["settings"]}
    assert rows["filter.window"] == {
        "key": "filter.window",
        "value": 7,
        "unit": "poses",
        "source": "flag",
    }
    assert "calibration" not in shown  # nothing left to calibrate
    assert main(["config", "show", str(tmp_path / "d")]) == 0
    text = capsys.readouterr().out
    assert "sensor model: the dataset's (calibration" in text
    line = next(x for x in text.splitlines() if x.startswith("filter.feature_std "))
    assert line.split()[-1] == "dataset" and "camera units" in line
    assert len([x for x in text.splitlines() if "." in x.split(" ")[0]]) == len(MsckfConfig.keys())


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--set", "objekt_std=1"], "unknown setting 'objekt_std'; did you mean"),
        (["--set", "windw=8"], "did you mean filter.window"),
        (["--set", "window=8"], "window is now filter.window"),
        (["--set", "filter.window=ten"], "filter.window = 'ten'"),
        (["--set", "window"], "expected group.name=value"),
    ],
)
def test_bad_settings_exit_2_naming_them(tmp_path, capsys, argv, message):
    save_dataset(scenario_team("normalised-0.005-objects", 1, 5, 0), tmp_path / "d")
    assert main(["run", str(tmp_path / "d"), *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1


def test_wrong_sigma_draws_one_warning_line_naming_the_sensor(tmp_path, capsys):
    save_dataset(scenario_team("normalised-0.005-objects", 1, 60, 4), tmp_path / "d")
    config = tmp_path / "bad.yaml"
    config.write_text("filter:\n  object_std: 15.0\n")  # a pixel σ on a K = I camera
    assert main(["run", str(tmp_path / "d"), "--config", str(config), "--separate"]) == 0
    err = capsys.readouterr().err
    lines = [s for s in err.splitlines() if s.startswith("warning")]
    assert any("object σ (filter.object_std) probably too large" in s for s in lines), err


def test_params_file_is_imported_but_checked_against_the_data(tmp_path, capsys):
    truth_team = scenario_team("normalised-0.005-objects", 2, 80, 5)
    export_reference(truth_team, tmp_path / "published")
    params = tmp_path / "params.yaml"
    # variances: odometry σ 0.02 (right), objects σ 0.5 — a hundred times the truth
    params.write_text("motion_noise: 0.0004\nobj_obs_noise: 0.25\n")
    argv = ["data", "import-reference", str(tmp_path / "published"), str(tmp_path / "d")]
    assert main([*argv, "--params", str(params)]) == 0
    out, err = capsys.readouterr()
    assert "params.yaml: variances converted to σ" in out
    assert "warning: the params file's object σ (0.5)" in err
    assert "odometry σ translation" not in err
    from teamslam.datasets import load_dataset

    model = load_dataset(tmp_path / "d").sensor_model
    assert model.origin == "params file" and model.team.object_std == 0.5
