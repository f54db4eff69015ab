"""Which objects of two robots' maps are the same, without shared ids: :func:`associate`.

The stages in order — candidates (:mod:`~teamslam.association.candidates`), pairwise consistency
(:mod:`~teamslam.association.consistency`), the largest consistent sets
(:mod:`~teamslam.association.clique`), their transforms (:mod:`~teamslam.association.transform`)
and gates (:mod:`~teamslam.association.gate`), the mirror test (:mod:`~teamslam.association.
mirror`) and the seeds (:mod:`~teamslam.association.seeds`) — give an answer of at least
``min_inliers`` pairs, or none (``too-few``, ``ambiguous``): never a guess. When both summaries
carry appearance and the link's learned appearance model is informative
(:mod:`~teamslam.association.appearance`), candidates are also drawn by appearance and class, pairs
that look different at the gate's odds are vetoed, and an answer may hold as few as three pairs
if their appearance is beyond what chance look-alikes give at ``consistency_probability``. Before
the model is informative (no sample yet of the same object) the same bound holds for the rarity
of the resemblance among different objects (:func:`~teamslam.association.appearance.rarity`),
and the answer's pairs then teach the model. What position alone answers stands when appearance
gives no answer, without vetoed pairs. When no consistent set answers and the two maps share
one world frame (``frame_probability``), the pairs the frame allows that look alike beyond
chance among all it allows are the answer one by one (:func:`identified_by_frame`), with the
identity as transform. Without appearance, or with appearance that separates nothing, the rules
are exactly those above. The
result is a deterministic function of the two summaries in a canonical order (the smaller robot
id first, objects by id, ties by index), so both ends of a link hold the same correspondences.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from teamslam.association.appearance import (
    beyond_chance,
    chance_tail,
    cosine_distances,
    link_model,
    rare_triples,
    rarity,
    unit_rows,
)
from teamslam.association.candidates import (
    appearance_candidates,
    neighbourhood_sets,
    select_candidates,
)
from teamslam.association.clique import maximum_clique
from teamslam.association.consistency import consistency_graph, consistent_members
from teamslam.association.distances import pair_distances
from teamslam.association.gate import (
    crowd,
    frame_allowed,
    gate_extent,
    in_frame,
    separated,
    support,
    told_apart_by_frame,
)
from teamslam.association.mirror import flipped
from teamslam.association.seeds import seed_sets
from teamslam.association.settings import AssociationSettings
from teamslam.association.summary import ObjectSummary
from teamslam.association.transform import fit_transform, pair_nis
from teamslam.errors import InputError
from teamslam.geometry import se3

__all__ = ["AssociationResult", "associate", "identified_by_frame"]


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
        Size of the consistent set behind the answer (without an answer, of the first set
        examined: the maximum clique of all candidates).
    rival
        Most pairs gathered by another set examined (a rival) that the answer does not hold;
        0 without another set. The answer is refused as ambiguous when this reaches
        ``ambiguity_ratio`` times its pairs and ``min_inliers``.
    exact
        Whether the clique searches finished within their budget.
    flipped
        Consistent sets refused because their transform puts the second robot's cameras on
        the other side of the set's plane than the first's (the mirror image of a near-planar
        group of objects; see :func:`flipped`).
    clique_pairs
        ``(c, 2)`` the pairs of the consistent set behind the answer (for diagnostics; the
        answer is :attr:`pairs`).
    gathered
        ``(g, 2)`` the pairs the answer's consistent set gathered under its transform, before
        the maps' shared frame dropped those it refuses (identified by shape, not by the frame:
        a link's table learns the frame's scale from them,
        :meth:`~teamslam.association.CorrespondenceTable.merge`); empty without an answer.
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
    gathered: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))

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
            gathered=flip(self.gathered),
            T_first_second=None if t is None else se3.inverse(t),
        )

    @property
    def matched(self) -> bool:
        """Whether the association gave correspondences."""
        return self.status == "matched"


def _canonical_key(summary: ObjectSummary) -> int:
    return summary.robot


def associate(
    first: ObjectSummary,
    second: ObjectSummary,
    settings: AssociationSettings | None = None,
    held: np.ndarray | None = None,
    history: FrameHistory | None = None,
) -> AssociationResult:
    """Correspondences between two robots' objects, from their summaries alone.

    The stages are those of the module docstring (their reasons: the association concept
    page). The result depends only on the two summaries, not on their order:
    ``associate(b, a)`` is ``associate(a, b).swapped()``.

    Parameters
    ----------
    first
        The caller's own summary.
    second
        The neighbour's summary.
    settings
        Thresholds (default :class:`AssociationSettings`).
    held
        ``(h, 2)`` pairs ``(first's id, second's id)`` the link already holds: samples of the
        *same* appearance (read only when both summaries carry appearance).
    history
        The link's decisions one by one in the shared frame over its run, pairs in the order of
        the robots' ids (:class:`FrameHistory`, updated when single pairs are tried): an answer
        of single pairs is then held to the link's run-long bound, as its extensions'.

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
    if held is not None:
        held = np.asarray(held, dtype=np.int64).reshape(-1, 2)
    if _canonical_key(second) < _canonical_key(first):
        swapped = None if held is None else held[:, ::-1]
        return _associate(second.sorted(), first.sorted(), settings, swapped, history).swapped()
    return _associate(first.sorted(), second.sorted(), settings, held, history)


