"""Robust object updates: Huber and Cauchy weights of the object innovations."""

from __future__ import annotations

import numpy as np
import pytest

from teamslam.errors import InputError
from teamslam.msckf import MsckfConfig, config_for, run_team
from teamslam.sim import lissajous_team


def test_weights_are_huber_and_cauchy():
    d = np.array([0.0, 1.0, 2.0, 4.0, 8.0])
    huber = MsckfConfig.from_settings(
        {"objects.loss": "huber", "objects.loss_scale": 2.0}
    ).objects.robust_weight(d)
    np.testing.assert_allclose(huber, [1, 1, 1, 0.5, 0.25])
    cauchy = MsckfConfig.from_settings(
        {"objects.loss": "cauchy", "objects.loss_scale": 2.0}
    ).objects.robust_weight(d)
    np.testing.assert_allclose(cauchy, 1 / (1 + (d / 2) ** 2))
    np.testing.assert_array_equal(MsckfConfig().objects.robust_weight(d), np.ones(5))


@pytest.mark.parametrize(
    ("settings", "reason"),
    [
        ({"objects.loss": "tukey"}, "objects.loss must be"),
        ({"objects.loss_scale": 0.0}, "objects.loss_scale"),
        ({"objects.loss_scale": float("nan")}, "objects.loss_scale"),
    ],
)
def test_bad_robust_settings_are_named(settings, reason):
    with pytest.raises(InputError, match=reason):
        MsckfConfig.from_settings(settings)


@pytest.fixture(scope="module")
def team():
    return lissajous_team(robots=2, steps=40, seed=4, landmarks=10)


@pytest.fixture(scope="module")
def gaussian(team):
    """The objects-only settings and the separate run with Gaussian object updates."""
    base = config_for(team, {"filter.window": 8, "filter.use_geometric_features": False})
    return base, run_team(team, base, consensus=False, progress=False)


def test_a_loss_that_never_bites_is_the_gaussian_update(team, gaussian):
    base, gaussian = gaussian
    wide = run_team(
        team,
        base.with_({"objects.loss": "huber", "objects.loss_scale": 1e9}),
        consensus=False,
        progress=False,
    )
    for a, b in zip(gaussian.poses, wide.poses, strict=True):
        np.testing.assert_array_equal(a, b)
    assert all(c["objects_downweighted"] == 0 for c in wide.counters)


def test_down_weighted_updates_move_the_estimate_less(team, gaussian):
    base, gaussian = gaussian
    tight = run_team(
        team,
        base.with_({"objects.loss": "cauchy", "objects.loss_scale": 0.5}),
        consensus=False,
        progress=False,
    )
    assert all(c["objects_downweighted"] > 0 for c in tight.counters)
    # down-weighted objects correct the pose less: its covariance stays larger
    for g, t in zip(gaussian.pose_covs, tight.pose_covs, strict=True):
        trace_g = np.trace(g[-1][:3, :3])
        trace_t = np.trace(t[-1][:3, :3])
        assert trace_t > trace_g
