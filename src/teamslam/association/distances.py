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
    """Distance from each object to its nearest other object of the same map (``inf``: alone)."""
    d2 = np.einsum("abi,abi->ab", means[:, None] - means[None], means[:, None] - means[None])
    np.fill_diagonal(d2, np.inf)
    return np.sqrt(d2.min(axis=1)) if means.shape[0] else np.zeros(0)


def anchor_distance(means: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """Distance from each object to its nearest anchor (a matched object) of the same map."""
    return np.min(np.linalg.norm(means[:, None] - anchors[None], axis=2), axis=1)