def _no_answer(a: ObjectSummary, b: ObjectSummary, status: str, **counts) -> AssociationResult:
    return AssociationResult(a.robot, b.robot, np.zeros((0, 2), np.int64), None, status, **counts)


def _associate(
    a: ObjectSummary,
    b: ObjectSummary,
    settings: AssociationSettings,
    held: np.ndarray | None = None,
    history: FrameHistory | None = None,
) -> AssociationResult:
    model = None
    if a.appearance is not None and b.appearance is not None:
        model = link_model(a, b, held, settings.consistency_probability)
    if model is None:
        return _by_position(a, b, settings)
    result = _by_sets(a, b, settings, model)
    if result.matched or settings.frame_probability is None:
        return result
    # no consistent set answers: the maps' shared frame is a known transform, and a pair it
    # allows that looks alike beyond chance among every pair it allows is the same object
    framed = _by_frame(a, b, settings, model if model.informative else rarity(model), history)
    return result if framed is None else framed


def _by_sets(
    a: ObjectSummary, b: ObjectSummary, settings: AssociationSettings, model
) -> AssociationResult:
    """The answer of the consistent sets with appearance ``model`` (the link's, informative or
    not)."""
    if model.informative:
        result = _with_appearance(a, b, settings, model)
        if result.matched:
            return result
        # appearance weighs the sets by position too; what position alone answers stands,
        # without the pairs that look different at the gate's odds
        return _unless_vetoed(a, b, _by_position(a, b, settings), model, settings)
    # no sample yet of how the same object looks (a link's first answer): a resemblance
    # counts by how rarely different objects show it, when it can be rare enough at all
    rare = rarity(model)
    if not rare_triples(rare, max(len(a), len(b)), settings.consistency_probability):
        return _by_position(a, b, settings)
    result = _with_appearance(a, b, settings, rare, likelihood=False)
    if not result.matched:
        # rarity only adds evidence for a set, never against one: what position alone answers
        # stands (with three pairs allowed its rival test is stricter than position's)
        return _by_position(a, b, settings)
    # the answer's pairs alike beyond chance on their own are the link's first samples of the
    # same object: with them the likelihood ratio is learned, and the answer is the one it
    # gives (its veto included: a pair gathered by position that looks nothing alike goes)
    rows = np.searchsorted(a.ids, result.pairs[:, 0])
    cols = np.searchsorted(b.ids, result.pairs[:, 1])
    d = np.einsum("pd,pd->p", unit_rows(a.appearance[rows]), unit_rows(b.appearance[cols]))
    alike = beyond_chance(
        rare, rare.log_ratio(1.0 - d), max(len(a), len(b)), settings.consistency_probability
    )
    model = link_model(a, b, result.pairs[alike], settings.consistency_probability)
    if not model.informative:
        return result
    learned = _with_appearance(a, b, settings, model)
    return learned if learned.matched else _unless_vetoed(a, b, result, model, settings)


def _by_frame(
    a: ObjectSummary,
    b: ObjectSummary,
    settings: AssociationSettings,
    model,
    history: FrameHistory | None = None,
) -> AssociationResult | None:
    """The pairs the maps' shared frame and appearance identify one by one
    (:func:`identified_by_frame`) as an answer with the identity as its transform, or ``None``
    when there are none."""
    rows, cols, hypotheses = identified_by_frame(a, b, settings, model, history=history)
    if rows.size == 0:
        return None
    pairs = np.column_stack([a.ids[rows], b.ids[cols]])
    pairs = pairs[np.argsort(pairs[:, 0], kind="stable")]
    return AssociationResult(
        a.robot, b.robot, pairs, np.eye(4), "matched", candidates=hypotheses, clique=len(pairs)
    )


