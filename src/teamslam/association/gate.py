"""Stages 5 and 6 of the association: every pair gated under a transform, one to one, told apart.

:func:`frame_allowed` and :func:`in_frame` are the test of a pair under the identity when both
maps share one world frame (nothing without it): no pair it refuses is a candidate, and a pair
assigned under a transform that it refuses is dropped.

:func:`gate_pairs` is the ``χ²₃`` Mahalanobis gate under a transform with a drift allowance
growing with the distance from the anchors; :func:`assign` makes the gated pairs one to one;
:func:`distinct` and :func:`alone` drop pairs with a competitor; :func:`separated` drops pairs
whose gate is wide against their objects' spacing. :func:`support` chains them: what a
consistent set gathers under its transform.
"""

from __future__ import annotations

import numpy as np
import scipy.optimize

from teamslam.association.distances import anchor_distance
from teamslam.association.settings import AssociationSettings
from teamslam.association.summary import ObjectSummary
from teamslam.association.transform import consensus_core, fit_transform, rigid_core
from teamslam.gaussian import chi2_quantile

__all__ = [
    "alone",
    "assign",
    "crowd",
    "distinct",
    "frame_allowed",
    "frame_nis",
    "frame_scale",
    "gate_extent",
    "gate_pairs",
    "in_frame",
    "separated",
    "support",
    "told_apart_by_frame",
]


