"""Stereo pinhole projection and its Jacobian."""

from __future__ import annotations

import numpy as np
import pytest

from teamslam.errors import InputError
from teamslam.geometry import se3
from teamslam.geometry.camera import StereoCamera
from teamslam.testing import numerical_jacobian


def test_rectified_disparity_is_fx_baseline_over_depth():
    cam = StereoCamera.from_baseline(718.856, 718.856, 607.19, 185.22, 0.532)
    p = np.array([[1.0, -0.5, 10.0], [-3.0, 2.0, 25.0]])
    z = cam.project(p)
    np.testing.assert_allclose(z[:, 0] - z[:, 2], cam.fx_baseline / p[:, 2])
    np.testing.assert_allclose(z[:, 1], z[:, 3])
    assert cam.fx_baseline == pytest.approx(718.856 * 0.532)


def test_projection_jacobian_matches_finite_differences():
    rng = np.random.default_rng(0)
    # a general (non-rectified) right camera pose, to exercise the rotation
    t_lr = se3.exp(np.array([0.5, 0.02, -0.01, 0.01, -0.02, 0.005]))
    cam = StereoCamera(np.array([[400.0, 0, 320], [0, 410.0, 240], [0, 0, 1]]), t_lr)
    for _ in range(20):
        p = np.array([rng.uniform(-4, 4), rng.uniform(-3, 3), rng.uniform(2, 30)])
        numeric = numerical_jacobian(cam.project, p, 3)
        np.testing.assert_allclose(cam.project_jacobian(p), numeric, rtol=1e-6, atol=1e-6)
    batch = rng.uniform(1, 5, size=(7, 3))
    assert cam.project_jacobian(batch).shape == (7, 4, 3)


def test_in_view_checks_depth_bounds_and_disparity():
    cam = StereoCamera.from_baseline(400, 400, 320, 240, 0.5)
    p = np.array(
        [
            [0.0, 0.0, 10.0],  # centre: visible
            [0.0, 0.0, -10.0],  # behind
            [100.0, 0.0, 10.0],  # outside the image
            [0.0, 0.0, 50.0],  # beyond max depth
            [0.0, 0.0, 0.05],  # too close
        ]
    )
    np.testing.assert_array_equal(cam.in_view(p, 640, 480, 0.1, 40.0), [1, 0, 0, 0, 0])


def test_bad_camera_is_rejected():
    with pytest.raises(ValueError, match="3×3"):
        StereoCamera(np.eye(2), np.eye(4))
    with pytest.raises(ValueError, match=r"K\[0\]\[0\] must be finite, got nan"):
        StereoCamera(np.full((3, 3), np.nan), np.eye(4))


@pytest.mark.parametrize(
    ("fx", "fy", "cx", "baseline", "message"),
    [
        (-420.0, 420.0, 320.0, 0.5, r"fx = K\[0\]\[0\] must be > 0, got -420"),
        (420.0, 0.0, 320.0, 0.5, r"fy = K\[1\]\[1\] must be > 0, got 0"),
        (420.0, 420.0, np.inf, 0.5, r"K\[0\]\[2\] must be finite, got inf"),
        (420.0, 420.0, 320.0, 0.0, r"stereo baseline must be > 0, got 0"),
    ],
)
def test_every_camera_passes_the_one_check(fx, fy, cx, baseline, message):
    # focal lengths and baseline > 0, principal point finite: the message names the entry
    with pytest.raises(InputError, match=message):
        StereoCamera.from_baseline(fx, fy, cx, 240.0, baseline)
