"""The correspondences of one link, kept across steps: grown, checked, revoked.

A robot holds one :class:`CorrespondenceTable` per neighbour. Each association result
(:func:`~teamslam.association.associate`) is *merged*: pairs already held stay; a new pair is
added only when it is consistent with the transform of the pairs already held (a ``χ²₃`` gate
with the drift allowance), when neither of its objects is already matched to another object,
and when it was not revoked before. Consensus then checks every matched pair's innovation
(:func:`pair_innovation_consistent`, its quantile times the link's learned
:attr:`~CorrespondenceTable.frame_scale`); a pair that fails is
:meth:`~CorrespondenceTable.revoke` d and never re-added (or, with a hold-off, not before that
many steps have passed).

At run time a robot runs the full association when the table says it is
:meth:`~CorrespondenceTable.due` (nothing merged yet, a map grown by a quarter since the last
one, or — while the link has no answer — ``min_inliers`` new objects in a map) and grows the
table in between with :meth:`~CorrespondenceTable.extend` (one gate, one assignment; between maps
in one world frame, also the single pairs the frame and appearance identify, the link's chance
of a wrong one spent over its whole run). An extension decides only the pairs of objects new or
changed since the link's last one. Both ends
of a link merge the same results in the same order and compute every decision in the canonical
order of the two robots, so their tables stay mirror images of each
other (own ↔ neighbour ids swapped).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from types import MappingProxyType

import numpy as np

from teamslam.association.answer import AssociationResult, FrameHistory, identified_by_frame
from teamslam.association.appearance import (
    beyond_chance,
    cosine_distances,
    link_model,
    rare_triples,
    rarity,
)
from teamslam.association.consistency import consistent_members
from teamslam.association.distances import anchor_distance
from teamslam.association.gate import (
    alone,
    assign,
    distinct,
    frame_nis,
    frame_scale,
    gate_pairs,
    separated,
)
from teamslam.association.settings import AssociationSettings
from teamslam.association.summary import ObjectSummary
from teamslam.association.transform import fit_transform
from teamslam.errors import InputError
from teamslam.gaussian import chi2_quantile
from teamslam.geometry import se3

__all__ = ["CorrespondenceTable", "pair_innovation_consistent", "pair_innovation_nis"]


def pair_innovation_nis(
    mean_own: np.ndarray,
    cov_own: np.ndarray,
    mean_their: np.ndarray,
    cov_their: np.ndarray,
    T_own_their: np.ndarray | None = None,
) -> np.ndarray:
    """Normalised innovation squared of matched pairs: ``νᵀ S⁻¹ ν``.

    ``ν = μ_own − (R μ_their + t)``, ``S = Σ_own + R Σ_their Rᵀ`` (Cholesky solves).

    Parameters
    ----------
    mean_own, cov_own
        ``(k, 3)`` / ``(k, 3, 3)`` (or a single ``(3,)`` / ``(3, 3)``) the own marginals.
    mean_their, cov_their
        The neighbour's marginals of the same objects, in the neighbour's frame.
    T_own_their
        ``4 × 4`` transform from the neighbour's frame to the own one (identity when ``None``:
        both maps in the same world frame).

    Returns
    -------
    numpy.ndarray
        ``(k,)`` values, ``χ²`` with 3 degrees of freedom when both marginals are right.
    """
    mo = np.asarray(mean_own, dtype=float).reshape(-1, 3)
    mt = np.asarray(mean_their, dtype=float).reshape(-1, 3)
    co = np.asarray(cov_own, dtype=float).reshape(-1, 3, 3)
    ct = np.asarray(cov_their, dtype=float).reshape(-1, 3, 3)
    if not (mo.shape == mt.shape and co.shape == ct.shape == (mo.shape[0], 3, 3)):
        raise InputError("pair innovation: means and covariances of the two sides disagree")
    t = np.eye(4) if T_own_their is None else np.asarray(T_own_their, dtype=float)
    r = t[:3, :3]
    nu = mo - (mt @ r.T + t[:3, 3])
    s = co + r @ ct @ r.T
    s = 0.5 * (s + np.swapaxes(s, 1, 2))
    try:
        chol = np.linalg.cholesky(s)
    except np.linalg.LinAlgError:
        raise InputError("pair innovation: a covariance is not positive definite") from None
    # ‖L⁻¹ ν‖² with a batched triangular solve
    w = np.linalg.solve(chol, nu[:, :, None])[:, :, 0]
    return np.einsum("ki,ki->k", w, w)


def pair_innovation_consistent(
    mean_own: np.ndarray,
    cov_own: np.ndarray,
    mean_their: np.ndarray,
    cov_their: np.ndarray,
    T_own_their: np.ndarray | None = None,
    probability: float = 0.999,
    scale: float = 1.0,
) -> np.ndarray:
    """Whether each matched pair's innovation passes the ``χ²₃`` test at ``probability``.

    See :func:`pair_innovation_nis` for the arguments; returns a ``(k,)`` boolean array.
    ``scale`` (≥ 1): the factor by which the two maps' differences are known to exceed their
    covariances (a link's learned :attr:`CorrespondenceTable.frame_scale`); the test is then
    ``νᵀ S⁻¹ ν ≤ scale · χ²₃(probability)``, the hypothesis the link's frame gate tests.
    """
    if not 0.0 < probability < 1.0:
        raise InputError(f"probability must be in (0, 1), got {probability}")
    if not scale >= 1.0:
        raise InputError(f"scale must be ≥ 1, got {scale}")
    nis = pair_innovation_nis(mean_own, cov_own, mean_their, cov_their, T_own_their)
    return nis <= scale * chi2_quantile(probability, 3)


class CorrespondenceTable:
    """The matched objects of one link, seen from one end: own id ↔ neighbour id.

    Parameters
    ----------
    own, neighbour
        Robot ids of the two ends.
    settings
        Gate probability and drift ratio of the merge (default :class:`AssociationSettings`).
    hold_off
        Steps a revoked pair stays out; ``None`` (default) keeps it out for good.

    Attributes
    ----------
    proposed, accepted, revoked
        Pairs the association proposed (new ones only), pairs added, pairs revoked.
    T_own_their
        Transform of the held pairs (from the last merge that had at least three), or ``None``.
    history
        The link's decisions one by one in the shared frame over its run
        (:class:`~teamslam.association.answer.FrameHistory`; pairs in the order of the robots'
        ids): its extensions and the full associations run for it
        (:func:`~teamslam.association.associate`'s ``history``) spend the link's one chance
        of a wrong answer over them.
    """

    def __init__(
        self,
        own: int,
        neighbour: int,
        settings: AssociationSettings | None = None,
        hold_off: int | None = None,
    ) -> None:
        if hold_off is not None and (isinstance(hold_off, bool) or int(hold_off) < 0):
            raise InputError(f"hold_off must be a number of steps ≥ 0 or None, got {hold_off}")
        self.own = int(own)
        self.neighbour = int(neighbour)
        self.settings = settings or AssociationSettings()
        self.hold_off = None if hold_off is None else int(hold_off)
        self._theirs: dict[int, int] = {}  # own id → neighbour id
        self._pairs: np.ndarray | None = None  # the held pairs as an array (:meth:`pairs`)
        self._ours: dict[int, int] = {}  # neighbour id → own id
        self._revoked: dict[tuple[int, int], int] = {}  # pair → step it was revoked
        self.proposed = 0
        self.accepted = 0
        self.revoked = 0
        self.T_own_their: np.ndarray | None = None
        self._sizes: tuple[int, int] | None = None  # map sizes at the last full association
        #: whether the last summaries' appearance could answer from three pairs (an
        #: informative model, or resemblances rare enough among different objects:
        #: :func:`~teamslam.association.associate`); or the summaries and held pairs to tell it
        #: from, when :meth:`due` asks (only a link without an answer needs it)
        self._looks: bool | tuple = False
        #: the shared frame's scale learned from :attr:`_frame_samples` (1 until then)
        self.frame_scale = 1.0
        #: (own id, neighbour id) → squared Mahalanobis distance under the identity of a pair
        #: identified by a transform while neither object was held (:meth:`_learn_frame`)
        self._frame_samples: dict[tuple[int, int], float] = {}
        #: during one :meth:`extend`: the link's appearance models computed, by held pairs (the
        #: same two summaries give the same model, computed once)
        self._models: dict | None = None
        #: the link's identifications one by one in the shared frame over its run, in the
        #: canonical order (:func:`~teamslam.association.answer.identified_by_frame`)
        self.history = FrameHistory()
        #: the summaries, held pairs and frame scale at the end of the link's last extension
        #: (``None`` after a merge): what the next one needs not decide again (:meth:`_fresh`)
        self._decided: tuple | None = None

    def __len__(self) -> int:
        return len(self._theirs)

    def __contains__(self, pair: tuple[int, int]) -> bool:
        own_id, their_id = (int(v) for v in pair)
        return self._theirs.get(own_id) == their_id

    def frame_samples(self) -> Mapping[tuple[int, int], float]:
        """``(own id, neighbour id) → d²`` of each pair the link identified by the transform of
        the pairs it already held, taken while neither object was held (before consensus
        averaged the two estimates): a read-only view, filled as the link decides."""
        return MappingProxyType(self._frame_samples)

    def pairs(self) -> np.ndarray:
        """``(k, 2)`` int64 rows ``(own id, neighbour id)``, sorted by own id (a new array
        each call; built once per change of the pairs)."""
        if self._pairs is None:
            if not self._theirs:
                self._pairs = np.zeros((0, 2), np.int64)
            else:
                own = np.fromiter(self._theirs, dtype=np.int64, count=len(self._theirs))
                own.sort()
                their = [self._theirs[int(i)] for i in own]
                self._pairs = np.column_stack([own, their]).astype(np.int64)
        return self._pairs.copy()

    def _hold(self, pairs: list[tuple[int, int]]) -> None:
        """Add ``pairs`` (own id, neighbour id) to the held ones."""
        for a, b in pairs:
            self._theirs[a] = b
            self._ours[b] = a
        if pairs:
            self._pairs = None

    def theirs(self, own_ids: np.ndarray) -> np.ndarray:
        """The neighbour's ids of ``own_ids`` (-1 where unmatched)."""
        ids = np.asarray(own_ids, dtype=np.int64).reshape(-1)
        return np.array([self._theirs.get(int(i), -1) for i in ids], dtype=np.int64)

    def ours(self, their_ids: np.ndarray) -> np.ndarray:
        """Our ids of the neighbour's ``their_ids`` (-1 where unmatched)."""
        ids = np.asarray(their_ids, dtype=np.int64).reshape(-1)
        return np.array([self._ours.get(int(i), -1) for i in ids], dtype=np.int64)

    def current_settings(self) -> AssociationSettings:
        """The link's settings with the shared frame's scale it has learned
        (:attr:`frame_scale`, see :meth:`extend`): what its full associations and extensions
        use."""
        if self.frame_scale == 1.0:
            return self.settings
        return replace(self.settings, frame_scale=self.frame_scale)

    def _blocked(self, pair: tuple[int, int], step: int | None) -> bool:
        if pair not in self._revoked:
            return False
        if self.hold_off is None or step is None:
            return True
        return step - self._revoked[pair] < self.hold_off

    def merge(
        self,
        result: AssociationResult,
        own: ObjectSummary,
        their: ObjectSummary,
        step: int | None = None,
    ) -> np.ndarray:
        """Add the new pairs of ``result`` that agree with the pairs already held.

        Parameters
        ----------
        result
            :func:`~teamslam.association.associate` of ``own`` against ``their`` (seen from this
            end: ``result.first`` is :attr:`own`).
        own, their
            The summaries the result was computed from.
        step
            The current step (for the hold-off of revoked pairs).

        Returns
        -------
        numpy.ndarray
            ``(k, 2)`` the pairs added.
        """
        if result.first != self.own or result.second != self.neighbour:
            raise InputError(
                f"association of robots {result.first}→{result.second} merged into the table of "
                f"link {self.own}→{self.neighbour}"
            )
        self.learn_frame(result, own, their)
        new = [
            (int(a), int(b))
            for a, b in result.pairs
            if self._theirs.get(int(a)) != int(b)  # not already held
        ]
        self._sizes = (len(own), len(their))
        self._looks = (own, their, self.pairs())
        self.proposed += len(new)
        new = [
            p
            for p in new
            if p[0] not in self._theirs and p[1] not in self._ours and not self._blocked(p, step)
        ]
        # a merge decides the answer's pairs alone: the next extension decides every pair
        self._decided = None
        if not new:
            return np.zeros((0, 2), np.int64)
        held = self.pairs()
        proposal = np.array(new, dtype=np.int64).reshape(-1, 2)
        for ids, summary in ((proposal[:, 0], own), (proposal[:, 1], their)):
            if not np.isin(ids, summary.ids).all():
                raise InputError("the association result names an object its summaries do not hold")
        # computed in the canonical order of the two robots, so both ends decide alike
        if self._canonical_first():
            ok, t = _merge_gate(own, their, held, proposal, self.settings)
        else:
            ok, t = _merge_gate(their, own, held[:, ::-1], proposal[:, ::-1], self.settings)
            t = None if t is None else se3.inverse(t)
        if t is not None:
            self.T_own_their = t
        elif result.T_first_second is not None:
            self.T_own_their = result.T_first_second
        new = [p for p, keep in zip(new, ok, strict=True) if keep]
        self._hold(new)
        self.accepted += len(new)
        return np.array(new, dtype=np.int64).reshape(-1, 2)

    def extend(
        self, own: ObjectSummary, their: ObjectSummary, step: int | None = None
    ) -> np.ndarray:
        """Grow the held pairs without a full association (cheap: one gate, one assignment).

        The objects neither end has matched yet are gated under the transform of the held pairs
        (:func:`~teamslam.association.gate.gate_pairs`, drift allowance from the nearest held
        pair), assigned one to one, and kept when

        * alone in each other's gate: no second object of either map, held or not, passes the
          ``χ²₃`` gate with either of the two (a full association chooses between two objects
          in a gate with a consistent set behind its answer; here a gate alone would decide —
          on KITTI 00 the one wrong pair held for hundreds of frames entered so, a car of a row
          matched to the next one while both were in its gate);
        * distinct (no other object of either map fits nearly as well, held pairs included);
        * separated (their gate, with the drift allowance from the held pairs, narrow against
          their objects' spacing: :attr:`~teamslam.association.AssociationSettings.separation`);
        * consistent two by two with the held pairs and the pairs added before them, as the
          members of a full association's consistent set are
          (:func:`~teamslam.association.consistency.consistent_members`);
        * allowed by the maps' shared frame (when they share one: the test of
          :attr:`~teamslam.association.AssociationSettings.frame_probability` with the scale
          the link has learned).

        Between maps in one world frame, with appearance, the pairs of objects neither end holds
        that the frame and appearance identify one by one
        (:func:`~teamslam.association.answer.identified_by_frame`) are added too when the merge's
        gate under the held pairs' transform admits them (all, while fewer than three held
        pairs are in the summaries): a link without a transform of its own takes a new shared
        object at the next exchange, not at its next full association.

        The pairs that pass every test but the last are identified by the held pairs' transform,
        not by the frame: their squared Mahalanobis distances under the identity
        (:func:`~teamslam.association.gate.frame_nis`) measure how far the two maps' estimates
        of one object lie apart against their covariances. When they are at least
        ``min_inliers`` (none of them a pair consensus revoked), they set the link's
        :attr:`frame_scale` (:func:`~teamslam.association.gate.frame_scale`), used from the next
        association or extension on: maps overconfident against each other (noisy odometry
        with the standard linearisation) no longer have their right pairs refused by the frame.
        Before the link holds an answer the scale is 1.

        Only pairs with an object new since the link's last extension, or whose summary changed
        since, are decided (each still judged against every object): between whole summaries a
        link's maps only gain objects, and the other pairs were decided on the same evidence.
        After a merge, an extension that added pairs or learned the frame's scale, or a revoked
        pair, every pair is decided again; with nothing new, nothing is (:meth:`_fresh`). The
        single pairs of the frame spend the link's chance of a wrong answer over its run
        (:attr:`history`).

        A pair left out waits for a full association or for covariances that tell its objects
        apart. Computed in the canonical order of the two robots, like
        :func:`~teamslam.association.associate`, so both ends add the same pairs.

        Parameters
        ----------
        own, their
            The current summaries of the two maps.
        step
            The current step (for the hold-off of revoked pairs).

        Returns
        -------
        numpy.ndarray
            ``(k, 2)`` the pairs added; none under the held pairs' transform while fewer than
            ``min_inliers`` held pairs (three with an informative appearance model) are in the
            summaries, only those the shared frame and appearance identify.
        """
        if own.robot != self.own or their.robot != self.neighbour:
            raise InputError(
                f"summaries of robots {own.robot}→{their.robot} given to the table of link "
                f"{self.own}→{self.neighbour}"
            )
        self._models = {}
        try:
            return self._extend_with(own, their, step)
        finally:
            self._models = None

    def _link_model(self, first: ObjectSummary, second: ObjectSummary, held: np.ndarray):
        """:func:`~teamslam.association.appearance.link_model` of the sorted summaries in the
        canonical order, once per held pairs during an :meth:`extend`."""
        probability = self.settings.consistency_probability
        if self._models is None:
            return link_model(first, second, held, probability)
        key = held.tobytes()
        if key not in self._models:
            self._models[key] = link_model(first, second, held, probability)
        return self._models[key]

    def _fresh(
        self, own: ObjectSummary, their: ObjectSummary
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Which objects of ``own`` and ``their`` (masks in id order) are new since the link's
        last extension or have a summary that changed since; all of them after a merge, an
        extension that added pairs or learned the frame's scale, or when the held pairs changed
        since (a revoked pair); ``None`` when none."""
        decided = self._decided
        if (
            decided is None
            or not np.array_equal(decided[2], self.pairs())
            or decided[3] != self.frame_scale
        ):
            return np.ones(len(own), bool), np.ones(len(their), bool)
        masks = (
            _changed(own.sorted(), decided[0].sorted()),
            _changed(their.sorted(), decided[1].sorted()),
        )
        return masks if masks[0].any() or masks[1].any() else None

    def _extend_with(
        self, own: ObjectSummary, their: ObjectSummary, step: int | None
    ) -> np.ndarray:
        fresh = self._fresh(own, their)
        if fresh is None:  # nothing new to decide: the last decision stands
            return np.zeros((0, 2), np.int64)
        held = self.pairs()
        settings_scale = self.frame_scale
        settings, model = self.current_settings(), self._model(own, their)
        self._looks = True if model is not None else (own, their, held)
        if model is not None:
            settings = replace(settings, min_inliers=3)
        if self._canonical_first():
            found, nis, framed = _extend(own.sorted(), their.sorted(), held, settings, model, fresh)
        else:
            found, nis, framed = _extend(
                their.sorted(), own.sorted(), held[:, ::-1], settings, model, fresh[::-1]
            )
            found = found[:, ::-1]
        if model is not None and len(found):
            alike = _looks_alike(own, their, found, model, settings)
            found, nis, framed = found[alike], nis[alike], framed[alike]
        if self.settings.frame_probability is not None:
            self._learn_frame(own, their, found, nis=nis)
        found = found[framed]
        self.proposed += len(found)
        new = [
            (int(a), int(b))
            for a, b in found
            if int(a) not in self._theirs
            and int(b) not in self._ours
            and not self._blocked((int(a), int(b)), step)
        ]
        self._hold(new)
        framed = self._identified_by_frame(own, their, step)
        self.proposed += len(framed)
        self._hold(framed)
        new += framed
        self.accepted += len(new)
        # what the next extension needs not decide again: nothing, when this one added pairs
        # (new anchors) or learned another frame scale
        quiet = not new and self.frame_scale == settings_scale
        self._decided = (own, their, self.pairs(), self.frame_scale) if quiet else None
        return np.array(new, dtype=np.int64).reshape(-1, 2)

    def _identified_by_frame(
        self,
        own: ObjectSummary,
        their: ObjectSummary,
        step: int | None,
    ) -> list[tuple[int, int]]:
        """New pairs of objects neither end holds yet that the maps' shared frame and appearance
        identify one by one (:func:`~teamslam.association.answer.identified_by_frame`, with the
        link's appearance model, or the rarity before it is informative) and that the held
        pairs' transform admits (the merge's gate, when three held pairs are in the summaries),
        never a revoked one; computed in the canonical order. None without a shared frame or
        descriptors."""
        settings = self.current_settings()
        if settings.frame_probability is None or own.appearance is None:
            return []
        if their.appearance is None or own.appearance.shape[1] != their.appearance.shape[1]:
            return []
        held = self.pairs()
        first, second = (own, their) if self._canonical_first() else (their, own)
        first, second = first.sorted(), second.sorted()
        held = held if self._canonical_first() else held[:, ::-1]
        model = self._link_model(first, second, np.ascontiguousarray(held))
        model = model if model.informative else rarity(model)
        free = (~_held_mask(first.ids, held[:, 0]), ~_held_mask(second.ids, held[:, 1]))
        rows, cols, _ = identified_by_frame(first, second, settings, model, free, self.history)
        found = np.column_stack([first.ids[rows], second.ids[cols]])
        if not self._canonical_first():
            found = found[:, ::-1]
        found = found[[not self._blocked((int(a), int(b)), step) for a, b in found]]
        if len(found) == 0:
            return []
        if self._canonical_first():
            ok, _ = _merge_gate(own, their, self.pairs(), found, self.settings)
        else:
            ok, _ = _merge_gate(their, own, self.pairs()[:, ::-1], found[:, ::-1], self.settings)
        return [(int(a), int(b)) for a, b in found[ok]]

    def learn_frame(
        self, result: AssociationResult, own: ObjectSummary, their: ObjectSummary
    ) -> bool:
        """Learn the shared frame's scale from a full association's answer (the pairs its
        consistent set gathered by shape, :attr:`~teamslam.association.AssociationResult.
        gathered`; see :meth:`_learn_frame`), as :meth:`merge` does.

        Returns
        -------
        bool
            Whether :attr:`frame_scale` grew: the association, run with the old scale, refused
            pairs the maps' measured disagreement allows (the caller may run it again).
        """
        before = self.frame_scale
        if result.matched and self.settings.frame_probability is not None:
            self._learn_frame(own, their, result.gathered, fresh=True)
        return self.frame_scale > before

    def _learn_frame(
        self,
        own: ObjectSummary,
        their: ObjectSummary,
        pairs: np.ndarray,
        nis: np.ndarray | None = None,
        fresh: bool = False,
    ) -> None:
        """Learn the shared frame's scale from ``pairs`` (own id, neighbour id) identified by a
        transform, not by the frame: those whose objects are both unmatched and that consensus
        did not revoke are samples of the maps' disagreement
        (:func:`~teamslam.association.gate.frame_nis`; a held pair's estimates were averaged,
        so its distance says nothing of it), once the link holds an answer (``min_inliers``
        pairs: until then the frame is taken at its word). ``fresh`` (a full association): at least
        ``min_inliers`` of them replace the samples kept so far; else they are added, each pair
        keeping its latest. From ``min_inliers`` samples on, :attr:`frame_scale` is
        :func:`~teamslam.association.gate.frame_scale` of them."""
        need = self.settings.min_inliers
        if len(self) < need:
            return  # before the link holds an answer the frame is taken at its word
        pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        keep = np.array(
            [
                int(a) not in self._theirs
                and int(b) not in self._ours
                and not self._blocked((int(a), int(b)), None)
                for a, b in pairs
            ],
            dtype=bool,
        )
        pairs = pairs[keep]
        if nis is None:
            if pairs.size == 0:
                return
            ia = _indices(own.ids, pairs[:, 0])
            ib = _indices(their.ids, pairs[:, 1])
            if self._canonical_first():
                nis = frame_nis(own, their, ia, ib)
            else:
                nis = frame_nis(their, own, ib, ia)
        else:
            nis = np.asarray(nis, dtype=float)[keep]
        samples = {(int(a), int(b)): float(v) for (a, b), v in zip(pairs, nis, strict=True)}
        if fresh and len(samples) >= need:
            self._frame_samples = samples
        else:
            self._frame_samples.update(samples)
        if len(self._frame_samples) >= need:
            self.frame_scale = frame_scale(np.fromiter(self._frame_samples.values(), float))

    def _canonical_first(self) -> bool:
        return self.own <= self.neighbour

    def _model(self, own: ObjectSummary, their: ObjectSummary, held: np.ndarray | None = None):
        """The link's appearance model when informative (as the association builds it, in the
        canonical order, with the ``held`` pairs: the table's by default), else ``None``."""
        if own.appearance is None or their.appearance is None:
            return None
        held = self.pairs() if held is None else held
        if self._canonical_first():
            model = self._link_model(own.sorted(), their.sorted(), held)
        else:
            model = self._link_model(
                their.sorted(), own.sorted(), np.ascontiguousarray(held[:, ::-1])
            )
        return model if model is not None and model.informative else None

    def _from_three(self, own: ObjectSummary, their: ObjectSummary, held: np.ndarray) -> bool:
        """Whether the two summaries' appearance may give an answer of three pairs with the
        ``held`` pairs: the link's model is informative, or, before it is, three resemblances
        can be rarer among different objects than chance look-alikes
        (:func:`~teamslam.association.appearance.rare_triples`), as the association decides."""
        if own.appearance is None or their.appearance is None:
            return False
        if self._model(own, their, held) is not None:
            return True
        first, second = (own, their) if self._canonical_first() else (their, own)
        held = held if self._canonical_first() else held[:, ::-1]
        model = self._link_model(first.sorted(), second.sorted(), np.ascontiguousarray(held))
        if model is None:
            return False
        m = max(len(own), len(their))
        return rare_triples(rarity(model), m, self.settings.consistency_probability)

    def due(self, own_objects: int, their_objects: int, growth: float = 1.25) -> bool:
        """Whether a full association is worth running now.

        Yes when none was merged yet; when either map has grown by the factor ``growth`` since
        the last one; and, while the table holds fewer pairs than an answer needs
        (:attr:`~teamslam.association.AssociationSettings.min_inliers`), when either map holds
        that many objects more than at the last one (three while the link's appearance may
        answer from three pairs: :meth:`_from_three`). In between, :meth:`extend` grows the
        table for the cost of one gate.

        The growth factor spaces the full associations of a link that has an answer (maps of
        a hundred or two objects; with ``growth = 1.25`` a map growing from 10 to 200 objects
        is associated about 14 times), and :meth:`extend` grows its table meanwhile. A link
        without an answer has nothing to extend: its maps may share objects for tens of frames
        before they have grown by a quarter (25 new objects on maps of a hundred). Its next
        attempt comes once either map holds as many new objects as an answer needs pairs — a
        count the answer itself sets, no constant of its own — so a link that begins to share
        objects with its neighbour waits a few exchanges, not tens of frames. Estimates that
        only moved do not make an attempt due, nor do fewer new objects: an answer that needs
        the last few objects of maps that then stop growing is not found (as with the growth
        rule alone).

        Measured (``benchmarks/association.py ring``; ``teamslam run --association own`` on
        KITTI 00 with per-robot ids): on 15 simulated robots on a ring with 30% link loss,
        recall 0.932 → 0.967 and RMSE 0.0898 → 0.0878 m; on the ``make run`` team 0.954 →
        0.986 and 0.0536 → 0.0509 m; on KITTI 00 RMSE 7.70 → 7.65 m, precision 0.996 as
        before (one wrong pair). Two rules that try more often reached the same on the
        simulated teams but let two more wrong pairs in on KITTI 00 (precision 0.996 → 0.987):
        an attempt at every exchange with new objects, and this rule with an attempt also once
        the maps stopped growing (the same sizes at two exchanges running). Each attempt on maps
        that do not overlap is one more chance of a wrong answer.
        """
        if growth <= 1.0:
            raise InputError(f"growth must be > 1, got {growth}")
        if self._sizes is None:
            return True
        own0, their0 = self._sizes
        if own_objects >= growth * max(own0, 1) or their_objects >= growth * max(their0, 1):
            return True
        if len(self) >= self.settings.min_inliers:
            return False
        if isinstance(self._looks, tuple):  # told from the last summaries when first needed
            self._looks = self._from_three(*self._looks)
        need = 3 if self._looks else self.settings.min_inliers
        return own_objects >= own0 + need or their_objects >= their0 + need

    def revoke(self, own_id: int, their_id: int, step: int | None = None) -> bool:
        """Drop a held pair (its consensus innovation failed); it is not re-added.

        Returns
        -------
        bool
            Whether the pair was held.
        """
        own_id, their_id = int(own_id), int(their_id)
        if self._theirs.get(own_id) != their_id:
            return False
        del self._theirs[own_id]
        self._pairs = None
        del self._ours[their_id]
        self._frame_samples.pop((own_id, their_id), None)
        self._revoked[(own_id, their_id)] = -1 if step is None else int(step)
        self.revoked += 1
        return True

    def revoke_other_classes(
        self, own: ObjectSummary, theirs: ObjectSummary, step: int | None = None
    ) -> int:
        """Revoke the held pairs whose two objects' classes now differ in ``own`` and
        ``theirs`` (an object's class is the majority of its boxes' labels and may change after
        its pair was held; the association pairs equal classes only); the number revoked.
        Pairs with an object outside either summary are kept."""
        if own.classes is None or theirs.classes is None or not len(self):
            return 0
        pairs = self.pairs()
        own_in = np.isin(pairs[:, 0], own.ids)
        their_in = np.isin(pairs[:, 1], theirs.ids)
        pairs = pairs[own_in & their_in]
        if not pairs.size:
            return 0
        own_class = own.classes[_indices(own.ids, pairs[:, 0])]
        their_class = theirs.classes[_indices(theirs.ids, pairs[:, 1])]
        other = pairs[own_class != their_class]
        for own_id, their_id in other.tolist():
            self.revoke(own_id, their_id, step)
        return int(other.shape[0])

    def counts(self) -> dict[str, int]:
        """``proposed``, ``accepted``, ``revoked`` and ``held`` pairs."""
        return {
            "proposed": self.proposed,
            "accepted": self.accepted,
            "revoked": self.revoked,
            "held": len(self),
        }


def _changed(now: ObjectSummary, before: ObjectSummary) -> np.ndarray:
    """Which objects of ``now`` (sorted by id) ``before`` (sorted) does not hold, or holds with
    another mean, covariance, class or descriptor."""
    k = np.minimum(np.searchsorted(before.ids, now.ids), max(len(before) - 1, 0))
    if len(before) == 0:
        return np.ones(len(now), bool)
    changed = before.ids[k] != now.ids
    changed |= np.any(before.means[k] != now.means, axis=1)
    changed |= np.any(before.covs[k] != now.covs, axis=(1, 2))
    for name in ("classes", "appearance"):
        a, b = getattr(now, name), getattr(before, name)
        if (a is None) != (b is None) or (a is not None and a.shape[1:] != b.shape[1:]):
            return np.ones(len(now), bool)
        if a is not None:
            changed |= (b[k] != a) if a.ndim == 1 else np.any(b[k] != a, axis=1)
    return changed


def _held_mask(ids: np.ndarray, held: np.ndarray) -> np.ndarray:
    """Which of the increasing ``ids`` are in ``held`` (``np.isin``, by a binary search)."""
    out = np.zeros(ids.size, dtype=bool)
    if ids.size == 0 or held.size == 0:
        return out
    at = np.minimum(np.searchsorted(ids, held), ids.size - 1)
    out[at[ids[at] == held]] = True
    return out


def _indices(ids: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """Indices into ``ids`` (unique, in any order) of the ids ``wanted`` (all present)."""
    order = np.argsort(ids, kind="stable")
    return order[np.searchsorted(ids, wanted, sorter=order)]


def _looks_alike(
    own: ObjectSummary,
    their: ObjectSummary,
    pairs: np.ndarray,
    model,
    settings: AssociationSettings,
) -> np.ndarray:
    """Which pairs do not look different at the gate's odds (the association's veto)."""
    ia = np.searchsorted(own.ids, pairs[:, 0], sorter=np.argsort(own.ids, kind="stable"))
    ib = np.searchsorted(their.ids, pairs[:, 1], sorter=np.argsort(their.ids, kind="stable"))
    ia = np.argsort(own.ids, kind="stable")[ia]
    ib = np.argsort(their.ids, kind="stable")[ib]
    la, lb = own.appearance[ia], their.appearance[ib]
    d = np.clip(np.diagonal(cosine_distances(la, lb)), 0.0, 2.0)
    llr = model.log_ratio(d)
    unknown = ~np.any(la != 0, axis=1) | ~np.any(lb != 0, axis=1)
    veto = np.log1p(-settings.gate_probability) - np.log(settings.gate_probability)
    return unknown | (llr >= veto)


def _extend(
    a: ObjectSummary,
    b: ObjectSummary,
    held: np.ndarray,
    settings: AssociationSettings,
    model=None,
    fresh: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """New pairs of unmatched objects of ``a`` and ``b`` under the held pairs' transform (with
    an appearance ``model``, pairs assigned and told apart by Mahalanobis distance plus
    ``−2`` times their log likelihood ratio, as in the association). With ``fresh`` (masks
    of the objects new or changed since the link's last decision) only pairs with at least one
    of them are kept, each still judged against every object; none when no such pair is in
    the gate.

    Returns
    -------
    pairs, nis, framed
        ``(k, 2)`` the pairs that pass every test but the shared frame's (ids, sorted by the
        first), their :func:`~teamslam.association.gate.frame_nis` and which the frame allows.
    """
    none = (np.zeros((0, 2), np.int64), np.zeros(0), np.zeros(0, bool))
    ia = np.searchsorted(a.ids, held[:, 0]) if held.size else np.zeros(0, np.int64)
    ib = np.searchsorted(b.ids, held[:, 1]) if held.size else np.zeros(0, np.int64)
    ia = np.minimum(ia, max(len(a) - 1, 0))
    ib = np.minimum(ib, max(len(b) - 1, 0))
    present = (
        (a.ids[ia] == held[:, 0]) & (b.ids[ib] == held[:, 1])
        if held.size and len(a) and len(b)
        else np.zeros(0, bool)
    )
    ia, ib = ia[present], ib[present]
    if ia.size < settings.min_inliers:
        return none
    t = fit_transform(a.means[ia], b.means[ib], a.covs[ia], b.covs[ib])
    free_a = np.ones(len(a), bool)
    free_a[ia] = False
    free_b = np.ones(len(b), bool)
    free_b[ib] = False
    few = fresh is not None and 2 * _fresh_cells(fresh) < len(a) * len(b)
    if few and not _fresh_in_gate(a, b, t, ia, ib, free_a, free_b, fresh, settings):
        return none  # no pair of a new object in the gate: nothing the last decision did not
    cost, passed = gate_pairs(a, b, t, a.means[ia], b.means[ib], settings)
    fresh_pairs = None if fresh is None else fresh[0][:, None] | fresh[1][None, :]
    if not few and fresh is not None:
        gated = passed & free_a[:, None] & free_b[None, :]
        if not (gated & fresh_pairs).any():
            return none
    told = None
    if model is not None:
        known_a = np.any(a.appearance != 0, axis=1)
        known_b = np.any(b.appearance != 0, axis=1)
        llr = model.log_ratio(cosine_distances(a.appearance, b.appearance))
        llr[~known_a, :] = 0.0
        llr[:, ~known_b] = 0.0
        looks = -2.0 * llr
        looks -= looks.min(initial=0.0)
        cost = cost + looks
        m = max(len(a), len(b))

        def told(r: np.ndarray, c: np.ndarray) -> np.ndarray:
            """Whether the pairs look alike beyond chance (of every pair's, elementwise)."""
            alike = beyond_chance(model, llr[r, c], m, settings.consistency_probability)
            return alike & known_a[r] & known_b[c]

    passed &= free_a[:, None] & free_b[None, :]
    rows, cols = assign(cost, passed)
    if rows.size:
        # once more with the new pairs as anchors too, as in the association: a new pair must
        # then fit the refitted transform within its own covariances
        ra, rb = np.concatenate([ia, rows]), np.concatenate([ib, cols])
        t = fit_transform(a.means[ra], b.means[rb], a.covs[ra], b.covs[rb])
        cost, passed = gate_pairs(a, b, t, a.means[ra], b.means[rb], settings)
        if told is not None:
            cost = cost + looks
        gated = passed.copy()
        passed &= free_a[:, None] & free_b[None, :]
        rows, cols = assign(cost, passed)
        # alone in each other's gate: no second object of either map (held or not) fits
        single = alone(gated, rows, cols)
        if told is not None:  # alike beyond chance: not a neighbour taken for the object
            single |= told(rows, cols)
        rows, cols = rows[single], cols[single]
    # distinct against every object, the held pairs counting as assigned
    all_rows = np.concatenate([ia, rows])
    all_cols = np.concatenate([ib, cols])
    keep_rows, keep_cols = distinct(cost, all_rows, all_cols, settings.distinctness)
    added = free_a[keep_rows]
    # the drift allowance from the held pairs: a new pair does not vouch for itself
    spaced = separated(
        a, b, t, a.means[ia], b.means[ib], keep_rows[added], keep_cols[added], settings
    )
    if told is not None:
        spaced |= told(keep_rows[added], keep_cols[added])
    added[added] = spaced
    rows, cols = keep_rows[added], keep_cols[added]
    ok = consistent_members(a, b, ia, ib, rows, cols, cost[rows, cols], settings)
    if fresh is not None:
        ok &= fresh[0][rows] | fresh[1][cols]
    rows, cols = rows[ok], cols[ok]
    if rows.size == 0:
        return none
    nis = frame_nis(a, b, rows, cols)
    chi2 = settings.frame_threshold
    framed = np.ones(rows.size, bool) if chi2 is None else nis <= chi2
    pairs = np.column_stack([a.ids[rows], b.ids[cols]])
    order = np.argsort(pairs[:, 0], kind="stable")
    return pairs[order], nis[order], framed[order]


def _fresh_cells(fresh: tuple[np.ndarray, np.ndarray]) -> int:
    """How many pairs have a fresh object (of masks ``fresh``)."""
    r, c = int(np.count_nonzero(fresh[0])), int(np.count_nonzero(fresh[1]))
    return r * fresh[1].size + c * fresh[0].size - r * c


def _fresh_in_gate(
    a: ObjectSummary,
    b: ObjectSummary,
    t: np.ndarray,
    ia: np.ndarray,
    ib: np.ndarray,
    free_a: np.ndarray,
    free_b: np.ndarray,
    fresh: tuple[np.ndarray, np.ndarray],
    settings: AssociationSettings,
) -> bool:
    """Whether a pair of free objects, one of them ``fresh``, passes the gate under ``t``
    anchored on the held pairs ``(ia, ib)``: :func:`~teamslam.association.gate.gate_pairs` of
    the fresh rows against every column and of every row against the fresh columns (each
    pair's value is its own: the same as in the whole gate)."""
    anchors = (a.means[ia], b.means[ib])
    rows = np.flatnonzero(fresh[0] & free_a)
    if rows.size:
        _, passed = gate_pairs(a.take(rows), b, t, *anchors, settings)
        if (passed & free_b[None, :]).any():
            return True
    cols = np.flatnonzero(fresh[1] & free_b)
    if cols.size:
        _, passed = gate_pairs(a, b.take(cols), t, *anchors, settings)
        if (passed & free_a[:, None]).any():
            return True
    return False


def _merge_gate(
    a: ObjectSummary,
    b: ObjectSummary,
    held: np.ndarray,
    proposal: np.ndarray,
    settings: AssociationSettings,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Which proposed pairs pass the ``χ²₃`` gate under the held pairs' transform (all of them
    while fewer than three held pairs are in the summaries), and that transform."""
    index_a = {int(i): k for k, i in enumerate(a.ids)}
    index_b = {int(i): k for k, i in enumerate(b.ids)}
    present = [
        (index_a[int(x)], index_b[int(y)])
        for x, y in held
        if int(x) in index_a and int(y) in index_b
    ]
    if len(present) < 3:
        return np.ones(len(proposal), bool), None
    ia = np.array([i for i, _ in present])
    ib = np.array([j for _, j in present])
    t = fit_transform(a.means[ia], b.means[ib], a.covs[ia], b.covs[ib])
    ca = np.array([index_a[int(x)] for x in proposal[:, 0]])
    cb = np.array([index_b[int(y)] for y in proposal[:, 1]])
    # the drift allowance grows with the distance from the nearest held pair
    near_a = anchor_distance(a.means[ca], a.means[ia])
    near_b = anchor_distance(b.means[cb], b.means[ib])
    extra = 0.5 * settings.drift_ratio**2 * (near_a**2 + near_b**2)
    nis = pair_innovation_nis(
        a.means[ca], a.covs[ca] + extra[:, None, None] * np.eye(3), b.means[cb], b.covs[cb], t
    )
    return nis <= settings.gate_threshold, t
