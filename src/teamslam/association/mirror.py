"""The mirror test of the association: a near-planar set fitted by its mirror image is refused.

Distances cannot tell a near-planar group of objects from its mirror image; :func:`flipped` asks
the cameras (the summaries' ``views``) whether a transform puts the two robots on opposite sides
of the set's plane. Computed from the two summaries alone, in the canonical order, it is the same
on both ends of a link.
"""

from __future__ import annotations

import numpy as np

from teamslam.association.settings import AssociationSettings
from teamslam.association.summary import ObjectSummary

__all__ = ["flipped"]


def flipped(
    first: ObjectSummary,
    second: ObjectSummary,
    rows: np.ndarray,
    cols: np.ndarray,
    T_first_second: np.ndarray,
    settings: AssociationSettings | None = None,
) -> bool:
    """Whether a transform puts the two robots' cameras on opposite sides of a near-planar set.

    With the summaries' :attr:`~teamslam.association.summary.ObjectSummary.views` (the
    direction from each object to the cameras that saw it), a transform is refused when

    * the pairs ``(rows[k], cols[k])`` are near-planar: with ``n`` the normal of the plane
      fitted to their objects (both maps', the second's under the transform, each weighted by
      ``1 / tr Σ``) and ``h`` the heights above it, every pair satisfies
      ``(hₐ + h_b)² ≤ χ²₃ · nᵀ (Σₐ + R Σ_b Rᵀ) n`` (the set turned over would fit as well);
    * for each robot, the sum of its views along ``n`` over the pairs whose views both robots
      know (at least three; the second's turned by the transform) is clear of zero: squared,
      above ``χ²₁`` times its variance (the views' scatter and the normal's fitted tilt);
    * and the two sums have opposite signs.

    The derivation is on the association concept page. Every number is from the two
    summaries: no unit, no up direction.

    Parameters
    ----------
    first, second
        The two summaries.
    rows, cols
        ``(k,)`` indices of the pairs' objects in ``first`` and ``second``.
    T_first_second
        The transform the pairs imply (``p_first = T · p_second``).
    settings
        The gate and consistency probabilities (default :class:`AssociationSettings`).
    """
    settings = settings or AssociationSettings()
    rows = np.asarray(rows, dtype=np.int64).reshape(-1)
    cols = np.asarray(cols, dtype=np.int64).reshape(-1)
    if first.views is None or second.views is None or rows.size < 3:
        return False
    r = np.asarray(T_first_second, dtype=float)[:3, :3]
    views_a = first.views[rows]
    views_b = second.views[cols] @ r.T
    known = np.any(views_a != 0, axis=1) & np.any(views_b != 0, axis=1)
    if np.count_nonzero(known) < 3:
        return False
    cov_a = first.covs[rows]
    cov_b = r @ second.covs[cols] @ r.T
    both = cov_a + cov_b
    # the plane of the pairs' objects, both maps' (the second's under the transform) weighted
    # as in fit_transform
    points = np.vstack([first.means[rows], second.means[cols] @ r.T + T_first_second[:3, 3]])
    covs = np.concatenate([cov_a, cov_b])
    w = 1.0 / np.maximum(np.trace(covs, axis1=1, axis2=2), np.finfo(float).tiny)
    centre = (w / w.sum()) @ points
    spread = points - centre
    _, axes = np.linalg.eigh((spread * w[:, None]).T @ spread)
    normal, in_plane = axes[:, 0], axes[:, 1:]
    height = spread @ normal
    # the set turned over about its plane (reflected) leaves each pair a residual of the sum
    # of its two heights along the normal: near-planar when that passes the gate
    turned = height[: rows.size] + height[rows.size :]
    if np.any(turned**2 > settings.gate_threshold * (normal @ both @ normal)):
        return False  # not near-planar: the set turned over would not fit
    # the normal's tilt towards each in-plane axis, as fitted: a least-squares slope
    var = np.einsum("i,kij,j->k", normal, covs, normal)
    along = spread @ in_plane  # (2k, 2)
    tilt = 1.0 / np.maximum(np.sum(along**2 / var[:, None], axis=0), np.finfo(float).tiny)
    chi2 = settings.consistency_threshold
    sides = []
    for views in (views_a[known], views_b[known]):
        heights = views @ normal
        up = float(np.sum(heights))
        variance = heights.size * float(np.var(heights, ddof=1))
        variance += float(np.sum(tilt * np.sum(views @ in_plane, axis=0) ** 2))
        if up**2 <= chi2 * variance:
            return False  # the side is not clear
        sides.append(np.sign(up))
    return bool(sides[0] != sides[1])
