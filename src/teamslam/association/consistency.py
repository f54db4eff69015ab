"""Stage 2 of the association: pairwise consistency of correspondences (PCM).

Pairs ``(a, b)`` and ``(a', b')`` are consistent when they name four different objects and the
distances ``‖a − a'‖`` and ``‖b − b'‖`` agree within a ``χ²₁`` test of their variances plus a
drift allowance proportional to the distance (Mangelson et al., ICRA 2018). The graph of all
candidates feeds the maximum clique (:mod:`teamslam.association.clique`); the same test, for a
few pairs against a held set, keeps the pairs a gate adds consistent with it.
"""

from __future__ import annotations

import numpy as np

from teamslam.association.kernels import consistent_pairs
from teamslam.association.settings import AssociationSettings
from teamslam.association.summary import ObjectSummary
from teamslam.errors import InputError

__all__ = ["consistency_graph", "consistent_members", "consistent_with"]


def consistency_graph(
    ia: np.ndarray,
    ib: np.ndarray,
    geo_a: tuple[np.ndarray, np.ndarray],
    geo_b: tuple[np.ndarray, np.ndarray],
    settings: AssociationSettings,
) -> np.ndarray:
    """Pairwise consistency of candidate correspondences ``(ia[p], ib[p])``.

    Parameters
    ----------
    ia, ib
        Indices of each candidate's objects in the first and the second map.
    geo_a, geo_b
        ``(distances, variances)`` within each map (all pairs of its objects).
    settings
        The ``χ²₁`` probability and the drift ratio.

    Returns
    -------
    numpy.ndarray
        ``(m, m)`` boolean, true where candidates ``p`` and ``q`` are consistent: they name four
        different objects and ``(dₐ − d_b)² ≤ χ²₁ · (σₐ² + σ_b² + ρ² d̄²)``.
    """
    dist_a, var_a = (np.asarray(x, dtype=np.float32) for x in geo_a)
    dist_b, var_b = (np.asarray(x, dtype=np.float32) for x in geo_b)
    ia, ib = np.asarray(ia), np.asarray(ib)
    # the compiled test reads without bounds checks: every index and shape is checked here
    for name, index, dist, var in (("ia", ia, dist_a, var_a), ("ib", ib, dist_b, var_b)):
        n = dist.shape[0] if dist.ndim == 2 else -1
        if dist.ndim != 2 or dist.shape != (n, n) or var.shape != (n, n):
            raise InputError(
                f"consistency_graph: the distances and variances of {name}'s map must be square "
                f"and alike, got {dist.shape} and {var.shape}"
            )
        if index.ndim != 1 or (index.size and not np.issubdtype(index.dtype, np.integer)):
            raise InputError(f"consistency_graph: {name} must be a 1-D array of integer indices")
        if index.size and (index.min() < 0 or index.max() >= n):
            raise InputError(f"consistency_graph: {name} has an index outside 0..{n - 1}")
    if ia.shape != ib.shape:
        raise InputError(f"consistency_graph: ia and ib differ in length ({ia.size}, {ib.size})")
    return consistent_pairs(
        np.ascontiguousarray(ia, dtype=np.int64),
        np.ascontiguousarray(ib, dtype=np.int64),
        dist_a,
        var_a,
        dist_b,
        var_b,
        np.float32(0.25 * settings.drift_ratio**2),
        np.float32(settings.consistency_threshold),
    )


def consistent_with(
    first: ObjectSummary,
    second: ObjectSummary,
    rows: np.ndarray,
    cols: np.ndarray,
    held_rows: np.ndarray,
    held_cols: np.ndarray,
    settings: AssociationSettings,
) -> np.ndarray:
    """Pairwise consistency of pairs ``(rows[k], cols[k])`` with pairs ``(held_rows[h],
    held_cols[h])`` — the test of :func:`consistency_graph`, for a few pairs against a set.

    Pairs ``(a, b)`` and ``(a', b')`` are consistent when they name four different objects and
    ``(‖a − a'‖ − ‖b − b'‖)² ≤ χ²₁ · (σₐ² + σ_b² + ρ²/4 · (‖a − a'‖ + ‖b − b'‖)²)``, with
    ``σ²`` each distance's variance along its direction from its map's two covariances.

    Parameters
    ----------
    first, second
        The two summaries.
    rows, cols
        ``(k,)`` indices of the tested pairs' objects in ``first`` and ``second``.
    held_rows, held_cols
        ``(h,)`` indices of the set's pairs.
    settings
        The ``χ²₁`` probability and the drift ratio.

    Returns
    -------
    numpy.ndarray
        ``(k, h)`` boolean.
    """
    rows, cols, held_rows, held_cols = (
        np.asarray(x, dtype=np.int64).reshape(-1) for x in (rows, cols, held_rows, held_cols)
    )
    if rows.shape != cols.shape or held_rows.shape != held_cols.shape:
        raise InputError("consistent_with: the indices of a set of pairs differ in length")

    def distance(summary: ObjectSummary, x: np.ndarray, y: np.ndarray):
        # the (x, y) block of the distances among x and y together (pair_distances), computed
        # alone: each entry as pair_distances computes it, both ways round
        delta = summary.means[x][:, None, :] - summary.means[y][None, :, :]
        dist = np.linalg.norm(delta, axis=2)
        unit = delta / np.maximum(dist, np.finfo(float).tiny)[..., None]
        back = np.ascontiguousarray(-unit.transpose(1, 0, 2))
        along = np.einsum("abi,aij,abj->ab", unit, summary.covs[x], unit)
        along_back = np.einsum("abi,aij,abj->ab", back, summary.covs[y], back)
        return dist, along + along_back.T

    d_a, v_a = distance(first, rows, held_rows)
    d_b, v_b = distance(second, cols, held_cols)
    diff = d_a - d_b
    total = d_a + d_b
    var = v_a + v_b + 0.25 * settings.drift_ratio**2 * total**2
    distinct = (rows[:, None] != held_rows[None, :]) & (cols[:, None] != held_cols[None, :])
    return distinct & (diff**2 <= settings.consistency_threshold * var)


def consistent_members(
    a: ObjectSummary,
    b: ObjectSummary,
    held_rows: np.ndarray,
    held_cols: np.ndarray,
    rows: np.ndarray,
    cols: np.ndarray,
    cost: np.ndarray,
    settings: AssociationSettings,
) -> np.ndarray:
    """Which new pairs keep the held set pairwise consistent, as a consistent set's members are.

    A gate under the held transform tests a pair against the transform alone; a wrong pair
    whose gate is wide in some direction passes it although its distances to the held objects
    disagree between the two maps. Here each new pair must be consistent
    (:func:`consistent_with`) with every held pair and with the new
    pairs taken before it (best gate cost first, ties by index): the table then stays a set of
    pairs whose distances agree two by two.
    """
    with_held = consistent_with(a, b, rows, cols, held_rows, held_cols, settings).all(axis=1)
    among = consistent_with(a, b, rows, cols, rows, cols, settings)
    keep = np.zeros(rows.size, dtype=bool)
    for k in np.argsort(cost, kind="stable"):
        keep[k] = with_held[k] and bool(among[k, keep].all())
    return keep
