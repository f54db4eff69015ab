"""Front-end settings from assignments with their sources, the marker detector's settings,
and the affine stereo alignment on a slanted surface."""

from __future__ import annotations

import numpy as np
import pytest

from teamslam.errors import InputError
from teamslam.frontend import match_stereo
from teamslam.frontend.config import FrontendConfig, frontend_table, resolve_frontend


def test_assignments_set_any_field_in_its_type_with_its_source():
    config, sources = resolve_frontend(
        [
            "max_features=120",
            "frontend.ncc_min=0.8",
            "affine_refinement=off",
            "marker_dictionary=none",
            "max_features=150",  # the last one wins
        ],
        {"lk_levels": 3},
        "frontend.yaml",
    )
    assert config.max_features == 150 and isinstance(config.max_features, int)
    assert config.ncc_min == 0.8
    assert config.affine_refinement is False
    assert config.marker_dictionary is None
    assert config.lk_levels == 3
    assert sources["max_features"] == "--frontend-set"
    assert sources["lk_levels"] == "frontend.yaml"
    assert sources["min_depth"] == "default"
    table = frontend_table(config, sources)
    assert len(table.splitlines()) == 1 + len(sources)
    assert any(
        line.split()[:3] == ["lk_levels", "3", "frontend.yaml"] for line in table.splitlines()
    )


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("max_features=1.5", "max_features: expected an integer"),
        ("affine_refinement=maybe", "expected true or false"),
        ("ncc_min=high", "ncc_min: expected a number"),
        ("nonsense=1", "unknown front-end setting 'nonsense'"),
        ("max_features", "NAME=VALUE"),
        ("min_depth=200", "min_depth must be below max_depth"),
        ("marker_dictionary=9x9", "marker_dictionary '9x9' unknown"),
        ("stereo_affine_iterations=-1", "stereo_affine_iterations"),
    ],
)
def test_bad_assignments_name_the_setting(text, match):
    with pytest.raises(InputError, match=match):
        resolve_frontend([text])


cv2 = pytest.importorskip("cv2", reason="the images extra (OpenCV) is not installed")


@pytest.mark.parametrize(("passes", "sizes"), [(1, [3]), (2, [3, 23]), (3, [3, 13, 23])])
def test_marker_threshold_passes_give_the_window_sizes(passes, sizes):
    from teamslam.frontend.markers import MarkerDetector

    detector = MarkerDetector(FrontendConfig(marker_threshold_passes=passes))
    p = detector._detector.getDetectorParameters()
    lo, hi, step = (
        p.adaptiveThreshWinSizeMin,
        p.adaptiveThreshWinSizeMax,
        p.adaptiveThreshWinSizeStep,
    )
    assert list(range(lo, hi + 1, step)) == sizes
    assert p.minMarkerPerimeterRate == pytest.approx(0.08)


def _texture(rng, shape):
    base = rng.standard_normal((shape[0] // 4 + 2, shape[1] // 4 + 2)).astype(np.float32)
    big = cv2.resize(base, (shape[1] + 8, shape[0] + 8), interpolation=cv2.INTER_CUBIC)
    return cv2.GaussianBlur(big, (0, 0), 1.0)[4:-4, 4:-4]


def test_affine_alignment_recovers_a_slanted_surfaces_disparity():
    """A slanted plane: the right image is the left one stretched horizontally by 8 % about a
    column and shifted, with another gain and offset. The affine alignment finds the exact
    right position from half a pixel away."""
    from teamslam.frontend.stereo import affine_align

    rng = np.random.default_rng(5)
    h, w = 200, 320
    tex = _texture(rng, (h, w))
    left = 120 + 40 * tex
    scale, shift, c0 = 1.08, 25.3, 160.0
    # right(x) = left(c0 + (x + shift - c0) / scale): a left point u is seen at
    # u_r = c0 + scale (u - c0) - shift
    xs = (c0 + (np.arange(w, dtype=np.float32) + shift - c0) / scale).astype(np.float32)
    mx = np.tile(xs, (h, 1))
    my = np.tile(np.arange(h, dtype=np.float32)[:, None], (1, w))
    right = 0.85 * cv2.remap(left, mx, my, cv2.INTER_CUBIC) + 9.0
    uv = np.column_stack([rng.uniform(120, 230, 40), rng.uniform(40, 160, 40)])
    truth = np.column_stack([c0 + scale * (uv[:, 0] - c0) - shift, uv[:, 1]])
    start = truth + rng.uniform(-0.6, 0.6, truth.shape)
    aligned, ncc = affine_align(left, uv, right.astype(np.float32), start, 10, 5)
    assert np.all(ncc > 0.99)
    assert np.abs(aligned - truth).max() < 0.05


def test_match_stereo_with_affine_alignment_on_a_slanted_pair():
    rng = np.random.default_rng(8)
    h, w = 200, 320
    left = np.clip(120 + 40 * _texture(rng, (h, w)), 0, 255).astype(np.float32)
    scale, shift, c0 = 1.06, 25.3, 160.0
    xs = (c0 + (np.arange(w, dtype=np.float32) + shift - c0) / scale).astype(np.float32)
    mx = np.tile(xs, (h, 1))
    my = np.tile(np.arange(h, dtype=np.float32)[:, None], (1, w))
    right = np.clip(0.9 * cv2.remap(left, mx, my, cv2.INTER_CUBIC) + 6, 0, 255)
    left8, right8 = np.rint(left).astype(np.uint8), np.rint(right).astype(np.uint8)
    uv = np.column_stack([rng.uniform(140, 260, 60), rng.uniform(40, 160, 60)])
    truth_u = c0 + scale * (uv[:, 0] - c0) - shift
    m = match_stereo(left8, right8, uv, (10.0, 60.0), FrontendConfig(stereo_affine_iterations=3))
    assert m.accepted.mean() > 0.8
    err = np.abs(m.uv_right[m.accepted, 0] - truth_u[m.accepted])
    assert np.median(err) < 0.05 and err.max() < 0.2
    np.testing.assert_allclose(m.uv_right[m.accepted, 1], uv[m.accepted, 1], atol=0.1)