@dataclass
class FrameHistory:
    """What one link has decided one by one in the shared frame over its run
    (:func:`identified_by_frame`): every pair (first map's id, second's) the frame allowed at
    any of its decisions, and how many decisions put a pair new to it to the test."""

    considered: set[tuple[int, int]] = field(default_factory=set)
    decisions: int = 0

    def level(self) -> float:
        """The share of the link's chance of a wrong answer its latest decision spends:
        ``6 / (π² k²)`` for its ``k``-th (the shares of all its decisions sum to 1)."""
        return 6.0 / (np.pi**2 * max(self.decisions, 1) ** 2)


def identified_by_frame(
    a: ObjectSummary,
    b: ObjectSummary,
    settings: AssociationSettings,
    model,
    free: tuple[np.ndarray, np.ndarray] | None = None,
    history: FrameHistory | None = None,
) -> tuple[np.ndarray, np.ndarray, int]:
    """The pairs the maps' shared frame and appearance identify one by one, without a
    consistent set.

    The shared frame (``frame_probability``) is a transform known before any pair: the
    identity, its uncertainty each estimate's marginal covariance (times the link's learned
    ``frame_scale``). The hypotheses it leaves are the ``M`` pairs it allows
    (:func:`~teamslam.association.gate.frame_allowed`; both objects with a descriptor, of one
    class, and among ``free`` — boolean masks of the objects of ``a`` and ``b`` still
    unmatched — when given). A pair is kept when it is the one best-looking partner of each of
    its two objects among them (``model``'s log ratio: the link's learned one, or the rarity
    before it is informative) and looks alike beyond what the best of ``M`` chance look-alikes
    reaches at ``consistency_probability`` (:func:`~teamslam.association.appearance.
    chance_tail` of one pair): under the hypothesis that none of the ``M`` is the same object,
    the probability that any is kept is at most ``α = 1 − consistency_probability``.

    ``history``: a link's decisions over its run (updated here). A link decides again at every
    exchange; held to ``α`` each time, its chance of ever taking a look-alike grows with the
    number of its decisions. With a history only the pairs the link never considered before
    are hypotheses (``M`` of them; each is still told apart from every pair the frame allows),
    none when there are none, and the ``k``-th decision that has some is held to
    ``α · 6 / (π² k²)`` (:meth:`FrameHistory.level`): over the whole run the probability that
    the link ever takes a pair of which none is the same object is at most ``α``
    (``docs/concepts/association.md``, *A bound over the link's run*).

    Returns
    -------
    rows, cols, hypotheses
        Indices of the pairs into ``a`` and ``b`` (none without a shared frame or
        descriptors) and ``M``.
    """
    none = (np.zeros(0, np.int64), np.zeros(0, np.int64), 0)
    if a.appearance is None or b.appearance is None or len(a) == 0 or len(b) == 0:
        return none
    if settings.frame_threshold is None:
        return none
    # the frame's test of the free objects' pairs alone (each pair's value is its own)
    known_a = np.any(a.appearance != 0, axis=1)
    known_b = np.any(b.appearance != 0, axis=1)
    rows = np.flatnonzero(known_a if free is None else known_a & free[0])
    cols = np.flatnonzero(known_b if free is None else known_b & free[1])
    allowed = np.zeros((len(a), len(b)), dtype=bool)
    if rows.size and cols.size:
        allowed[np.ix_(rows, cols)] = frame_allowed(a.take(rows), b.take(cols), settings)
    if a.classes is not None and b.classes is not None:
        allowed &= a.classes[:, None] == b.classes[None, :]
    tested = allowed
    probability = settings.consistency_probability
    if history is not None:
        rows, cols = np.nonzero(allowed)
        pairs = list(zip(a.ids[rows].tolist(), b.ids[cols].tolist(), strict=True))
        new = np.array([p not in history.considered for p in pairs], dtype=bool)
        if not new.any():
            return none  # every pair the frame allows was decided before
        history.considered.update(pairs)
        history.decisions += 1
        tested = np.zeros_like(allowed)
        tested[rows[new], cols[new]] = True
        probability = 1.0 - (1.0 - probability) * history.level()
    hypotheses = int(np.count_nonzero(tested))
    if hypotheses == 0:
        return none
    score = np.where(
        allowed, model.log_ratio(cosine_distances(a.appearance, b.appearance)), -np.inf
    )
    # the one best of its row and of its column (a tie chooses neither)
    row_best = score == score.max(axis=1, keepdims=True)
    col_best = score == score.max(axis=0, keepdims=True)
    mutual = tested & row_best & col_best
    mutual &= (row_best.sum(axis=1) == 1)[:, None] & (col_best.sum(axis=0) == 1)[None, :]
    rows, cols = np.nonzero(mutual)
    if rows.size == 0:
        return none
    alike = beyond_chance(model, score[rows, cols], hypotheses, probability)
    return rows[alike], cols[alike], hypotheses


