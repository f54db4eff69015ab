"""The sensor model: part of the data, calibrated from the data, visible settings, sensor health."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from teamslam.datasets import (
    DatasetError,
    SensorModel,
    SensorNoise,
    export_reference,
    ground_truth_noise,
    import_reference,
    load_dataset,
    read_reference_params,
    save_dataset,
)
from teamslam.geometry import se3
from teamslam.msckf import MsckfConfig, build_settings, config_for, run_team
from teamslam.msckf.calibration import epipolar_noise, nis_ratio
from teamslam.msckf.settings.health import (
    InnovationRecord,
    SensorHealth,
    health_warnings,
    odometry_lag_residuals,
    odometry_step_residual,
)
from teamslam.msckf.settings.sources import (
    ConfigError,
    camera_defaults,
    load_config_file,
    parse_assignments,
)
from teamslam.sim import lissajous_team, scenario_team


@pytest.fixture(scope="module")
def small_team():
    return lissajous_team(robots=2, steps=30, objects=40, seed=3, landmarks=200)


# ---------------------------------------------------------------- the sensor model in the data
def test_sensor_model_json_round_trip_and_per_robot_values():
    model = SensorModel(
        SensorNoise((0.01, 0.02, 0.03, 1e-3, 2e-3, 3e-3), 1.5, 2.5, (1.0, 30.0)),
        {1: SensorNoise(object_std=4.0)},
        origin="user",
        note="hand-made",
    )
    back = SensorModel.from_json(json.loads(json.dumps(model.to_json())), robots=2)
    assert back == model
    assert back.for_robot(0).object_std == 2.5
    assert back.for_robot(1).object_std == 4.0
    assert back.for_robot(1).feature_std == 1.5  # the team's value where the robot has none


@pytest.mark.parametrize(
    ("section", "message"),
    [
        ({"version": 1, "odometry_std": [0.1] * 5}, "odometry_std must be six numbers"),
        ({"version": 1, "object_std": -1.0}, "object_std must be a positive"),
        ({"version": 1, "object_std": "wide"}, "object_std must be a number"),
        ({"version": 1, "pixel_std": 1.0}, "unknown field 'pixel_std'"),
        ({"version": 1, "object_depth_range": [30, 5]}, "min < max"),
        ({"version": 2}, "unsupported version 2"),
        ({"version": 1, "origin": "guess"}, "origin must be one of"),
        ({"version": 1, "robots": {"7": {"object_std": 1.0}}}, "no robot 7"),
    ],
)
def test_sensor_model_errors_name_the_field(section, message):
    with pytest.raises(DatasetError, match=message):
        SensorModel.from_json(section, robots=3)


def test_dataset_round_trip_keeps_the_sensor_model(tmp_path, small_team):
    save_dataset(small_team, tmp_path / "team")
    manifest = json.loads((tmp_path / "team" / "manifest.json").read_text())
    assert manifest["version"] >= 2  # the version that added the sensor model, or later
    assert manifest["sensor_model"]["origin"] == "simulation"
    back = load_dataset(tmp_path / "team")
    assert back.sensor_model == small_team.sensor_model
    bad = dict(manifest, sensor_model={"version": 1, "object_std": 0.0})
    (tmp_path / "team" / "manifest.json").write_text(json.dumps(bad))
    with pytest.raises(DatasetError, match=r"manifest.json: sensor_model.object_std"):
        load_dataset(tmp_path / "team")


def test_version_1_datasets_still_load(tmp_path, small_team):
    save_dataset(replace(small_team, sensor_model=None), tmp_path / "old")
    path = tmp_path / "old" / "manifest.json"
    manifest = json.loads(path.read_text())
    manifest["version"] = 1
    path.write_text(json.dumps(manifest))
    old = load_dataset(tmp_path / "old")
    # a simulated team of format 1 recorded its generator's noise in its metadata
    assert old.sensor_model is not None
    assert old.sensor_model.team.object_std == small_team.sensor_model.team.object_std
    manifest["metadata"] = {"name": "someone else's data"}
    path.write_text(json.dumps(manifest))
    assert load_dataset(tmp_path / "old").sensor_model is None


def test_simulator_records_its_true_noise_and_writes_normalised_coordinates():
    pixels = lissajous_team(robots=1, steps=10, seed=2, landmarks=100, noise_free=True)
    normalised = lissajous_team(
        robots=1, steps=10, seed=2, landmarks=100, noise_free=True, normalised_coordinates=True
    )
    np.testing.assert_array_equal(normalised.calibration.camera.intrinsics, np.eye(3))
    k = pixels.calibration.camera.intrinsics
    z_px, z_n = pixels.robots[0].objects.measurements, normalised.robots[0].objects.measurements
    assert z_px.shape[0] > 10
    centre = np.tile(k[:2, 2], 2)
    np.testing.assert_allclose((z_px - centre) / k[0, 0], z_n, atol=1e-12)
    noisy = lissajous_team(robots=1, steps=5, seed=2, landmarks=50, object_pixel_noise=3.5)
    assert noisy.sensor_model.origin == "simulation"
    assert noisy.sensor_model.team.object_std == 3.5


# ---------------------------------------------------------------- the published layout
def test_published_layout_round_trip_is_exact(tmp_path, small_team):
    export_reference(small_team, tmp_path / "published")
    back = import_reference(tmp_path / "published")
    assert back.sensor_model is None  # the published files carry no noise levels
    for a, b in zip(small_team.robots, back.robots, strict=True):
        np.testing.assert_array_equal(a.T_world_body, b.T_world_body)
        np.testing.assert_array_equal(a.odometry, b.odometry)
        for kind in ("features", "objects"):
            np.testing.assert_array_equal(getattr(a, kind).ids, getattr(b, kind).ids)
            np.testing.assert_array_equal(
                getattr(a, kind).measurements, getattr(b, kind).measurements
            )
    inverted = export_reference(small_team, tmp_path / "inverted", inverted_odometry=True)
    again = import_reference(inverted, inverted_odometry=True)
    np.testing.assert_allclose(again.robots[1].odometry, small_team.robots[1].odometry, atol=1e-12)


def test_params_file_variances_become_standard_deviations(tmp_path):
    path = tmp_path / "params.yaml"
    path.write_text(
        "motion_noise: 0.01\ngeo_obs_noise: 0.25\nobj_obs_noise: 4.0\n"
        "obj_init_dist_min_thre: 5\nobj_init_dist_max_thre: 30\nmax_num_cam: 20\n"
    )
    model = read_reference_params(path)
    assert model.origin == "params file"
    assert model.team.odometry_std == (0.1,) * 6  # W = q·I: σ = √q on every axis
    assert model.team.feature_std == 0.5
    assert model.team.object_std == 2.0
    assert model.team.object_depth_range == (5.0, 30.0)
    path.write_text("motion_noise: -1\n")
    with pytest.raises(DatasetError, match=r"params\.yaml: motion_noise must be a positive"):
        read_reference_params(path)
    path.write_text("motion_noise: [1, 2\n")
    with pytest.raises(DatasetError, match="not valid YAML"):
        read_reference_params(path)


# ---------------------------------------------------------------- where settings come from
def test_settings_take_the_last_layer_and_record_it(small_team):
    team = replace(
        small_team,
        sensor_model=SensorModel(SensorNoise(object_std=7.0, feature_std=0.7), origin="user"),
    )
    eff = build_settings(
        team,
        {"filter": {"object_std": 8.0, "window": 12}},
        {"filter.window": 9},
        calibrate="never",
    )
    assert eff.config.filter.window == 9 and eff.sources["filter.window"] == "flag"
    assert eff.config.filter.object_std == 8.0 and eff.sources["filter.object_std"] == "file"
    assert eff.config.filter.feature_std == 0.7 and eff.sources["filter.feature_std"] == "dataset"
    assert eff.sources["filter.odometry_std"] == "default"
    assert eff.sources["filter.gate_probability"] == "default"
    payload = eff.to_json()
    assert payload["config"]["filter"]["window"] == 9
    assert payload["config_sources"]["filter.window"] == "flag"
    rows = {r["key"]: r for r in eff.rows()}
    assert set(rows) == set(MsckfConfig.keys())
    assert rows["filter.window"] == {
        "key": "filter.window",
        "value": 9,
        "unit": "poses",
        "source": "flag",
    }


def test_defaults_scale_with_the_camera_and_ignore_where_the_data_came_from(small_team):
    pixels = camera_defaults(small_team)
    normalised = camera_defaults(
        replace(
            small_team,
            calibration=replace(
                small_team.calibration,
                camera=replace(small_team.calibration.camera, intrinsics=np.eye(3)),
            ),
        )
    )
    fx = small_team.calibration.camera.intrinsics[0, 0]
    for key in ("filter.object_std", "filter.feature_std"):
        assert pixels[key] == pytest.approx(fx * normalised[key])
    bare = replace(small_team, sensor_model=None)
    configs = [
        build_settings(replace(bare, metadata=meta), calibrate="never").config
        for meta in ({}, {"source": "distributed-MSCKF published data"}, {"source": "kitti"})
    ]
    assert configs[0] == configs[1] == configs[2]


def test_unknown_settings_and_bad_values_are_named(tmp_path):
    with pytest.raises(
        ConfigError, match=r"unknown setting 'filter\.objekt_std'.*filter\.object_std"
    ):
        parse_assignments(["filter.objekt_std=1"])
    with pytest.raises(ConfigError, match=r"filter\.window = 'ten'"):
        parse_assignments(["filter.window=ten"])
    with pytest.raises(ConfigError, match=r"filter\.odometry_std must be a list of six"):
        parse_assignments(["filter.odometry_std=0.1"])
    assert parse_assignments(["filter.odometry_std=[1,1,1,0.1,0.1,0.1]", "filter.debug=true"]) == {
        "filter.odometry_std": (1.0, 1.0, 1.0, 0.1, 0.1, 0.1),
        "filter.debug": True,
    }
    path = tmp_path / "filter.yaml"
    path.write_text("filter:\n  window: 10\n  gate_probability: 1.5\n")
    with pytest.raises(ConfigError, match=r"filter\.gate_probability"):
        build_settings(lissajous_team(robots=1, steps=3, landmarks=10), path)
    path.write_text("- window\n")
    with pytest.raises(ConfigError, match=r"group\.name: value"):
        load_config_file(path)


@pytest.mark.parametrize(
    ("assignment", "message"),
    [
        ("windw=8", "unknown setting 'windw'; did you mean filter.window?"),
        ("consensus.rul=hybrid", "did you mean consensus.rule?"),
        ("filter=8", "filter is a group of settings"),
        ("window=8", "window is now filter.window"),
        ("object_retire_after=3", "object_retire_after is now objects.retire_after"),
        ("association=own", "association is now association.mode"),
        ("consensus_hybrid=true", "replaced by consensus.rule .* consensus.rule=hybrid"),
        ("consensus_increments=true", "consensus.rule=increments"),
    ],
)
def test_unknown_and_old_keys_are_named_with_the_new_one(assignment, message):
    with pytest.raises(ConfigError, match=message):
        parse_assignments([assignment])


def test_nested_and_dotted_file_keys_give_every_setting(tmp_path, small_team):
    path = tmp_path / "settings.yaml"
    path.write_text(
        "filter: {window: 7}\n"
        "consensus:\n  rule: increments\n"
        "association.min_inliers: 4\n"
        "tracking.loop_closure: true\n"
    )
    assert load_config_file(path) == {
        "filter.window": 7,
        "consensus.rule": "increments",
        "association.min_inliers": 4,
        "tracking.loop_closure": True,
    }
    eff = build_settings(small_team, path, ["association.separation=0"], calibrate="never")
    config = eff.config
    assert config.filter.window == 7 and config.consensus.rule == "increments"
    assert config.association.min_inliers == 4 and config.association.matching().min_inliers == 4
    assert config.association.separation == 0.0 and eff.sources["association.separation"] == "flag"
    assert eff.sources["association.min_inliers"] == "file"
    # every setting can be set from a flag: the defaults given back as flags change nothing
    defaults = MsckfConfig().settings()
    flags = {k: list(v) if isinstance(v, tuple) else v for k, v in defaults.items()}
    assert build_settings(small_team, flags=flags, calibrate="never").config == MsckfConfig()
    with pytest.raises(ConfigError, match=r"association\.min_inliers must be an integer"):
        build_settings(small_team, flags={"association.min_inliers": 2}, calibrate="never")


def test_every_setting_has_a_documented_meaning_and_a_unit_entry():
    import inspect
    from dataclasses import fields

    from teamslam.msckf.settings.values import GROUPS

    for group, kind in GROUPS.items():
        doc = inspect.getdoc(kind)
        for f in fields(kind):
            assert f"\n{f.name}\n" in doc, f"{group}.{f.name} has no entry in the docstring"
            assert isinstance(MsckfConfig.unit(f"{group}.{f.name}"), str)


# ---------------------------------------------------------------- statistics behind health
def test_health_nis_is_the_normalised_innovation_squared():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(50, 4, 4))
    s = a @ np.swapaxes(a, 1, 2) + np.eye(4)
    r = rng.normal(size=(50, 4))
    health = SensorHealth(record=True)
    accepted, _ = health.test("objects", r, s, 1.0, stats.chi2.ppf(0.95, 4))
    nis = np.array([ri @ np.linalg.solve(si, ri) for ri, si in zip(r, s, strict=True)])
    np.testing.assert_array_equal(accepted, nis < stats.chi2.ppf(0.95, 4))
    summary = health.summary()
    assert summary["nis"]["objects"] == pytest.approx(nis.sum() / 200)
    assert summary["gate_rejection_rate"]["objects"] == pytest.approx(np.mean(~accepted))
    # the eigenbasis record reproduces the NIS
    rec = health.records["objects"]
    again = [np.sum(c / (lam + 1.0)) for c, lam in zip(rec.c2, rec.lam, strict=True)]
    np.testing.assert_allclose(again, nis, rtol=1e-9)


def test_nis_ratio_is_one_at_the_true_noise_and_ignores_a_wild_outlier():
    """Innovations r ~ N(0, HPHᵀ + σ²I): the ratio is ≈ 1 at the true σ, > 1 below, < 1 above."""
    rng = np.random.default_rng(1)
    record = InnovationRecord()
    sigma = 0.3
    for _ in range(4000):
        lam = np.concatenate([rng.uniform(0.0, 0.5, 3), [0.0]])  # one state-blind direction
        r = rng.normal(size=4) * np.sqrt(lam + sigma**2)
        record.c2.append(r**2)
        record.lam.append(lam)
    assert nis_ratio(record, sigma) == pytest.approx(1.0, abs=0.05)
    lam = np.array([x[:3] for x in record.lam])  # the state-blind direction is not counted
    for other in (0.5 * sigma, 2.0 * sigma):
        expected = np.sum((lam + sigma**2) / (lam + other**2)) / lam.size
        assert nis_ratio(record, other) == pytest.approx(expected, rel=0.05)
        assert abs(expected - 1.0) > 0.3
    record.c2.append(np.full(4, 1e12))
    record.lam.append(np.array([0.1, 0.1, 0.1, 0.0]))
    assert nis_ratio(record, sigma) == pytest.approx(1.0, abs=0.05)


def test_odometry_lag_design_predicts_the_composed_noise():
    """With exact poses, the composed odometry's residual has diag covariance ``M_L · diag W``."""
    rng = np.random.default_rng(2)
    c = 6
    steps = se3.exp(rng.normal(size=(c - 1, 6)) * np.array([0.5, 0.2, 0.1, 0.05, 0.05, 0.2]))
    poses = np.empty((c, 4, 4))
    poses[0] = np.eye(4)
    for k in range(1, c):
        poses[k] = poses[k - 1] @ steps[k - 1]
    sigma = np.array([0.02, 0.01, 0.015, 0.004, 0.002, 0.003])
    draws = 20000
    noisy = steps[None] @ se3.exp(rng.normal(size=(draws, c - 1, 6)) * sigma)
    moments = []
    for d in range(draws):
        moment, design = odometry_lag_residuals(poses, noisy[d], np.zeros((6 * c, 6 * c)))
        moments.append(moment)
    predicted = design @ sigma**2
    np.testing.assert_allclose(np.mean(moments, axis=0), predicted, rtol=0.06)


