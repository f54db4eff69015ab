"""Distances within one object map: all pairs with their variances, nearest neighbours, anchors.

The variance of a distance is taken along its direction from the two objects' marginal
covariances (``uᵀ (Σₐ + Σₐ') u``); every later stage of the association reads distances and
variances from here, in the map's own coordinates.
"""

from __future__ import annotations

import numpy as np

__all__ = ["anchor_distance", "nearest_distance", "nearest_neighbours", "pair_distances"]


def pair_distances(means: np.ndarray, covs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All distances within one map and their variances along their directions."""
    delta = means[:, None, :] - means[None, :, :]
    dist = np.linalg.norm(delta, axis=2)
    unit = delta / np.maximum(dist, np.finfo(float).tiny)[..., None]
    # uᵀ Σₐ u for every ordered pair, then the variance of ‖a − a'‖ is uᵀ (Σₐ + Σₐ') u
    along = np.einsum("abi,aij,abj->ab", unit, covs, unit)
    return dist, along + along.T


def nearest_neighbours(dist: np.ndarray, k: int) -> np.ndarray:
    """Indices of each object's ``k`` nearest other objects (ascending; ties by index)."""
    n = dist.shape[0]
    k = min(k, n - 1)
    masked = dist + np.diag(np.full(n, np.inf))
    return np.argsort(masked, axis=1, kind="stable")[:, :k]


def nearest_distance(means: np.ndarray) -> np.ndarray:
    """Distance from each object to its nearest other object of the same map (``inf``: alone).

    The squared differences of the three coordinates are summed as numpy's ``einsum`` sums
    three terms (the first and third, then the second), without the ``(n, n, 3)``
    temporaries: the same numbers as the sum of products over the differences."""
    if means.shape[0] == 0:
        return np.zeros(0)
    x, y, z = (means[:, i, None] - means[None, :, i] for i in range(3))
    d2 = (x * x + z * z) + y * y
    np.fill_diagonal(d2, np.inf)
    return np.sqrt(d2.min(axis=1))


def anchor_distance(means: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """Distance from each object to its nearest anchor (a matched object) of the same map.

    The squared differences summed coordinate by coordinate in order, as the Euclidean norm
    sums them, without the ``(n, k, 3)`` temporaries; the root of the least (the root is
    monotone: the least of the roots)."""
    x, y, z = (means[:, i, None] - anchors[None, :, i] for i in range(3))
    return np.sqrt(np.min((x * x + y * y) + z * z, axis=1))
