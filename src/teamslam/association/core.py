"""Which objects of two robots' maps are the same, without shared ids.

Two neighbours exchange :class:`~teamslam.association.summary.ObjectSummary` s (id, mean,
marginal covariance, optional class per object). Each robot's map is off by its own drift, so
positions alone do not match (on KITTI 00 the separate maps are ~8 m off while parked cars stand
~5 m apart); the *shape* of a group of objects survives drift. :func:`associate` works in six
stages:

1. **Candidates.** Two objects are a candidate pair when their neighbourhoods hold objects that
   can be the same, as a rigid whole (:func:`~teamslam.association.kernels.
   shared_neighbourhood`): among the ``k`` nearest neighbours of each, the neighbour pairs
   whose distances to the two objects agree within their uncertainty, and of those the
   largest set found greedily whose distances to each other agree as well (one to one; the
   most mutually consistent first). Each robot maps neighbours the other has not seen, so the
   two lists differ; a neighbour only one map holds finds no partner and costs nothing, while
   distances that agree by chance rarely agree with each other too. (An earlier rule compared
   the two lists of neighbour distances rank-free but element by element, many to one: chance
   agreements among unrelated neighbours ranked wrong pairs above right ones, and on simulated
   teams two maps sharing six or more objects often had only three to six of them among the
   candidates.) Classes must agree when both maps have them; each object keeps its best few
   candidates, so the consistency graph stays far smaller than all pairs.
2. **Pairwise consistency** (Mangelson et al., "Pairwise Consistency Maximization for Robust
   Multi-Robot Map Merging", ICRA 2018). Correspondences ``(a, b)`` and ``(a', b')`` are
   consistent when ``(‖a − a'‖ − ‖b − b'‖)² / σ² ≤ χ²₁(p)``, where ``σ²`` is the variance of the
   two distances along their directions from both maps' covariances plus a drift allowance
   ``(ρ · d)²``: a unit-free ratio ``ρ`` (:attr:`AssociationSettings.drift_ratio`) of the
   distance — a map's deformation grows with the distance covered, no constant in metres.
3. **The largest mutually consistent sets**: the maximum clique of the consistency graph
   (:func:`~teamslam.association.clique.maximum_clique`, PCM's solver), then the maximum clique
   among the candidates its transform rejects, and so on (:attr:`AssociationSettings.rivals`
   more); each goes through stages 4–5, and the one gathering the most pairs is the answer.
   Distances alone let wrong pairs into it (among clustered objects many distances agree by
   chance, and an object with a long covariance agrees with almost any distance), so its
   *rigid core* is kept: trimmed refitting drops the pairs that do not fit the set's rigid
   transform within their covariances; when that leaves fewer than ``min_inliers`` (a fit on
   all the set's pairs is dragged off by the wrong ones) the core is the largest subset that
   fits the transform of one of its triples (a consensus of triples, then trimmed), and any
   core of three pairs or more fixes the transform of stage 4. When none of these sets gathers
   an answer, each candidate pair with its shared neighbourhood's consistent set (three pairs
   or more, from stage 1) is a seed: the seeds' transforms are ranked by how many objects they
   could gather (a bounding-sphere count) and the best ``rivals + 1`` are judged like the
   consistent sets (:func:`_local_hypotheses`). In young maps the right pairs are often only a
   few of the candidates, a set smaller than chance sets, while the right neighbourhoods
   still hold them.
4. **The relative transform** it implies: weighted Horn / Umeyama (no scale), ``SE(3)``.
5. **Every pair gated under that transform**: Mahalanobis distance with both covariances plus
   the drift allowance ``ρ² (rₐ² + r_b²) / 2`` (``r`` the distance to the nearest anchor pair in
   its own map: the transform holds near the pairs it was fitted on), ``χ²₃`` gate, one to one
   with :func:`scipy.optimize.linear_sum_assignment`. The gated pairs' rigid core becomes the
   anchors of a second gate and assignment, whose pairs are kept when *distinct*: no other
   object of either map fits within :attr:`AssociationSettings.distinctness` of the pair's
   Mahalanobis distance (unless that object fits its own partner clearly better).
6. **Every pair separated from its neighbours**: a pair is kept only when its gate is narrow
   against the spacing of the objects around it — the longest semi-axis of its ``χ²₃`` gate
   ellipsoid, times :attr:`AssociationSettings.separation`, within the nearest-neighbour
   distance of both objects in their own maps. The distinctness test of stage 5 sees only the
   objects both maps hold: when the true partner of an object is missing from the other map (not
   seen yet) and that object's covariance is long (depth poorly observed: standard deviations of
   tens of metres occur on KITTI 00), the neighbour of the missing partner — the next car of the
   row — passes the gate with no rival in sight. The test thins an answer once it has no
   rival, and the pairs :meth:`~teamslam.association.table.CorrespondenceTable.extend` adds;
   an answer left with fewer than ``min_inliers`` pairs is none (``too-few``): pairs that
   cannot be told from their neighbours are no evidence of the transform either (a row of
   such cars with four well-placed objects beside it used to be answered with those four).
   The default 0.5 refuses a pair whose gate reaches twice as far as the nearest other
   object; the pair enters later, once its objects are placed well enough. On KITTI 00 this
   removed 6 of the 9 wrong pairs a run ended with (their gates reached 2.5–36 times the
   spacing).

Never guess: fewer than :attr:`AssociationSettings.min_inliers` pairs (after stage 6), or a
*rival* — another of the sets of stage 3 — whose pairs contradicting the answer number at least
:attr:`AssociationSettings.ambiguity_ratio` times the answer's, give no correspondence. A
regular grid of objects, a row of evenly parked cars, two maps of different places all end
there. Three pairs fix a transform, but in maps as dense and uncertain as KITTI 00's (objects
~5 m apart, marginal standard deviations of metres) chance sets of several pairs (nine seen)
fit one within their covariances; they come with rivals of about their size, so the default
rival threshold is half the answer, and the default minimum six pairs.

**The mirror image of a near-planar group.** Distances cannot tell a near-planar group of
objects from its mirror image, which a proper rotation turning the plane over fits (on a street,
each side's cars matched with the other side's). A consistent set whose transform puts the two
robots' cameras clearly on opposite sides of its plane (:func:`flipped`, from the summaries'
``views``) is neither an answer nor a rival.

Cost: all pairs of objects within each map, ``n_a · n_b · k²`` neighbour comparisons (and the
mutual consistency of the neighbour pairs that agree), ``m²`` consistency tests for ``m``
candidates (a few per object), up to ``rivals + 1`` clique searches and, when they find no
answer, one count of ``m · n_a · n_b`` distances for the seeds. The neighbourhood comparison,
the consistency test, the clique search and the seeds' count are compiled loops
(:mod:`teamslam.association.kernels`, :mod:`teamslam.association.clique`): about ten
milliseconds for maps of a hundred objects (median 13.4 ms of CPU over the 294 full
associations of 15 simulated robots on a ring: ``benchmarks/association.py ring``). At run time
a link runs it when its table is :meth:`~teamslam.association.table.CorrespondenceTable.due`
(no answer yet and new objects, or maps grown markedly since the last run), and grows its table
in between with :meth:`~teamslam.association.table.CorrespondenceTable.extend`
(one gate and one assignment).

Both ends of a link hold the same correspondences
-------------------------------------------------
The rule is a deterministic function of the two summaries, computed in a canonical order: the
summary of the robot with the smaller id always plays the first role, objects are sorted by id,
and every tie (candidate ranking, clique search, assignment) is broken by index. So
``associate(S_i, S_j)`` equals ``associate(S_j, S_i)`` with each pair swapped, bit for bit, and
both robots reach the same table without a further message. A propose/accept exchange would need
a third message round per link and per step, would have to handle a proposal or an acceptance
lost on a lossy link (the two ends then disagree until the next exchange), and would let the
proposing end's choices decide; the shared rule costs only the summaries, which both ends need
anyway, and cannot disagree as long as both ends hold the same two summaries.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.optimize
import scipy.stats

from teamslam.association.clique import maximum_clique
from teamslam.association.kernels import (
    consistent_pairs,
    gathered_objects,
    shared_neighbourhood,
)
from teamslam.association.summary import ObjectSummary
from teamslam.errors import InputError
from teamslam.gaussian import chi2_quantile

__all__ = [
    "AssociationResult",
    "AssociationSettings",
    "associate",
    "consistency_graph",
    "consistent_with",
    "fit_transform",
    "flipped",
    "gate_pairs",
]


@dataclass(frozen=True)
class AssociationSettings:
    """Settings of :func:`associate` (all unit-free).

    Attributes
    ----------
    consistency_probability
        Probability of the ``χ²₁`` test of pairwise distance consistency (and of the descriptor
        comparison).
    gate_probability
        Probability of the ``χ²₃`` Mahalanobis gate of a pair under the relative transform.
    drift_ratio
        Standard deviation of a map's deformation per unit of distance: two objects ``d`` apart
        in one map may be ``d ± ρ·d`` apart in the other beyond what their covariances say.
    neighbours
        Nearest neighbours ``k`` of each object compared for candidates.
    descriptor_matches
        Neighbours two objects must have in common (as a consistent set) to be a candidate
        pair.
    candidates_per_object
        Each object keeps at most this many candidates (its best by descriptor agreement).
    min_inliers
        Fewest pairs that give an answer (at least 3, which fix a transform).
    ambiguity_ratio
        A rival consistent set gathering at least this fraction of the answer's pair count in
        pairs that contradict the answer makes it ambiguous (no correspondence).
    clique_budget
        Search nodes of the exact maximum-clique search (beyond it, the best clique found).
    rivals
        Consistent sets examined after the first (each among the candidates the earlier ones'
        transforms reject); the one gathering the most pairs is the answer, the others its
        rivals.
    distinctness
        A matched pair is kept only when no other object fits within this many units of
        squared Mahalanobis distance (a likelihood ratio of ``exp(distinctness / 2)``).
    separation
        A matched pair is kept only when its gate is narrow against the spacing of the objects
        around it: the longest semi-axis of its ``χ²₃`` gate ellipsoid times ``separation``
        must not exceed the distance from either object to its nearest neighbour in its own
        map. A pair whose gate could hold a neighbour of the true partner — a car of the same
        row, when the true partner is not (yet) in the other map, so no rival is there to be
        seen — is a guess. 0 turns the test off.
    """

    consistency_probability: float = 0.99
    gate_probability: float = 0.99
    drift_ratio: float = 0.05
    neighbours: int = 6
    descriptor_matches: int = 2
    candidates_per_object: int = 3
    min_inliers: int = 6
    ambiguity_ratio: float = 0.5
    clique_budget: int = 2_000
    distinctness: float = 2.0
    rivals: int = 3
    separation: float = 0.5

    def __post_init__(self) -> None:
        for name in ("consistency_probability", "gate_probability"):
            value = getattr(self, name)
            if not 0.0 < value < 1.0:
                raise InputError(f"association setting {name} must be in (0, 1), got {value}")
        if not (np.isfinite(self.drift_ratio) and self.drift_ratio >= 0.0):
            raise InputError(f"association setting drift_ratio must be ≥ 0, got {self.drift_ratio}")
        if not 0.0 < self.ambiguity_ratio <= 1.0:
            raise InputError(
                f"association setting ambiguity_ratio must be in (0, 1], got {self.ambiguity_ratio}"
            )
        for name, low in (
            ("neighbours", 1),
            ("descriptor_matches", 0),
            ("candidates_per_object", 1),
            ("min_inliers", 3),
            ("clique_budget", 1),
            ("rivals", 1),
        ):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < low:
                raise InputError(f"association setting {name} must be an integer ≥ {low}")
        if not (np.isfinite(self.distinctness) and self.distinctness >= 0.0):
            raise InputError(
                f"association setting distinctness must be ≥ 0, got {self.distinctness}"
            )
        if not (np.isfinite(self.separation) and self.separation >= 0.0):
            raise InputError(f"association setting separation must be ≥ 0, got {self.separation}")
        if self.descriptor_matches > self.neighbours:
            raise InputError("association setting descriptor_matches exceeds neighbours")

    @property
    def consistency_threshold(self) -> float:
        """``χ²₁`` quantile of :attr:`consistency_probability`."""
        return chi2_quantile(self.consistency_probability, 1)

    @property
    def gate_threshold(self) -> float:
        """``χ²₃`` quantile of :attr:`gate_probability`."""
        return chi2_quantile(self.gate_probability, 3)


@dataclass(frozen=True)
class AssociationResult:
    """The correspondences between two summaries, as seen from the first.

    Attributes
    ----------
    first, second
        Robot ids of the two summaries (``first`` is the caller's own).
    pairs
        ``(k, 2)`` int64 rows ``(first's id, second's id)``, sorted by the first column; empty
        when there is no answer.
    T_first_second
        ``4 × 4`` transform taking the second map's coordinates into the first's
        (``p_first = T · p_second``), or ``None`` without an answer.
    status
        ``"matched"``, ``"too-few"`` (fewer than ``min_inliers`` consistent pairs, or fewer
        told apart from their neighbours) or ``"ambiguous"`` (a rival set nearly as large).
    candidates
        Number of candidate pairs in the consistency graph.
    clique
        Size of the largest consistent set.
    rival
        Pairs gathered by the best rival set (the largest consistent set among the candidates
        the answer's transform rejects) that contradict the answer; 0 when no rival set has
        ``min_inliers`` members.
    exact
        Whether the clique searches finished within their budget.
    flipped
        Consistent sets refused because their transform puts the second robot's cameras on
        the other side of the set's plane than the first's (the mirror image of a near-planar
        group of objects; see :func:`flipped`).
    clique_pairs
        ``(c, 2)`` the pairs of the largest consistent set (for diagnostics; the answer is
        :attr:`pairs`).
    """

    first: int
    second: int
    pairs: np.ndarray
    T_first_second: np.ndarray | None
    status: str
    candidates: int = 0
    clique: int = 0
    rival: int = 0
    exact: bool = True
    flipped: int = 0
    clique_pairs: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))

    def swapped(self) -> AssociationResult:
        """The same result seen from the second robot."""

        def flip(pairs: np.ndarray) -> np.ndarray:
            out = pairs[:, ::-1].copy()
            return out[np.argsort(out[:, 0], kind="stable")] if out.size else out

        t = self.T_first_second
        return replace(
            self,
            first=self.second,
            second=self.first,
            pairs=flip(self.pairs),
            clique_pairs=flip(self.clique_pairs),
            T_first_second=None if t is None else _inverse(t),
        )

    @property
    def matched(self) -> bool:
        """Whether the association gave correspondences."""
        return self.status == "matched"


def _inverse(t: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = t[:3, :3].T
    out[:3, 3] = -t[:3, :3].T @ t[:3, 3]
    return out


def _distances(means: np.ndarray, covs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All distances within one map and their variances along their directions."""
    delta = means[:, None, :] - means[None, :, :]
    dist = np.linalg.norm(delta, axis=2)
    unit = delta / np.maximum(dist, np.finfo(float).tiny)[..., None]
    # uᵀ Σₐ u for every ordered pair, then the variance of ‖a − a'‖ is uᵀ (Σₐ + Σₐ') u
    along = np.einsum("abi,aij,abj->ab", unit, covs, unit)
    return dist, along + along.T


def _nearest(dist: np.ndarray, k: int) -> np.ndarray:
    """Indices of each object's ``k`` nearest other objects (ascending; ties by index)."""
    n = dist.shape[0]
    k = min(k, n - 1)
    masked = dist + np.diag(np.full(n, np.inf))
    return np.argsort(masked, axis=1, kind="stable")[:, :k]


def _neighbourhoods(
    geo: tuple[np.ndarray, np.ndarray], k: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each object's ``k`` nearest neighbours as float32 tables: distances and variances to
    them ``(n, k)``, and between them ``(n, k, k)`` (the arguments of
    :func:`~teamslam.association.kernels.shared_neighbourhood` for one map)."""
    dist, var = geo
    near = _nearest(dist, k)
    rows = np.arange(dist.shape[0])[:, None]
    pair = (near[:, :, None], near[:, None, :])
    return tuple(
        np.ascontiguousarray(x, dtype=np.float32)
        for x in (dist[rows, near], var[rows, near], dist[pair], var[pair])
    )


def _neighbourhood_sets(
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


def _select_candidates(
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


def _candidates(
    first: ObjectSummary,
    second: ObjectSummary,
    geo_a: tuple[np.ndarray, np.ndarray],
    geo_b: tuple[np.ndarray, np.ndarray],
    settings: AssociationSettings,
) -> tuple[np.ndarray, np.ndarray]:
    """Candidate pairs ``(index in first, index in second)`` by shared neighbourhood."""
    score, mismatch, _ = _neighbourhood_sets(first, second, geo_a, geo_b, settings)
    return _select_candidates(score, mismatch, settings)


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
        # the (x, y) block of the distances among x and y together (_distances)
        both = np.concatenate([x, y])
        dist, var = _distances(summary.means[both], summary.covs[both])
        return dist[: x.size, x.size :], var[: x.size, x.size :]

    d_a, v_a = distance(first, rows, held_rows)
    d_b, v_b = distance(second, cols, held_cols)
    diff = d_a - d_b
    total = d_a + d_b
    var = v_a + v_b + 0.25 * settings.drift_ratio**2 * total**2
    distinct = (rows[:, None] != held_rows[None, :]) & (cols[:, None] != held_cols[None, :])
    return distinct & (diff**2 <= settings.consistency_threshold * var)


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
    return _horn(a[None], b[None], w[None])[0]


def _horn(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted Horn / Umeyama of a batch: ``(T, k, 3)`` points, ``(T, k)`` weights →
    ``(T, 4, 4)`` transforms with ``a ≈ R b + t``."""
    w = (w / w.sum(axis=1, keepdims=True))[:, None, :]
    ca = (w @ a)[:, 0]
    cb = (w @ b)[:, 0]
    h = np.swapaxes(b - cb[:, None], 1, 2) @ ((a - ca[:, None]) * np.swapaxes(w, 1, 2))
    u, _, vt = np.linalg.svd(h)
    v = np.swapaxes(vt, 1, 2)
    d = np.sign(np.linalg.det(v @ np.swapaxes(u, 1, 2)))
    d[d == 0] = 1.0
    fix = np.broadcast_to(np.eye(3), h.shape).copy()
    fix[:, 2, 2] = d
    r = v @ fix @ np.swapaxes(u, 1, 2)
    out = np.broadcast_to(np.eye(4), (h.shape[0], 4, 4)).copy()
    out[:, :3, :3] = r
    out[:, :3, 3] = ca - (r @ cb[:, :, None])[:, :, 0]
    return out


def _anchor_distance(means: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """Distance from each object to its nearest anchor (a matched object) of the same map."""
    return np.min(np.linalg.norm(means[:, None] - anchors[None], axis=2), axis=1)


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
    ra = _anchor_distance(first.means, anchors_first)
    rb = _anchor_distance(second.means, anchors_second)
    extra = 0.5 * rho2 * (ra[:, None] ** 2 + rb[None, :] ** 2)
    chi2 = settings.gate_threshold
    delta = first.means[:, None, :] - b_in_a[None, :, :]
    sq = np.einsum("abi,abi->ab", delta, delta)
    top_a = np.linalg.eigvalsh(first.covs)[:, -1]
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


def _assign(cost: np.ndarray, passed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


def _distinct(
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


def _alone(gated: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Which pairs ``(rows[k], cols[k])`` are alone in each other's gate: no second object of
    either map passes the gate ``gated`` (``(n_first, n_second)`` boolean) with either of the two
    — a gate alone does not choose between two objects."""
    return (gated[rows].sum(axis=1) == 1) & (gated[:, cols].sum(axis=0) == 1)


def _consistent_members(
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
    (:func:`~teamslam.association.core.consistent_with`) with every held pair and with the new
    pairs taken before it (best gate cost first, ties by index): the table then stays a set of
    pairs whose distances agree two by two.
    """
    with_held = consistent_with(a, b, rows, cols, held_rows, held_cols, settings).all(axis=1)
    among = consistent_with(a, b, rows, cols, rows, cols, settings)
    keep = np.zeros(rows.size, dtype=bool)
    for k in np.argsort(cost, kind="stable"):
        keep[k] = with_held[k] and bool(among[k, keep].all())
    return keep


def _nearest_neighbour(means: np.ndarray) -> np.ndarray:
    """Distance from each object to its nearest other object of the same map (``inf``: alone)."""
    d2 = np.einsum("abi,abi->ab", means[:, None] - means[None], means[:, None] - means[None])
    np.fill_diagonal(d2, np.inf)
    return np.sqrt(d2.min(axis=1)) if means.shape[0] else np.zeros(0)


def _separated(
    a: ObjectSummary,
    b: ObjectSummary,
    T_first_second: np.ndarray,
    anchors_first: np.ndarray,
    anchors_second: np.ndarray,
    rows: np.ndarray,
    cols: np.ndarray,
    settings: AssociationSettings,
) -> np.ndarray:
    """Which pairs ``(rows[k], cols[k])`` have a gate narrower than their objects' spacing.

    The squared longest semi-axis of the pair's ``χ²₃`` gate is ``χ²₃ · λ_max(S)`` with ``S``
    the innovation covariance of :func:`gate_pairs` (bounded above by the sum of the largest
    eigenvalues of its terms); the pair passes when ``separation² · χ²₃ · λ_max(S)`` is at most
    the squared nearest-neighbour distance of either object in its own map. All distances are
    the maps' own: no unit enters.
    """
    if settings.separation <= 0 or rows.size == 0:
        return np.ones(rows.size, dtype=bool)
    r = T_first_second[:3, :3]
    top_a = np.linalg.eigvalsh(a.covs[rows])[:, -1]
    top_b = np.linalg.eigvalsh(r @ b.covs[cols] @ r.T)[:, -1]
    ra = _anchor_distance(a.means[rows], anchors_first)
    rb = _anchor_distance(b.means[cols], anchors_second)
    extent = top_a + top_b + 0.5 * settings.drift_ratio**2 * (ra**2 + rb**2)
    spacing = np.minimum(_nearest_neighbour(a.means)[rows], _nearest_neighbour(b.means)[cols])
    return settings.separation**2 * settings.gate_threshold * extent <= spacing**2


def _canonical_key(summary: ObjectSummary) -> int:
    return summary.robot


def associate(
    first: ObjectSummary,
    second: ObjectSummary,
    settings: AssociationSettings | None = None,
) -> AssociationResult:
    """Correspondences between two robots' objects, from their summaries alone.

    See the module docstring for the method. The result depends only on the two summaries, not
    on their order: ``associate(b, a)`` is ``associate(a, b).swapped()``.

    Parameters
    ----------
    first
        The caller's own summary.
    second
        The neighbour's summary.
    settings
        Thresholds (default :class:`AssociationSettings`).

    Returns
    -------
    AssociationResult
        Pairs ``(first's id, second's id)`` and the transform they imply, or no pair with the
        reason (``too-few``, ``ambiguous``).
    """
    settings = settings or AssociationSettings()
    if not isinstance(first, ObjectSummary) or not isinstance(second, ObjectSummary):
        raise InputError("associate takes two ObjectSummary")
    if first.robot == second.robot:
        raise InputError(
            f"associate needs the summaries of two robots, both are robot {first.robot}'s"
        )
    if _canonical_key(second) < _canonical_key(first):
        return _associate(second.sorted(), first.sorted(), settings).swapped()
    return _associate(first.sorted(), second.sorted(), settings)


def _no_answer(a: ObjectSummary, b: ObjectSummary, status: str, **counts) -> AssociationResult:
    return AssociationResult(a.robot, b.robot, np.zeros((0, 2), np.int64), None, status, **counts)


def _associate(
    a: ObjectSummary, b: ObjectSummary, settings: AssociationSettings
) -> AssociationResult:
    need = settings.min_inliers
    if len(a) < need or len(b) < need:
        return _no_answer(a, b, "too-few")
    geo_a = _distances(a.means, a.covs)
    geo_b = _distances(b.means, b.covs)
    score, mismatch, members = _neighbourhood_sets(a, b, geo_a, geo_b, settings)
    ia, ib = _select_candidates(score, mismatch, settings)
    graph = consistency_graph(ia, ib, geo_a, geo_b, settings)
    # the largest consistent sets, one after another: each next one among the candidates that
    # the transforms of the earlier ones reject; each judged by the pairs its transform gathers
    pool = np.ones(ia.size, dtype=bool)
    found = []  # (rows, cols, transform, clique pairs, clique indices)
    exact = True
    refused = 0
    for _ in range(settings.rivals + 1):
        index = np.flatnonzero(pool)
        clique, done = maximum_clique(
            graph[np.ix_(index, index)], settings.clique_budget, lower_bound=need - 1
        )
        exact = exact and done
        if clique.size < need:
            break
        ca, cb = ia[index[clique]], ib[index[clique]]
        rows, cols, t, passed = _support(a, b, ca, cb, settings)
        pool[index[clique]] = False
        pool &= ~passed[ia, ib]
        if rows.size >= need and flipped(a, b, rows, cols, t, settings):
            refused += 1  # the mirror image of a near-planar group: neither answer nor rival
            continue
        found.append((rows, cols, t, np.column_stack([a.ids[ca], b.ids[cb]]), (ca, cb)))
    if not any(f[0].size >= need for f in found):
        # no consistent set gathered an answer: the candidates' own neighbourhoods as seeds
        local, flips = _local_hypotheses(a, b, ia, ib, members, geo_a, geo_b, found, settings)
        found += local
        refused += flips
    counts = {
        "candidates": int(ia.size),
        "clique": int(found[0][3].shape[0]) if found else 0,
        "flipped": refused,
    }
    if not found:
        return _no_answer(a, b, "too-few", exact=exact, **counts)
    # the answer: the set gathering the most pairs (the first found among equals)
    best = max(range(len(found)), key=lambda k: (found[k][0].size, -k))
    rows, cols, t, clique_pairs, (ca, cb) = found[best]
    counts["clique"] = int(clique_pairs.shape[0])
    held = set(zip(rows.tolist(), cols.tolist(), strict=True))
    # a rival: another set whose pairs contradict the answer's (pairs it does not hold)
    counts["rival"] = max(
        (
            sum(
                (r, c) not in held
                for r, c in zip(other[0].tolist(), other[1].tolist(), strict=True)
            )
            for k, other in enumerate(found)
            if k != best
        ),
        default=0,
    )
    if counts["rival"] >= max(settings.ambiguity_ratio * rows.size, need):
        return _no_answer(a, b, "ambiguous", exact=exact, **counts)
    # the answer's pairs too loosely placed to tell from a neighbour are left out; what is
    # left must still be an answer
    ok = _separated(a, b, t, a.means[rows], b.means[cols], rows, cols, settings)
    if np.count_nonzero(ok) < need:
        return _no_answer(a, b, "too-few", exact=exact, **counts)
    rows, cols = rows[ok], cols[ok]
    rows, cols = _beyond_the_clique(a, b, rows, cols, ca, cb, t, settings)
    if rows.size < need:
        # the pairs the gate added beyond the consistent set that disagree with it are gone;
        # what is left is held to the same minimum as every answer
        return _no_answer(a, b, "too-few", exact=exact, **counts)
    pairs = np.column_stack([a.ids[rows], b.ids[cols]])
    pairs = pairs[np.argsort(pairs[:, 0], kind="stable")]
    return AssociationResult(
        a.robot,
        b.robot,
        pairs,
        t,
        "matched",
        exact=exact,
        clique_pairs=clique_pairs[np.argsort(clique_pairs[:, 0], kind="stable")],
        **counts,
    )


def _local_hypotheses(
    a: ObjectSummary,
    b: ObjectSummary,
    ia: np.ndarray,
    ib: np.ndarray,
    members: np.ndarray,
    geo_a: tuple[np.ndarray, np.ndarray],
    geo_b: tuple[np.ndarray, np.ndarray],
    found: list,
    settings: AssociationSettings,
) -> tuple[list, int]:
    """Consistent sets seeded by the candidates' neighbourhoods, for a link whose largest
    consistent sets gathered no answer.

    In young maps the right pairs are often a few among the candidates (each object keeps its
    best few, and a neighbour only one map holds pushes a right pair out), so they form a set
    smaller than chance sets among hundreds of candidates, and the largest sets examined are
    chance ones whose transforms gather too few pairs. Every candidate pair, with its shared
    neighbourhood's consistent set of neighbour pairs (three pairs or more), fixes a transform;
    the transforms are ranked by an upper bound on the objects they could gather
    (:func:`~teamslam.association.kernels.gathered_objects`), and the best ``rivals + 1`` whose
    seed is not already gathered by an earlier one go through :func:`_support` like a
    consistent set. What makes an answer is unchanged: the sets found here are judged with
    the others — the most pairs gathered, rivals, separation and the consistency of the added
    pairs — and need ``min_inliers`` pairs like any answer.

    Returns
    -------
    sets, refused
        Entries for ``found`` (as in :func:`_associate`), and the number refused as mirror
        images (:func:`flipped`).
    """
    need = settings.min_inliers
    k = settings.neighbours
    if ia.size == 0:
        return [], 0
    mem = members[ia, ib]  # (h, k): i · k_b + j, -1 beyond the set
    valid = mem >= 0
    score_ok = valid.sum(axis=1) >= 2  # with the anchor, three pairs fix a transform
    if not score_ok.any():
        return [], 0
    xs, ys, mem, valid = ia[score_ok], ib[score_ok], mem[score_ok], valid[score_ok]
    near_a, near_b = _nearest(geo_a[0], k), _nearest(geo_b[0], k)
    k_b = near_b.shape[1]  # fewer than k in a map of k objects or fewer
    slot_a, slot_b = np.where(valid, mem // k_b, 0), np.where(valid, mem % k_b, 0)
    rows = np.concatenate([xs[:, None], near_a[xs[:, None], slot_a]], axis=1)
    cols = np.concatenate([ys[:, None], near_b[ys[:, None], slot_b]], axis=1)
    weight = np.concatenate([np.ones((xs.size, 1)), valid.astype(float)], axis=1)
    t = _horn(a.means[rows], b.means[cols], weight)
    reach = gathered_objects(
        np.ascontiguousarray(t[:, :3, :3]),
        np.ascontiguousarray(t[:, :3, 3]),
        a.means,
        b.means,
        np.linalg.eigvalsh(a.covs)[:, -1],
        np.linalg.eigvalsh(b.covs)[:, -1],
        settings.gate_threshold,
    )
    explained = np.zeros((len(a), len(b)), dtype=bool)
    for rows_f, cols_f, *_ in found:
        explained[rows_f, cols_f] = True
    out, refused = [], 0
    for h in np.lexsort((np.arange(reach.size), -reach)):  # most reach first, ties by order
        if reach[h] < need or len(out) + refused > settings.rivals:
            break
        if explained[xs[h], ys[h]]:
            continue
        seed = weight[h] > 0
        ca, cb = rows[h][seed], cols[h][seed]
        got_rows, got_cols, t_h, passed = _support(a, b, ca, cb, settings)
        explained |= passed
        if got_rows.size >= need and flipped(a, b, got_rows, got_cols, t_h, settings):
            refused += 1
            continue
        out.append((got_rows, got_cols, t_h, np.column_stack([a.ids[ca], b.ids[cb]]), (ca, cb)))
    return out, refused


def flipped(
    first: ObjectSummary,
    second: ObjectSummary,
    rows: np.ndarray,
    cols: np.ndarray,
    T_first_second: np.ndarray,
    settings: AssociationSettings | None = None,
) -> bool:
    """Whether a transform puts the two robots' cameras on opposite sides of a near-planar set.

    Distances cannot tell a near-planar group of objects from its mirror image, and the mirror
    image of a plane is the plane turned over: a proper rotation (a half-turn about an axis in
    the plane) fits pairs that match each object with its mirror image's — on a street, the cars
    of one side with those of the other. The cameras can tell: a robot sees objects from one side
    of their plane (ground robots, drones and hand-held cameras are not inside the plane of the
    objects they see), and both robots saw the same objects from the same side. With the
    summaries' :attr:`~teamslam.association.summary.ObjectSummary.views` (the direction from
    each object to the cameras that saw it), a transform is refused when

    * the pairs ``(rows[k], cols[k])`` are near-planar: reflected about the plane fitted to
      their objects (both maps', the second's under the transform, weighted by their
      variances), they would still pass the ``χ²₃`` gate — each pair's two heights above the
      plane, summed (the reflection's residual along the normal ``n``), satisfy
      ``(hₐ + h_b)² ≤ χ²₃ · nᵀ S n`` with ``S`` the pair's innovation covariance (a set that
      is not near-planar is never refused: its side is no matter of a mirror image);
    * for each robot, the views' component along the plane's normal (the sine of the angle
      the cameras looked down or up at the objects), summed over the pairs whose views both
      robots know (the second robot's turned by the transform), is clear of zero: squared,
      above ``χ²₁`` times its variance — the pairs' own scatter about their mean, and the
      normal's uncertainty from the fit (its tilt towards each in-plane axis) times the views'
      sum along that axis;
    * and the two heights have opposite signs.

    Every number is from the two summaries: no unit, no up direction. Computed in the canonical
    order of :func:`associate`, it is the same on both ends of a link.

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


def _support(
    a: ObjectSummary,
    b: ObjectSummary,
    ca: np.ndarray,
    cb: np.ndarray,
    settings: AssociationSettings,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The pairs a consistent set gathers: its transform, the gate, one to one, and again.

    Returns
    -------
    rows, cols, T_first_second, passed
        Indices of the matched objects, the transform they imply, and the first gate (anchored
        on the set) — what the set's transform accepts.
    """
    # distances alone let a few wrong pairs into a consistent set; keep its rigid core
    core_a, core_b = _core(a, b, ca, cb, settings)
    if core_a.size < settings.min_inliers:
        core_a, core_b = _consensus_core(a, b, ca, cb, settings)
    if core_a.size >= 3:
        ca, cb = core_a, core_b
    t = fit_transform(a.means[ca], b.means[cb], a.covs[ca], b.covs[cb])
    cost, passed = gate_pairs(a, b, t, a.means[ca], b.means[cb], settings)
    first_gate = passed
    rows, cols = _assign(cost, passed)
    need = settings.min_inliers
    if rows.size >= need:
        # the core: the gated pairs that fit their refitted transform within their own
        # covariances (each is its own nearest anchor: no drift allowance); as for the set,
        # by a consensus of triples when trimming from a fit dragged off by a wrong pair
        # leaves too few
        core_rows, core_cols = _core(a, b, rows, cols, settings)
        if core_rows.size < need:
            core_rows, core_cols = _consensus_core(a, b, rows, cols, settings)
        rows, cols = core_rows, core_cols
    if rows.size >= need:
        # every pair gated again, the drift allowance growing with the distance from the core
        t = fit_transform(a.means[rows], b.means[cols], a.covs[rows], b.covs[cols])
        cost, passed = gate_pairs(a, b, t, a.means[rows], b.means[cols], settings)
        rows, cols = _assign(cost, passed)
        rows, cols = _distinct(cost, rows, cols, settings.distinctness)
        if rows.size >= need:
            t = fit_transform(a.means[rows], b.means[cols], a.covs[rows], b.covs[cols])
    return rows, cols, t, first_gate


def _beyond_the_clique(
    a: ObjectSummary,
    b: ObjectSummary,
    rows: np.ndarray,
    cols: np.ndarray,
    clique_rows: np.ndarray,
    clique_cols: np.ndarray,
    T_first_second: np.ndarray,
    settings: AssociationSettings,
) -> tuple[np.ndarray, np.ndarray]:
    """The answer's pairs, those the gate added beyond the consistent set held to the consistency
    test of an extension (:meth:`~teamslam.association.CorrespondenceTable.extend`).

    The consistent set's pairs in the answer stay. A pair the gate added is kept when it is
    consistent two by two with the set's pairs and the added pairs kept before it, best gate
    cost first (:func:`_consistent_members`): a gate under the set's transform tests a pair
    against the transform alone, and a wrong pair whose gate is wide in some direction passes it
    although its distances to the set's objects disagree between the two maps.

    The extension's other test, both objects alone in each other's gate (:func:`_alone`), is not
    applied here. Measured on KITTI 00 with per-robot ids (``teamslam run --association own``):
    with it, the pairs full associations add beyond their consistent sets fall from 27 wrong and
    36 right (per end of the links) to 16 and 18, the RMSE from 7.724 to 7.687 m, the revoked
    pairs from 37 to 26, but recall from 0.739 to 0.719; without it (this rule) 25 wrong and 36
    right, RMSE, recall and held pairs as before, 35 revoked.
    """
    if rows.size == 0:
        return rows, cols
    in_clique = np.zeros((len(a), len(b)), dtype=bool)
    in_clique[clique_rows, clique_cols] = True
    member = in_clique[rows, cols]
    added = np.flatnonzero(~member)
    if added.size == 0:
        return rows, cols
    r, c = rows[added], cols[added]
    # the order of the added pairs: their Mahalanobis distance under the answer's transform
    cost = _pair_nis(a, b, r, c, T_first_second)
    ok = _consistent_members(a, b, rows[member], cols[member], r, c, cost, settings)
    keep = member.copy()
    keep[added[ok]] = True
    return rows[keep], cols[keep]


def _pair_nis(
    a: ObjectSummary, b: ObjectSummary, rows: np.ndarray, cols: np.ndarray, T_first_second
) -> np.ndarray:
    """Each pair's ``χ²₃`` statistic under a transform: ``νᵀ S⁻¹ ν`` with ``ν = a − (R b + t)``
    and ``S = Σ_a + R Σ_b Rᵀ`` (no drift allowance). ``(k,)``."""
    rot = T_first_second[:3, :3]
    nu = a.means[rows] - (b.means[cols] @ rot.T + T_first_second[:3, 3])
    s = a.covs[rows] + rot @ b.covs[cols] @ rot.T
    return np.einsum("ki,ki->k", nu, np.linalg.solve(s, nu[:, :, None])[:, :, 0])


#: Triples of a consistent set's pairs that :func:`_consensus_core` tries, at most
_TRIPLES = 2_000


def _consensus_core(
    a: ObjectSummary,
    b: ObjectSummary,
    rows: np.ndarray,
    cols: np.ndarray,
    settings: AssociationSettings,
) -> tuple[np.ndarray, np.ndarray]:
    """The pairs of a consistent set that fit one rigid transform, by consensus of triples.

    When wrong pairs that fit the distances only thanks to a long covariance are many in a set,
    and some of them are precisely placed, no transform fitted on all its pairs fits the right
    ones, and trimming from it (:func:`_core`) ends with too few. Here every triple of the set's
    pairs (a deterministic sample of :data:`_TRIPLES` when there are more) fixes a transform;
    the one under which the most pairs pass the ``χ²₃`` gate within their own covariances wins,
    ties by the order of the triples, and its pairs are trimmed by :func:`_core`.
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
    t = _horn(ma[triples], mb[triples], w[triples])  # (T, 4, 4)
    r = t[:, :3, :3]
    nu = ma[None] - (np.einsum("tij,kj->tki", r, mb) + t[:, None, :3, 3])
    s = sa[None] + np.einsum("tij,kjl,tml->tkim", r, sb, r)
    nis = np.einsum("tki,tki->tk", nu, np.linalg.solve(s, nu[..., None])[..., 0])
    inliers = nis <= settings.gate_threshold
    best = int(np.argmax(inliers.sum(axis=1)))
    keep = inliers[best]
    return _core(a, b, rows[keep], cols[keep], settings)


def _core(
    a: ObjectSummary,
    b: ObjectSummary,
    rows: np.ndarray,
    cols: np.ndarray,
    settings: AssociationSettings,
) -> tuple[np.ndarray, np.ndarray]:
    """The pairs that fit their own rigid transform within their covariances (no allowance).

    Trimmed refitting: fit, drop the pairs far outside the gate (four times its threshold) or
    else the worst one, refit, until every pair left passes — a few wrong pairs in the
    consistent set cannot drag the transform away from the right ones.
    """
    gate = settings.gate_threshold
    while rows.size >= settings.min_inliers:
        t = fit_transform(a.means[rows], b.means[cols], a.covs[rows], b.covs[cols])
        nis = _pair_nis(a, b, rows, cols, t)
        if nis.max() <= gate:
            break
        far = nis > 4.0 * gate
        keep = ~far if far.any() and not far.all() else np.arange(rows.size) != np.argmax(nis)
        rows, cols = rows[keep], cols[keep]
    return rows, cols