def test_one_step_odometry_residual_is_lag_one_of_the_window_statistic():
    """The agent's per-step statistic equals lag 1 of :func:`odometry_lag_residuals`, with a
    covariance that correlates the two poses (so every term of ``J Σ Jᵀ`` counts)."""
    rng = np.random.default_rng(7)
    for _ in range(5):
        poses = se3.exp(rng.normal(size=(2, 6)))
        odometry = se3.inverse(poses[0]) @ poses[1] @ se3.exp(0.05 * rng.normal(size=6))
        root = rng.normal(size=(12, 12))
        cov = root @ root.T + 0.1 * np.eye(12)
        want, _ = odometry_lag_residuals(poses, odometry[None], cov)
        got = odometry_step_residual(poses, odometry, cov)
        np.testing.assert_allclose(got, want[0], rtol=1e-12, atol=1e-14)
        # the covariance terms matter: a wrong cross term would move the result
        assert not np.allclose(got, odometry_step_residual(poses, odometry, np.diag(np.diag(cov))))


def test_health_warnings_name_the_sensor_and_the_cause():
    summary = {
        "nis": {"features": 0.001, "objects": 1.0},
        "gate_rejection_rate": {"features": 0.0, "objects": 0.6},
        "odometry_residual_ratio": {"translation": 1.0, "rotation": 40.0},
    }
    lines = health_warnings(summary)
    assert any("geometric-feature" in s and "too large" in s for s in lines)
    assert any("object" in s and "rejects 60%" in s and "too small" in s for s in lines)
    assert any("odometry rotation" in s and "too small" in s for s in lines)
    healthy = {
        "nis": {"features": 1.1, "objects": 0.9},
        "gate_rejection_rate": {"features": 0.05, "objects": 0.06},
        "odometry_residual_ratio": {"translation": 0.9, "rotation": 1.0},
    }
    assert health_warnings(healthy) == []