def frame_allowed(
    first: ObjectSummary,
    second: ObjectSummary,
    settings: AssociationSettings,
    top: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray | None:
    """``(n_first, n_second)`` which pairs the maps' shared world frame allows: the ``χ²₃``
    test at :attr:`~teamslam.association.AssociationSettings.frame_probability` of
    ``μₐ − μ_b`` with ``Σₐ + Σ_b`` (``None`` when the maps are not taken to share a frame).
    ``top``: each map's largest covariance eigenvalues when the caller has them."""
    chi2 = settings.frame_threshold
    if chi2 is None:
        return None
    delta = first.means[:, None, :] - second.means[None, :, :]
    sq = np.einsum("abi,abi->ab", delta, delta)
    if top is None:
        top = (first.top_variances(), second.top_variances())
    top_a, top_b = top
    out = np.zeros(sq.shape, dtype=bool)
    ia, ib = np.nonzero(sq <= chi2 * (top_a[:, None] + top_b[None, :]))  # a bound first
    if ia.size:
        s = first.covs[ia] + second.covs[ib]
        d = delta[ia, ib]
        out[ia, ib] = np.einsum("pi,pi->p", d, np.linalg.solve(s, d[:, :, None])[:, :, 0]) <= chi2
    return out


def told_apart_by_frame(
    first: ObjectSummary,
    second: ObjectSummary,
    rows: np.ndarray,
    cols: np.ndarray,
    settings: AssociationSettings,
) -> np.ndarray:
    """Which pairs ``(rows[k], cols[k])`` the shared frame alone identifies: each of the two
    objects the only one of the other map the frame allows for its partner (``False`` for
    every pair when the maps are not taken to share a frame)."""
    frame = frame_allowed(first, second, settings)
    if frame is None or rows.size == 0:
        return np.zeros(rows.size, dtype=bool)
    return frame[rows, cols] & (frame[rows].sum(axis=1) == 1) & (frame[:, cols].sum(axis=0) == 1)


def in_frame(
    first: ObjectSummary,
    second: ObjectSummary,
    rows: np.ndarray,
    cols: np.ndarray,
    settings: AssociationSettings,
) -> np.ndarray:
    """Which pairs ``(rows[k], cols[k])`` the maps' shared frame allows (the test of
    :func:`frame_allowed`; all of them when the maps are not taken to share a frame).

    Applied to pairs already assigned one to one under a transform: a pair the frame refuses is
    dropped, and its objects are not given to another partner instead (the refused partner
    still competes for them in the assignment and the distinctness test)."""
    chi2 = settings.frame_threshold
    if chi2 is None or rows.size == 0:
        return np.ones(rows.size, dtype=bool)
    return frame_nis(first, second, rows, cols) <= chi2


def frame_nis(
    first: ObjectSummary, second: ObjectSummary, rows: np.ndarray, cols: np.ndarray
) -> np.ndarray:
    """``(k,)`` squared Mahalanobis distances under the identity of the pairs
    ``(rows[k], cols[k])``: ``(μₐ − μ_b)ᵀ (Σₐ + Σ_b)⁻¹ (μₐ − μ_b)``, ``χ²₃`` when both maps are
    estimates in one world frame with right marginal covariances."""
    d = first.means[rows] - second.means[cols]
    s = first.covs[rows] + second.covs[cols]
    return np.einsum("pi,pi->p", d, np.linalg.solve(s, d[:, :, None])[:, :, 0])


def frame_scale(nis: np.ndarray) -> float:
    """The factor by which two maps' differences exceed their marginal covariances, learned
    from the :func:`frame_nis` of pairs known to be the same objects: the median of ``nis``
    over the median of ``χ²₃`` (a robust estimate of ``s`` when ``nis ~ s · χ²₃``: a minority of
    wrong pairs moves it little), never below 1 (maps found more consistent than their
    covariances say do not narrow the test)."""
    nis = np.asarray(nis, dtype=float)
    if nis.size == 0:
        return 1.0
    return max(1.0, float(np.median(nis)) / chi2_quantile(0.5, 3))


def gate_pairs(
    first: ObjectSummary,
    second: ObjectSummary,
    T_first_second: np.ndarray,
    anchors_first: np.ndarray,
    anchors_second: np.ndarray,
    settings: AssociationSettings,
) -> tuple[np.ndarray, np.ndarray]:
    """Mahalanobis distances of every pair under a transform, and which pass the ``χ²₃`` gate.

    The innovation covariance of pair ``(a, b)`` is ``Σₐ + R Σ_b Rᵀ + ρ² (rₐ² + r_b²) / 2 · I``,
    with ``rₐ`` (``r_b``) the distance from ``a`` (``b``) to the nearest anchor — a matched
    object — in its own map: the transform holds near the objects it was fitted on, and a map
    deforms with the distance from them.

    Returns
    -------
    mahalanobis, passed
        ``(n_first, n_second)`` squared Mahalanobis distances (``inf`` where not computed) and
        the gate.
    """
    r = T_first_second[:3, :3]
    b_in_a = second.means @ r.T + T_first_second[:3, 3]
    covs_b = r @ second.covs @ r.T
    rho2 = settings.drift_ratio**2
    ra = anchor_distance(first.means, anchors_first)
    rb = anchor_distance(second.means, anchors_second)
    extra = 0.5 * rho2 * (ra[:, None] ** 2 + rb[None, :] ** 2)
    chi2 = settings.gate_threshold
    delta = first.means[:, None, :] - b_in_a[None, :, :]
    sq = np.einsum("abi,abi->ab", delta, delta)
    top_a = first.top_variances()
    top_b = np.linalg.eigvalsh(covs_b)[:, -1]
    bound = top_a[:, None] + top_b[None, :] + extra  # largest eigenvalue of the sum, at most
    near = sq <= chi2 * bound
    out = np.full(sq.shape, np.inf)
    ia, ib = np.nonzero(near)
    if ia.size:
        s = first.covs[ia] + covs_b[ib] + extra[ia, ib][:, None, None] * np.eye(3)
        d = delta[ia, ib]
        out[ia, ib] = np.einsum("pi,pi->p", d, np.linalg.solve(s, d[:, :, None])[:, :, 0])
    if first.classes is not None and second.classes is not None:
        out[first.classes[:, None] != second.classes[None, :]] = np.inf
    return out, out <= chi2


def assign(cost: np.ndarray, passed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one pairs among the gated ones, minimising the total Mahalanobis distance."""
    rows = np.flatnonzero(passed.any(axis=1))
    cols = np.flatnonzero(passed.any(axis=0))
    if rows.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    sub = cost[np.ix_(rows, cols)]
    ok = passed[np.ix_(rows, cols)]
    big = 1e6 * (1.0 + np.max(sub[ok]))
    r, c = scipy.optimize.linear_sum_assignment(np.where(ok, sub, big))
    good = ok[r, c]
    return rows[r[good]], cols[c[good]]


def distinct(
    cost: np.ndarray, rows: np.ndarray, cols: np.ndarray, margin: float
) -> tuple[np.ndarray, np.ndarray]:
    """Keep the assigned pairs with no close competitor (never guess between two objects).

    Pair ``(a, b)`` is dropped when another object ``b'`` of the second map has a cost within
    ``margin`` of ``(a, b)``'s — unless ``b'`` is itself assigned to an object it fits better
    by at least ``margin`` — and likewise for the objects of the first map competing for ``b``.
    """
    if rows.size == 0 or margin <= 0:
        return rows, cols
    best = cost[rows, cols]
    own_col = np.full(cost.shape[1], np.inf)
    own_col[cols] = best
    own_row = np.full(cost.shape[0], np.inf)
    own_row[rows] = best
    k = np.arange(rows.size)
    across = cost[rows]  # rivals for each assigned row: (k, n_second)
    rival = (across < best[:, None] + margin) & ~(own_col[None, :] + margin <= across)
    rival[k, cols] = False
    down = cost[:, cols].T  # rivals for each assigned column: (k, n_first)
    rival_col = (down < best[:, None] + margin) & ~(own_row[None, :] + margin <= down)
    rival_col[k, rows] = False
    keep = ~rival.any(axis=1) & ~rival_col.any(axis=1)
    return rows[keep], cols[keep]


def alone(gated: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Which pairs ``(rows[k], cols[k])`` are alone in each other's gate: no second object of
    either map passes the gate ``gated`` (``(n_first, n_second)`` boolean) with either of the two
    — a gate alone does not choose between two objects."""
    return (gated[rows].sum(axis=1) == 1) & (gated[:, cols].sum(axis=0) == 1)


def separated(
    a: ObjectSummary,
    b: ObjectSummary,
    T_first_second: np.ndarray,
    anchors_first: np.ndarray,
    anchors_second: np.ndarray,
    rows: np.ndarray,
    cols: np.ndarray,
    settings: AssociationSettings,
    extent: np.ndarray | None = None,
) -> np.ndarray:
    """Which pairs ``(rows[k], cols[k])`` have a gate narrower than their objects' spacing.

    The squared longest semi-axis of the pair's ``χ²₃`` gate is ``χ²₃ · λ_max(S)`` with ``S``
    the innovation covariance of :func:`gate_pairs` (bounded above by the sum of the largest
    eigenvalues of its terms); the pair passes when ``separation² · χ²₃ · λ_max(S)`` is at most
    the squared distance from each of its two objects to its nearest neighbour in its own map.
    All distances are the maps' own: no unit enters. ``extent``: the pairs' bounds on
    ``λ_max(S)`` (:func:`gate_extent`) when the caller has them.
    """
    if settings.separation <= 0 or rows.size == 0:
        return np.ones(rows.size, dtype=bool)
    if extent is None:
        extent = gate_extent(
            a, b, T_first_second, anchors_first, anchors_second, rows, cols, settings
        )
    spacing = np.minimum(a.nearest_distances()[rows], b.nearest_distances()[cols])
    return settings.separation**2 * settings.gate_threshold * extent <= spacing**2


def gate_extent(
    a: ObjectSummary,
    b: ObjectSummary,
    T_first_second: np.ndarray,
    anchors_first: np.ndarray,
    anchors_second: np.ndarray,
    rows: np.ndarray,
    cols: np.ndarray,
    settings: AssociationSettings,
) -> np.ndarray:
    """Each pair's bound on ``λ_max(S)`` (:func:`separated`): the sum of its two covariances'
    largest eigenvalues and the drift allowance from the nearest anchors."""
    r = T_first_second[:3, :3]
    top_a = np.linalg.eigvalsh(a.covs[rows])[:, -1]
    top_b = np.linalg.eigvalsh(r @ b.covs[cols] @ r.T)[:, -1]
    ra = anchor_distance(a.means[rows], anchors_first)
    rb = anchor_distance(b.means[cols], anchors_second)
    return top_a + top_b + 0.5 * settings.drift_ratio**2 * (ra**2 + rb**2)


def crowd(
    a: ObjectSummary,
    b: ObjectSummary,
    rows: np.ndarray,
    cols: np.ndarray,
    extent: np.ndarray,
    settings: AssociationSettings,
) -> np.ndarray:
    """How many other objects lie within each pair's gate: of its first object's map within
    the longest semi-axis ``√(χ²₃ · λ_max(S))`` (:func:`separated`) of it, or of the second's
    of it, whichever is more — the neighbours the gate could take for the object.
    ``extent``: the pairs' bounds on ``λ_max(S)`` (:func:`gate_extent`, which
    :func:`separated` uses too)."""
    if rows.size == 0:
        return np.zeros(0, dtype=np.int64)
    reach2 = settings.gate_threshold * extent
    counts = []
    for means, index in ((a.means, rows), (b.means, cols)):
        d2 = np.sum((means[index][:, None] - means[None]) ** 2, axis=2)
        counts.append(np.count_nonzero(d2 <= reach2[:, None], axis=1) - 1)
    return np.maximum(*counts)


def support(
    a: ObjectSummary,
    b: ObjectSummary,
    ca: np.ndarray,
    cb: np.ndarray,
    settings: AssociationSettings,
    looks: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The pairs a consistent set gathers: its transform, the gate, one to one, and again.

    ``looks`` (``(n_a, n_b)``, or ``None``) is added to the Mahalanobis distances where pairs
    are assigned one to one and told apart: ``−2`` times their appearance log likelihood ratio
    (the gate itself stays the positions').

    Returns
    -------
    rows, cols, T_first_second, passed
        Indices of the matched objects, the transform they imply, and the first gate (anchored
        on the set) — what the set's transform accepts.
    """
    # distances alone let a few wrong pairs into a consistent set; keep its rigid core
    core_a, core_b = rigid_core(a, b, ca, cb, settings)
    if core_a.size < settings.min_inliers:
        core_a, core_b = consensus_core(a, b, ca, cb, settings)
    if core_a.size >= 3:
        ca, cb = core_a, core_b
    t = fit_transform(a.means[ca], b.means[cb], a.covs[ca], b.covs[cb])
    cost, passed = gate_pairs(a, b, t, a.means[ca], b.means[cb], settings)
    first_gate = passed
    if looks is not None:
        cost = cost + looks
    rows, cols = assign(cost, passed)
    need = settings.min_inliers
    if rows.size >= need:
        # the core: the gated pairs that fit their refitted transform within their own
        # covariances (each is its own nearest anchor: no drift allowance); as for the set,
        # by a consensus of triples when trimming from a fit dragged off by a wrong pair
        # leaves too few
        core_rows, core_cols = rigid_core(a, b, rows, cols, settings)
        if core_rows.size < need:
            core_rows, core_cols = consensus_core(a, b, rows, cols, settings)
        rows, cols = core_rows, core_cols
    if rows.size >= need:
        # every pair gated again, the drift allowance growing with the distance from the core
        t = fit_transform(a.means[rows], b.means[cols], a.covs[rows], b.covs[cols])
        cost, passed = gate_pairs(a, b, t, a.means[rows], b.means[cols], settings)
        if looks is not None:
            cost = cost + looks
        rows, cols = assign(cost, passed)
        rows, cols = distinct(cost, rows, cols, settings.distinctness)
        if rows.size >= need:
            t = fit_transform(a.means[rows], b.means[cols], a.covs[rows], b.covs[cols])
    return rows, cols, t, first_gate