def _unless_vetoed(
    a: ObjectSummary, b: ObjectSummary, result: AssociationResult, model, settings
) -> AssociationResult:
    """``result`` without its pairs that look different at the gate's odds under the learned
    ``model``; no answer when that leaves fewer than it needed (``min_inliers``, or all of a
    smaller answer's pairs, whose bound held for them together)."""
    if not result.matched:
        return result
    rows = np.searchsorted(a.ids, result.pairs[:, 0])
    cols = np.searchsorted(b.ids, result.pairs[:, 1])
    la, lb = a.appearance[rows], b.appearance[cols]
    unknown = ~np.any(la != 0, axis=1) | ~np.any(lb != 0, axis=1)
    d = 1.0 - np.einsum("pd,pd->p", unit_rows(la), unit_rows(lb))
    veto = np.log1p(-settings.gate_probability) - np.log(settings.gate_probability)
    ok = unknown | (model.log_ratio(np.clip(d, 0.0, 2.0)) >= veto)
    need = min(settings.min_inliers, len(result.pairs))
    if np.count_nonzero(ok) < need:
        return _no_answer(a, b, "too-few", **_counts(result))
    return replace(result, pairs=result.pairs[ok])


def _with_appearance(
    a: ObjectSummary,
    b: ObjectSummary,
    settings: AssociationSettings,
    model,
    likelihood: bool = True,
) -> AssociationResult:
    """The association with appearance evidence: the same stages with candidates by
    appearance too, down to three pairs, and an answer of fewer than ``min_inliers`` pairs held
    to the chance look-alike bound (:func:`~teamslam.association.appearance.chance_tail`).

    ``likelihood``: ``model`` is the link's informative likelihood ratio, which also vetoes
    pairs that look different and weighs the assignment. Otherwise it is a rarity
    (:func:`~teamslam.association.appearance.rarity`): it draws candidates, exempts pairs
    alike beyond chance from the separation test and bounds a small answer, and nothing else.
    """
    relaxed = replace(settings, min_inliers=3)
    if len(a) < 3 or len(b) < 3:
        return _no_answer(a, b, "too-few")
    known_a = np.any(a.appearance != 0, axis=1)
    known_b = np.any(b.appearance != 0, axis=1)
    llr = model.log_ratio(cosine_distances(a.appearance, b.appearance))
    llr[~known_a, :] = 0.0
    llr[:, ~known_b] = 0.0
    # a pair that looks different at the gate's odds is no candidate and no answer
    veto = np.log1p(-settings.gate_probability) - np.log(settings.gate_probability)
    allowed = llr >= veto if likelihood else np.ones(llr.shape, dtype=bool)
    if a.classes is not None and b.classes is not None:
        allowed &= a.classes[:, None] == b.classes[None, :]
    geo_a, geo_b = _geometry(a), _geometry(b)
    score, mismatch, members = _neighbourhood_sets(a, b, geo_a, geo_b, relaxed)
    ia, ib = select_candidates(score, mismatch, relaxed)
    keep = np.zeros((len(a), len(b)), dtype=bool)
    keep[ia, ib] = True
    keep |= appearance_candidates(llr, allowed, relaxed)
    # a candidate looks more like the same object than not (or one of the two has no
    # descriptor); the gate under a set's transform still gathers any pair not vetoed
    unknown = ~known_a[:, None] | ~known_b[None, :]
    ia, ib = np.nonzero(keep & allowed & ((llr > 0) | unknown))
    ia, ib = _in_frame(a, b, ia, ib, settings)
    # the assignment and the distinctness test weigh a pair by −2 log of its full likelihood
    # ratio: the Mahalanobis distance and −2 ℓ (shifted to ≥ 0: a constant changes neither
    # the assignment nor a difference of costs)
    looks = None
    if likelihood:
        looks = -2.0 * llr
        looks -= looks.min(initial=0.0)

    # a pair alike beyond what chance look-alikes among the neighbours its gate holds give is
    # no neighbour of its object taken for it: the separation test does not apply to it
    def told(rows: np.ndarray, cols: np.ndarray, near: np.ndarray) -> np.ndarray:
        out = known_a[rows] & known_b[cols]
        for k in np.flatnonzero(out):
            tail = chance_tail(model, float(llr[rows[k], cols[k]]), 1, 1 + int(near[k]))
            out[k] = tail <= 1.0 - settings.consistency_probability
        return out

    # a rival's pair that looks more like two different objects than one is no alternative
    # to the answer's: only the rival's pairs that look alike (or cannot be compared) count
    plausible = ((llr > 0) | unknown) if likelihood else None
    result = _from_candidates(a, b, ia, ib, members, geo_a, geo_b, relaxed, looks, told, plausible)
    if not result.matched:
        return result
    rows = np.searchsorted(a.ids, result.pairs[:, 0])
    cols = np.searchsorted(b.ids, result.pairs[:, 1])
    ok = allowed[rows, cols]
    if np.count_nonzero(ok) < 3:
        return _no_answer(a, b, "too-few", **_counts(result))
    rows, cols = rows[ok], cols[ok]
    if rows.size < settings.min_inliers:
        evidence = float(llr[rows, cols].sum())
        tail = chance_tail(model, evidence, rows.size, max(len(a), len(b)))
        if tail > 1.0 - settings.consistency_probability:
            return _no_answer(a, b, "too-few", **_counts(result))
    return replace(result, pairs=result.pairs[ok])