def test_a_run_with_sigma_far_too_large_says_the_sensor_is_ignored():
    team = scenario_team("normalised-0.005-objects", robots=1, steps=60, seed=4)
    truth = config_for(team, {"filter.window": 10})
    right = run_team(team, truth, consensus=False, progress=False).health["team"]
    wrong = run_team(
        team,
        truth.with_({"filter.object_std": 1000 * truth.filter.object_std}),
        consensus=False,
        progress=False,
    ).health["team"]
    assert 0.5 < right["nis"]["objects"] < 2.0
    assert health_warnings(right) == []
    assert wrong["nis"]["objects"] < 1e-3
    assert any(
        "object σ (filter.object_std) probably too large" in s for s in health_warnings(wrong)
    )


# ---------------------------------------------------------------- noise measured against truth
def test_ground_truth_noise_recovers_the_simulated_noise():
    team = lissajous_team(
        robots=2,
        steps=150,
        seed=6,
        pixel_noise=0.7,
        object_pixel_noise=2.5,
        odometry_translation_noise=0.03,
        odometry_rotation_noise=0.006,
    )
    measured = ground_truth_noise(team)
    np.testing.assert_allclose(measured["odometry_std"], [0.03] * 3 + [0.006] * 3, rtol=0.15)
    assert measured["feature_std"] == pytest.approx(0.7, rel=0.05)
    assert measured["object_std"] == pytest.approx(2.5, rel=0.1)


