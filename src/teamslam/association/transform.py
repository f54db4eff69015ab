"""Stage 4 of the association: the rigid transform a set of pairs implies, and its rigid core.

:func:`fit_transform` is the weighted Horn / Umeyama fit (no scale,
:func:`teamslam.geometry.alignment.align`); :func:`rigid_core` trims a set to the pairs that fit
their own transform within their covariances, :func:`consensus_core` finds them from the triple
whose transform most pairs fit when trimming alone leaves too few. Every choice is
deterministic (ties by order; the triples' sample has a fixed seed), so both ends of a link agree.
"""

from __future__ import annotations

import itertools

import numpy as np

from teamslam.association.settings import AssociationSettings
from teamslam.association.summary import ObjectSummary
from teamslam.errors import InputError
from teamslam.geometry import se3
from teamslam.geometry.alignment import align

__all__ = ["consensus_core", "fit_transform", "pair_nis", "rigid_core", "rigid_transforms"]


def fit_transform(
    means_first: np.ndarray,
    means_second: np.ndarray,
    covs_first: np.ndarray | None = None,
    covs_second: np.ndarray | None = None,
) -> np.ndarray:
    """Weighted Horn / Umeyama: the rigid ``T_first_second`` with ``first ≈ T · second``.

    Weights are the inverse mean variances of each pair (``3 / tr(Σ₁ + Σ₂)``); no scale.

    Returns
    -------
    numpy.ndarray
        ``4 × 4`` transform in ``SE(3)``.
    """
    a = np.asarray(means_first, dtype=float).reshape(-1, 3)
    b = np.asarray(means_second, dtype=float).reshape(-1, 3)
    if a.shape != b.shape or a.shape[0] < 3:
        raise InputError(f"fit_transform needs ≥ 3 matched points, got {a.shape} and {b.shape}")
    if covs_first is not None and covs_second is not None:
        tr = np.trace(covs_first, axis1=1, axis2=2) + np.trace(covs_second, axis1=1, axis2=2)
        w = 3.0 / np.maximum(tr, np.finfo(float).tiny)
    else:
        w = np.ones(a.shape[0])
    return rigid_transforms(a[None], b[None], w[None])[0]


def rigid_transforms(first: np.ndarray, second: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted rigid fits of a batch: ``(T, k, 3)`` points of each map, ``(T, k)`` weights →
    ``(T, 4, 4)`` transforms ``T_first_second`` with ``first ≈ R · second + t``."""
    found = align(second, first, weights)
    return se3.from_rotation_translation(found.rotation, found.translation)


def pair_nis(
    a: ObjectSummary, b: ObjectSummary, rows: np.ndarray, cols: np.ndarray, T_first_second
) -> np.ndarray:
    """Each pair's ``χ²₃`` statistic under a transform: ``νᵀ S⁻¹ ν`` with ``ν = a − (R b + t)``
    and ``S = Σ_a + R Σ_b Rᵀ`` (no drift allowance). ``(k,)``."""
    rot = T_first_second[:3, :3]
    nu = a.means[rows] - (b.means[cols] @ rot.T + T_first_second[:3, 3])
    s = a.covs[rows] + rot @ b.covs[cols] @ rot.T
    return np.einsum("ki,ki->k", nu, np.linalg.solve(s, nu[:, :, None])[:, :, 0])


#: Triples of a consistent set's pairs that :func:`consensus_core` tries, at most
_TRIPLES = 2_000


def consensus_core(
    a: ObjectSummary,
    b: ObjectSummary,
    rows: np.ndarray,
    cols: np.ndarray,
    settings: AssociationSettings,
) -> tuple[np.ndarray, np.ndarray]:
    """The pairs of a consistent set that fit one rigid transform, by consensus of triples.

    For a set where trimming (:func:`rigid_core`) ends with too few pairs. Every triple of the
    set's pairs (a sample of :data:`_TRIPLES` with a fixed seed when there are more) fixes a
    transform; the one under which the most pairs pass the ``χ²₃`` gate within their own
    covariances wins, ties by the order of the triples, and its pairs are trimmed by
    :func:`rigid_core`.
    """
    k = rows.size
    if k < 3:
        return rows[:0], cols[:0]
    triples = np.array(list(itertools.combinations(range(k), 3)), dtype=np.int64)
    if triples.shape[0] > _TRIPLES:
        # the same sample on both ends of a link: the generator's seed is fixed
        pick = np.random.default_rng(0).choice(triples.shape[0], _TRIPLES, replace=False)
        triples = triples[np.sort(pick)]
    ma, mb = a.means[rows], b.means[cols]
    sa, sb = a.covs[rows], b.covs[cols]
    w = 3.0 / (np.trace(sa, axis1=1, axis2=2) + np.trace(sb, axis1=1, axis2=2))
    t = rigid_transforms(ma[triples], mb[triples], w[triples])  # (T, 4, 4)
    r = t[:, :3, :3]
    nu = ma[None] - (np.einsum("tij,kj->tki", r, mb) + t[:, None, :3, 3])
    s = sa[None] + np.einsum("tij,kjl,tml->tkim", r, sb, r)
    nis = np.einsum("tki,tki->tk", nu, np.linalg.solve(s, nu[..., None])[..., 0])
    inliers = nis <= settings.gate_threshold
    best = int(np.argmax(inliers.sum(axis=1)))
    keep = inliers[best]
    return rigid_core(a, b, rows[keep], cols[keep], settings)


def rigid_core(
    a: ObjectSummary,
    b: ObjectSummary,
    rows: np.ndarray,
    cols: np.ndarray,
    settings: AssociationSettings,
) -> tuple[np.ndarray, np.ndarray]:
    """The pairs that fit their own rigid transform within their covariances (no allowance).

    Trimmed refitting: fit, drop the pairs far outside the ``χ²₃`` gate (four times its
    threshold; the worst one when none or all are that far), refit, until every pair left
    passes or fewer than ``min_inliers`` are left.
    """
    gate = settings.gate_threshold
    while rows.size >= settings.min_inliers:
        t = fit_transform(a.means[rows], b.means[cols], a.covs[rows], b.covs[cols])
        nis = pair_nis(a, b, rows, cols, t)
        if nis.max() <= gate:
            break
        far = nis > 4.0 * gate
        keep = ~far if far.any() and not far.all() else np.arange(rows.size) != np.argmax(nis)
        rows, cols = rows[keep], cols[keep]
    return rows, cols