def _counts(result: AssociationResult) -> dict:
    return {
        "candidates": result.candidates,
        "clique": result.clique,
        "rival": result.rival,
        "exact": result.exact,
        "flipped": result.flipped,
    }


def _by_position(
    a: ObjectSummary, b: ObjectSummary, settings: AssociationSettings
) -> AssociationResult:
    need = settings.min_inliers
    if len(a) < need or len(b) < need:
        return _no_answer(a, b, "too-few")
    geo_a, geo_b = _geometry(a), _geometry(b)
    score, mismatch, members = _neighbourhood_sets(a, b, geo_a, geo_b, settings)
    ia, ib = _in_frame(a, b, *select_candidates(score, mismatch, settings), settings)
    return _from_candidates(a, b, ia, ib, members, geo_a, geo_b, settings)


def _geometry(summary: ObjectSummary) -> tuple[np.ndarray, np.ndarray]:
    """The map's :func:`~teamslam.association.distances.pair_distances`, computed once per
    summary (an association by appearance and its fallback by position read the same)."""
    geo = summary.__dict__.get("_geometry")
    if geo is None:
        geo = pair_distances(summary.means, summary.covs)
        summary.__dict__["_geometry"] = geo
    return geo


def _neighbourhood_sets(
    a: ObjectSummary,
    b: ObjectSummary,
    geo_a: tuple[np.ndarray, np.ndarray],
    geo_b: tuple[np.ndarray, np.ndarray],
    settings: AssociationSettings,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`~teamslam.association.candidates.neighbourhood_sets` of the two summaries,
    computed once per pair of summaries and the settings it reads (read only by its
    callers)."""
    key = (settings.neighbours, settings.drift_ratio, settings.consistency_threshold)
    cached = a.__dict__.get("_neighbourhood_sets")
    if cached is not None and cached[0] is b and cached[1] == key:
        return cached[2]
    sets = neighbourhood_sets(a, b, geo_a, geo_b, settings)
    a.__dict__["_neighbourhood_sets"] = (b, key, sets)
    return sets


def _in_frame(
    a: ObjectSummary,
    b: ObjectSummary,
    ia: np.ndarray,
    ib: np.ndarray,
    settings: AssociationSettings,
) -> tuple[np.ndarray, np.ndarray]:
    """The candidates the maps' shared frame allows, once every object has chosen its best
    (a refused candidate leaves its place empty: it does not let a worse one in)."""
    keep = in_frame(a, b, ia, ib, settings)
    return ia[keep], ib[keep]


def _from_candidates(
    a: ObjectSummary,
    b: ObjectSummary,
    ia: np.ndarray,
    ib: np.ndarray,
    members: np.ndarray,
    geo_a: tuple[np.ndarray, np.ndarray],
    geo_b: tuple[np.ndarray, np.ndarray],
    settings: AssociationSettings,
    looks: np.ndarray | None = None,
    told=None,
    plausible: np.ndarray | None = None,
) -> AssociationResult:
    """The stages after the candidates: consistent sets, their transforms and gates, the
    answer (``looks``: the appearance term of every pair's assignment cost, or ``None``;
    ``told``: which pairs ``(rows, cols)`` with ``near`` objects within their gates are
    exempt from the separation test, or ``None``; ``plausible``: the
    pairs a rival may count, or ``None`` for all)."""
    need = settings.min_inliers
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
        rows, cols, t, passed = support(a, b, ca, cb, settings, looks)
        pool[index[clique]] = False
        pool &= ~passed[ia, ib]
        if rows.size >= need and flipped(a, b, rows, cols, t, settings):
            refused += 1  # the mirror image of a near-planar group: neither answer nor rival
            continue
        found.append((rows, cols, t, np.column_stack([a.ids[ca], b.ids[cb]]), (ca, cb)))
    if not any(np.count_nonzero(in_frame(a, b, f[0], f[1], settings)) >= need for f in found):
        # no consistent set gathered an answer: the candidates' own neighbourhoods as seeds
        local, flips = seed_sets(a, b, ia, ib, members, geo_a, geo_b, found, settings, looks)
        found += local
        refused += flips
    counts = {
        "candidates": int(ia.size),
        "clique": int(found[0][3].shape[0]) if found else 0,
        "flipped": refused,
    }
    if not found:
        return _no_answer(a, b, "too-few", exact=exact, **counts)
    # what each set gathers that the maps' shared frame allows (all of it without one)
    framed = []
    for rows, cols, *_ in found:
        keep = in_frame(a, b, rows, cols, settings)
        framed.append((rows[keep], cols[keep]))
    # the answer: the set gathering the most pairs (the first found among equals)
    best = max(range(len(found)), key=lambda k: (framed[k][0].size, -k))
    rows, cols = framed[best]
    _, _, t, clique_pairs, (ca, cb) = found[best]
    gathered = np.column_stack([a.ids[found[best][0]], b.ids[found[best][1]]])
    if rows.size >= 3 and rows.size < found[best][0].size:
        t = fit_transform(a.means[rows], b.means[cols], a.covs[rows], b.covs[cols])
    counts["clique"] = int(clique_pairs.shape[0])
    held = set(zip(rows.tolist(), cols.tolist(), strict=True))
    # a rival: another set whose pairs contradict the answer's (pairs it does not hold). It
    # shows that sets of its size arise by chance in these maps, wherever it lies; only when
    # the frame alone identifies the answer's pairs (each the one partner the frame allows) is a
    # rival the frame refuses no alternative: then only its pairs the frame allows count
    by_frame = np.count_nonzero(told_apart_by_frame(a, b, rows, cols, settings)) >= need
    counts["rival"] = max(
        (
            sum(
                (r, c) not in held and (plausible is None or plausible[r, c])
                for r, c in zip(
                    *(p.tolist() for p in (framed[k] if by_frame else other[:2])), strict=True
                )
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
    anchors = (a.means[rows], b.means[cols])
    extent = None
    if rows.size and settings.separation > 0:
        extent = gate_extent(a, b, t, *anchors, rows, cols, settings)
    ok = separated(a, b, t, *anchors, rows, cols, settings, extent=extent)
    if told is not None and not ok.all():
        loose = np.flatnonzero(~ok)
        near = crowd(a, b, rows[loose], cols[loose], extent[loose], settings)
        ok[loose] = told(rows[loose], cols[loose], near)
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
        gathered=gathered[np.argsort(gathered[:, 0], kind="stable")],
        **counts,
    )


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
    cost first (:func:`~teamslam.association.consistency.consistent_members`). The extension's
    other test, both objects alone in each other's gate
    (:func:`~teamslam.association.gate.alone`), is not applied here.
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
    cost = pair_nis(a, b, r, c, T_first_second)
    ok = consistent_members(a, b, rows[member], cols[member], r, c, cost, settings)
    keep = member.copy()
    keep[added[ok]] = True
    return rows[keep], cols[keep]
