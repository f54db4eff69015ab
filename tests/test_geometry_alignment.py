"""Closed-form alignment of point sets: weights, batches, rotations never reflections."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from teamslam.errors import InputError
from teamslam.geometry.alignment import align


def _moved(points: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rotation = Rotation.random(random_state=seed).as_matrix()
    translation = np.random.default_rng(seed).uniform(-10, 10, 3)
    return points @ rotation.T + translation, rotation, translation


def _cost(found, source, target, weights) -> float:
    moved = found.scale * source @ found.rotation.T + found.translation
    return float(np.sum(weights * np.sum((target - moved) ** 2, axis=1)))


def test_a_weighted_fit_follows_the_heavy_points():
    rng = np.random.default_rng(0)
    source = rng.uniform(-5, 5, (12, 3))
    target, rotation, translation = _moved(source, 1)
    target[-1] += 3.0  # one pair off by metres
    weights = np.ones(12)
    weights[-1] = 1e-9
    found = align(source, target, weights)
    np.testing.assert_allclose(found.rotation, rotation, atol=1e-8)
    np.testing.assert_allclose(found.translation, translation, atol=1e-7)
    equal = align(source, target)
    assert np.abs(equal.translation - translation).max() > 1e-2


@pytest.mark.parametrize("with_scale", [False, True])
def test_the_weighted_fit_is_optimal_and_a_rotation(with_scale):
    # the target is near the mirror image of the source: the best rotation is not a reflection
    rng = np.random.default_rng(4)
    source = rng.standard_normal((25, 3))
    target = source * np.array([1.0, 1.0, -1.0]) + 0.05 * rng.standard_normal((25, 3))
    weights = rng.uniform(0.1, 5.0, 25)
    found = align(source, target, weights, with_scale=with_scale)
    assert np.linalg.det(found.rotation) == pytest.approx(1.0, abs=1e-12)
    assert with_scale or found.scale == 1.0
    best = _cost(found, source, target, weights)
    for k in range(200):
        d = 1e-3 * np.random.default_rng(k).standard_normal(7)
        other = found._replace(
            rotation=found.rotation @ Rotation.from_rotvec(d[:3]).as_matrix(),
            translation=found.translation + d[3:6],
            scale=found.scale * (1 + d[6]) if with_scale else found.scale,
        )
        assert _cost(other, source, target, weights) >= best


def test_a_batch_is_its_sets_aligned_one_by_one_and_weights_have_no_scale():
    rng = np.random.default_rng(7)
    source = rng.uniform(-3, 3, (6, 8, 3))
    target = np.stack([_moved(s, k)[0] for k, s in enumerate(source)])
    target += 0.1 * rng.standard_normal(target.shape)
    weights = rng.uniform(0.5, 2.0, (6, 8))
    batch = align(source, target, weights, with_scale=True)
    for k in range(6):
        one = align(source[k], target[k], 7.0 * weights[k], with_scale=True)
        np.testing.assert_allclose(batch.rotation[k], one.rotation, atol=1e-12)
        np.testing.assert_allclose(batch.translation[k], one.translation, atol=1e-12)
        np.testing.assert_allclose(batch.scale[k], one.scale, atol=1e-12)
        np.testing.assert_allclose(batch.singular_values[k], one.singular_values, rtol=1e-12)


def test_collinear_points_show_in_the_singular_values():
    line = np.outer(np.arange(10.0), [1.0, 2.0, 3.0])
    found = align(line, line + 1.0)
    assert found.singular_values[1] <= 1e-12 * found.singular_values[0]


def test_bad_shapes_are_refused():
    points = np.zeros((5, 3))
    with pytest.raises(InputError, match="point sets"):
        align(points, points[:, :2])
    with pytest.raises(InputError, match="weights"):
        align(points, points, np.ones(4))
