"""Stage 1 of the association: candidate pairs from shared neighbourhoods.

Two objects are a candidate pair when enough of their ``k`` nearest neighbours can be the same
objects, as a rigid whole (:func:`~teamslam.association.kernels.shared_neighbourhood`); classes
must agree when both maps have them, and the maps' shared frame allow the pair when they share
one (:func:`~teamslam.association.gate.frame_allowed`); each object keeps its best few candidates
(:attr:`~teamslam.association.AssociationSettings.candidates_per_object`). With an informative
appearance model each object also keeps its best few by appearance
(:func:`appearance_candidates`). The derivation and the reasons are on the association concept
page.
"""

from __future__ import annotations

import numpy as np

from teamslam.association.distances import nearest_neighbours
from teamslam.association.kernels import shared_neighbourhood
from teamslam.association.settings import AssociationSettings
from teamslam.association.summary import ObjectSummary

__all__ = ["appearance_candidates", "neighbourhood_sets", "select_candidates"]


def _neighbourhoods(
    geo: tuple[np.ndarray, np.ndarray], k: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each object's ``k`` nearest neighbours as float32 tables: distances and variances to
    them ``(n, k)``, and between them ``(n, k, k)`` (the arguments of
    :func:`~teamslam.association.kernels.shared_neighbourhood` for one map)."""
    dist, var = geo
    near = nearest_neighbours(dist, k)
    rows = np.arange(dist.shape[0])[:, None]
    pair = (near[:, :, None], near[:, None, :])
    return tuple(
        np.ascontiguousarray(x, dtype=np.float32)
        for x in (dist[rows, near], var[rows, near], dist[pair], var[pair])
    )


def neighbourhood_sets(
    first: ObjectSummary,
    second: ObjectSummary,
    geo_a: tuple[np.ndarray, np.ndarray],
    geo_b: tuple[np.ndarray, np.ndarray],
    settings: AssociationSettings,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every pair's shared neighbourhood (:func:`~teamslam.association.kernels.
    shared_neighbourhood`): the size of its consistent set of neighbour pairs, their summed
    mismatch, and the set's members (``(n_a, n_b, k)``, ``i · k_b + j`` for neighbour ``i`` of
    the first object and ``j`` of the second, ``k_b`` the second map's neighbours per object —
    fewer than ``k`` in a map of ``k`` objects or fewer — and ``-1`` beyond the set)."""
    allowed = np.ones((len(first), len(second)), dtype=bool)
    if first.classes is not None and second.classes is not None:
        allowed = first.classes[:, None] == second.classes[None, :]
    members = np.full((len(first), len(second), settings.neighbours), -1, dtype=np.int16)
    score, mismatch = shared_neighbourhood(
        *_neighbourhoods(geo_a, settings.neighbours),
        *_neighbourhoods(geo_b, settings.neighbours),
        np.ascontiguousarray(allowed),
        np.float32(0.25 * settings.drift_ratio**2),
        np.float32(settings.consistency_threshold),
        members,
    )
    return score, mismatch, members


def select_candidates(
    score: np.ndarray, mismatch: np.ndarray, settings: AssociationSettings
) -> tuple[np.ndarray, np.ndarray]:
    """Candidate pairs from the shared neighbourhoods: each object's best few."""
    chi2 = np.float32(settings.consistency_threshold)
    eligible = score >= max(settings.descriptor_matches, 1)
    # count first; among equal counts the closer agreement (mean normalised mismatch < χ²)
    key = score - mismatch / np.maximum(score, 1) / (chi2 + 1.0)
    key = np.where(eligible, key, -np.inf)
    keep = np.zeros_like(eligible)
    top = settings.candidates_per_object
    rows = np.argsort(-key, axis=1, kind="stable")[:, :top]
    keep[np.arange(key.shape[0])[:, None], rows] = True
    cols = np.argsort(-key, axis=0, kind="stable")[:top, :]
    keep[cols, np.arange(key.shape[1])[None, :]] = True
    ia, ib = np.nonzero(keep & eligible)
    return ia, ib


def appearance_candidates(
    log_ratio: np.ndarray, allowed: np.ndarray, settings: AssociationSettings
) -> np.ndarray:
    """``(n_a, n_b)`` which pairs are candidates by appearance: each object's best few
    (:attr:`~teamslam.association.AssociationSettings.candidates_per_object`) of the other map
    by log likelihood ratio, among the ``allowed`` pairs (classes agree) more likely the same
    object than not (a positive ratio)."""
    key = np.where(allowed & (log_ratio > 0), log_ratio, -np.inf)
    keep = np.zeros(key.shape, dtype=bool)
    if key.size == 0:
        return keep
    top = settings.candidates_per_object
    rows = np.argsort(-key, axis=1, kind="stable")[:, :top]
    keep[np.arange(key.shape[0])[:, None], rows] = True
    cols = np.argsort(-key, axis=0, kind="stable")[:top, :]
    keep[cols, np.arange(key.shape[1])[None, :]] = True
    return keep & np.isfinite(key)