def test_epipolar_bound_sees_independent_noise_only():
    team = scenario_team("pixels-700-3px-features", robots=1, steps=30, seed=1)
    assert epipolar_noise(team, "features") == pytest.approx(3.0, rel=0.1)
    # the same noise added to both images leaves the epipolar residual untouched
    robot = team.robots[0]
    z = robot.features.measurements.copy()
    common = np.random.default_rng(0).normal(size=(z.shape[0], 2)) * 20.0
    z[:, :2] += common
    z[:, 2:] += common
    shifted = replace(
        team, robots=[replace(robot, features=replace(robot.features, measurements=z))]
    )
    assert epipolar_noise(shifted, "features") == pytest.approx(3.0, rel=0.1)


def test_sensor_model_config_keeps_per_robot_values(small_team):
    model = SensorModel(
        SensorNoise(object_std=2.0, feature_std=1.0, odometry_std=(0.02,) * 3 + (0.004,) * 3),
        {1: SensorNoise(object_std=6.0)},
        origin="user",
    )
    team = replace(small_team, sensor_model=model)
    eff = build_settings(team, calibrate="never")
    assert [c.filter.object_std for c in eff.robots] == [2.0, 6.0]
    assert eff.to_json()["config_per_robot"] == {"1": {"filter.object_std": 6.0}}
    flagged = build_settings(team, flags={"filter.object_std": 3.0}, calibrate="never")
    assert [c.filter.object_std for c in flagged.robots] == [3.0, 3.0]  # a flag wins everywhere
    assert isinstance(eff.robots[0], MsckfConfig)
