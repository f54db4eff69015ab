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


def _bilinear(image, x, y):
    """Bilinear samples of ``image`` at ``(x, y)`` with the border replicated."""
    h, w = image.shape
    x, y = np.clip(x, 0, w - 1), np.clip(y, 0, h - 1)
    x0, y0 = np.minimum(x.astype(int), w - 2), np.minimum(y.astype(int), h - 2)
    fx, fy = x - x0, y - y0
    img = image.astype(np.float64)
    top = (1 - fx) * img[y0, x0] + fx * img[y0, x0 + 1]
    bottom = (1 - fx) * img[y0 + 1, x0] + fx * img[y0 + 1, x0 + 1]
    return (1 - fy) * top + fy * bottom


def _align_one_patch(window, template, gradients, uv, A, photo, iterations):
    """Gauss–Newton of one patch written out in numpy: the reference of the compiled
    alignment of all patches at once."""
    uv, A, photo = uv.astype(float), A.astype(float), photo.astype(float)
    ox, oy, w = window.ox, window.oy, window.weights
    for _ in range(iterations):
        xs, ys = uv[0] + A[0, 0] * ox + A[0, 1] * oy, uv[1] + A[1, 0] * ox + A[1, 1] * oy
        i_w, gx_w, gy_w = (_bilinear(channel, xs, ys) for channel in gradients)
        g = photo[0]
        J = np.stack([g * gx_w, g * gy_w, g * gx_w * ox, g * gx_w * oy])
        J = np.concatenate([J, [g * gy_w * ox, g * gy_w * oy, i_w, np.ones_like(i_w)]])
        r = g * i_w + photo[1] - template
        step = -np.linalg.solve((J * w) @ J.T + 1e-6 * np.eye(8), (J * w) @ r)
        uv, A, photo = uv + step[:2], A + step[2:6].reshape(2, 2), photo + step[6:]
    xs, ys = uv[0] + A[0, 0] * ox + A[0, 1] * oy, uv[1] + A[1, 0] * ox + A[1, 1] * oy
    t = template - template.mean()
    c = _bilinear(gradients[0], xs, ys)
    c -= c.mean()
    return uv, A, photo, (t * c).sum() / np.sqrt((t * t).sum() * (c * c).sum() + 1e-12)


def test_compiled_alignment_of_all_patches_equals_one_patch_at_a_time():
    """The compiled Gauss–Newton over every patch gives each patch's numpy alignment to
    1e-6 px (warps, gains, NCC alike), near the border too; a patch that starts at NaN
    ends as NaN with NCC −1 and leaves the others alone."""
    from teamslam.frontend._align import PatchWindow, align_patches, with_gradients

    rng = np.random.default_rng(11)
    h, w = 120, 160
    image = (120 + 40 * _texture(rng, (h, w))).astype(np.float32)
    moved = 0.9 * cv2.warpAffine(image, np.array([[1.05, 0.04, 1.3], [-0.03, 0.97, -0.8]]), (w, h))
    window = PatchWindow(6)
    n = 30
    uv = np.column_stack([rng.uniform(2, w - 3, n), rng.uniform(2, h - 3, n)])
    A = np.eye(2) + rng.uniform(-0.05, 0.05, (n, 2, 2))
    photo = np.column_stack([rng.uniform(0.9, 1.1, n), rng.uniform(-5, 5, n)])
    template = window.sample(image, uv, np.tile(np.eye(2), (n, 1, 1)))
    start = uv + rng.uniform(-1, 1, (n, 2))
    start[7] = np.nan
    gradients = with_gradients(moved)
    out = align_patches(window, template, gradients, start, A, photo, 3)
    assert np.isnan(out[0][7]).all() and out[3][7] == -1
    for k in np.delete(np.arange(n), 7):
        ref = _align_one_patch(window, template[k], gradients, start[k], A[k], photo[k], 3)
        for got, want in zip(out, ref, strict=True):
            np.testing.assert_allclose(got[k], want, rtol=0, atol=1e-6)
    # the template sampler is the same bilinear sampling
    xs = uv[:, :1] + A[:, 0, :1] * window.ox + A[:, 0, 1:] * window.oy
    ys = uv[:, 1:] + A[:, 1, :1] * window.ox + A[:, 1, 1:] * window.oy
    np.testing.assert_allclose(window.sample(image, uv, A), _bilinear(image, xs, ys), atol=1e-3)


def test_compiled_sampling_refuses_images_it_cannot_read():
    # the compiled loops read without bounds checks: a too small image or gradients of another
    # shape are refused by name before them
    from teamslam.frontend._align import PatchWindow, align_patches

    window = PatchWindow(2)
    uv, A = np.array([[0.0, 0.0]]), np.eye(2)[None]
    with pytest.raises(InputError, match="at least 2×2"):
        window.sample(np.zeros((1, 40), np.float32), uv, A)
    image = np.zeros((30, 40), np.float32)
    template = np.zeros((1, window.ox.size), np.float32)
    with pytest.raises(InputError, match="gradient of shape"):
        align_patches(
            window, template, (image, image, image[:, :20]), uv + 15, A, np.array([[1.0, 0.0]]), 2
        )
    assert window.sample(image, uv + 15, A).shape == (1, window.ox.size)
