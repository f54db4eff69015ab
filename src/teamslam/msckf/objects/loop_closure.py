"""Loop closure in a robot's own object map: a revisit re-identified by the shape of a group.

:func:`find_loop` runs the robot's own association (:func:`~teamslam.association.associate`)
between its *recent* objects and its *old* ones (unseen for longer than the window, and those
of the persistent map), with its views so that a mirror image is refused and a turn beyond the
drift (:func:`turn_within_drift`) too; it never guesses (too few pairs or a rival set gives
nothing). A single new object is re-identified by its own boxes instead: :func:`difference_d2`
gates ``x_n − x_o`` with its covariance from the joint state, :class:`PositionRatio` gives the
difference's likelihood ratio (one object against two, learned in the run), and
:func:`revisit_posterior` weighs the gated candidates' evidence against a new object and against
each other.
:func:`merge_objects` closes the loop: one EKF update with ``x_n − x_o = 0`` for every accepted
pair, then ``x_n`` leaves the state. Derivation: the concept page *Tracking*
(``docs/concepts/tracking.md``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import stats
from scipy.spatial.transform import Rotation

from teamslam.association import AssociationResult, AssociationSettings, ObjectSummary, associate
from teamslam.gaussian import log_chi2_std

__all__ = [
    "LoopClosure",
    "PositionRatio",
    "difference_d2",
    "find_loop",
    "merge_objects",
    "revisit_posterior",
]

#: Noise of the merge constraint, relative to each pair's own prior variance of ``x_n − x_o``.
MERGE_RELATIVE_NOISE = 1e-9


@dataclass
class LoopClosure:
    """Which objects of a robot's map are revisits of older ones.

    Parameters
    ----------
    gap
        Frames: an old object was last seen more than this before the first recent object was
        created (the filter's window).
    recent
        How many of the objects the tracker created last form the recent map (twice the
        association's default ``min_inliers``).
    settings
        The association's thresholds (:class:`~teamslam.association.AssociationSettings`).

    Attributes
    ----------
    closures
        Every merged pair: ``(frame, new id, old id)``.
    attempts
        Associations run (one per new recent object).
    outcomes
        How the attempts ended: ``merged``, ``too-few`` (fewer than ``min_inliers`` pairs),
        ``ambiguous`` (a rival set nearly as large), ``beyond-drift`` (a pair farther apart
        than the distance travelled allows), ``turned`` (a transform turned further than the
        robot's drift can: :func:`turn_within_drift`).
    """

    gap: int
    recent: int = 12
    settings: AssociationSettings = field(default_factory=AssociationSettings)
    closures: list[tuple[int, int, int]] = field(default_factory=list)
    attempts: int = 0
    outcomes: dict[str, int] = field(default_factory=dict)
    _last_key: tuple[int, ...] = ()
    # the distance the robot's estimate travelled up to each frame (from the first observed)
    _path: list[float] = field(default_factory=list)
    _first_frame: int = 0
    _last_position: np.ndarray | None = None

    def state_dict(self) -> dict[str, np.ndarray]:
        """What it learned so far, as arrays (for a checkpoint; :meth:`load_state`)."""
        names = list(self.outcomes)
        return {
            "closures": np.array(self.closures, np.int64).reshape(-1, 3),
            "attempts": np.array(self.attempts, np.int64),
            "outcome_names": np.array(names, dtype=str),
            "outcome_counts": np.array([self.outcomes[k] for k in names], np.int64),
            "last_key": np.array(self._last_key, np.int64),
            "path": np.array(self._path, float),
            "first_frame": np.array(self._first_frame, np.int64),
            "last_position": (
                np.zeros(0) if self._last_position is None else self._last_position.copy()
            ),
        }

    def load_state(self, state: dict[str, np.ndarray]) -> None:
        """Continue from a :meth:`state_dict`."""
        self.closures = [tuple(c) for c in state["closures"].tolist()]
        self.attempts = int(state["attempts"])
        self.outcomes = dict(
            zip(state["outcome_names"].tolist(), state["outcome_counts"].tolist(), strict=True)
        )
        self._last_key = tuple(state["last_key"].tolist())
        self._path = state["path"].tolist()
        self._first_frame = int(state["first_frame"])
        position = np.asarray(state["last_position"], float)
        self._last_position = position.copy() if position.size else None

    def travel(self, t: int, position: np.ndarray) -> None:
        """Record the robot's estimated position at frame ``t`` (every frame, in order)."""
        if self._last_position is None:
            self._first_frame = t
            self._path.append(0.0)
        else:
            self._path.append(
                self._path[-1] + float(np.linalg.norm(position - self._last_position))
            )
        self._last_position = np.array(position, float)

    def travelled_since(self, frames: np.ndarray) -> np.ndarray:
        """Distance travelled since each of ``frames`` (before the first recorded: all of it)."""
        path = np.asarray(self._path)
        index = np.clip(np.asarray(frames, np.int64) - self._first_frame, 0, path.size - 1)
        return path[-1] - path[index]

    def step(
        self,
        t: int,
        state,
        created_ids: np.ndarray,
        created_frames: np.ndarray,
        labels=None,
        views=None,
    ) -> np.ndarray:
        """Look for a revisit in ``state`` at frame ``t`` and merge it (:func:`merge_objects`).

        Parameters
        ----------
        t
            The current frame.
        state
            The robot's :class:`~teamslam.msckf.filter.state.MsckfState`.
        created_ids, created_frames
            The ids the tracker created and the frame of each one's first detection (in
            creation order).
        labels
            ``callable(ids) -> classes`` (``-1``: none) or ``None`` without classes.
        views
            ``callable(ids) -> (n, 3)``: the mean direction from each object to the cameras
            that saw it (:class:`~teamslam.msckf.filter.views.ObjectViews`), or ``None``. With them
            the association refuses a group matched to the mirror image of another
            (:func:`~teamslam.association.flipped`): in a row of parked cars the shape of the
            group fits a row elsewhere turned over.

        Returns
        -------
        numpy.ndarray
            ``(k, 2)`` pairs ``(new id, old id)`` merged (empty: none).
        """
        none = np.zeros((0, 2), np.int64)
        in_state = np.isin(created_ids, state.object_ids)
        ids = created_ids[in_state][-self.recent :]
        if ids.size < self.settings.min_inliers:
            return none
        key = tuple(ids.tolist())
        if key == self._last_key:
            return none
        self._last_key = key
        since = int(created_frames[in_state][-self.recent :].min()) - self.gap
        slots = state.object_slots(ids)
        old_slots = np.flatnonzero(
            (state.object_last_seen < since) & ~np.isin(state.object_ids, ids)
        )
        retired = state.retired.arrays()
        covs = state.object_covs()
        old_ids = np.concatenate([state.object_ids[old_slots], retired["ids"]])
        old = ObjectSummary(
            1,
            old_ids,
            np.concatenate([state.objects[old_slots], retired["means"]]),
            np.concatenate([covs[old_slots], retired["covs"]]),
            views=None if views is None else views(old_ids),
        )
        recent = ObjectSummary(
            0,
            ids,
            state.objects[slots],
            covs[slots],
            views=None if views is None else views(ids),
        )
        # the drift since an old object was last seen: a fraction of the distance travelled
        # (a retired object's last sighting is not kept: all of the distance)
        travelled = np.concatenate(
            [
                self.travelled_since(state.object_last_seen[old_slots]),
                self.travelled_since(np.zeros(len(retired["ids"]), np.int64)),
            ]
        )
        reach = drift_gate(recent, old, travelled, self.settings)
        within = np.flatnonzero(reach.any(axis=0))
        old, reach = old.take(within), reach[:, within]
        if len(old) < self.settings.min_inliers:
            return none
        if labels is not None:
            recent = _with_classes(recent, labels(recent.ids))
            old = _with_classes(old, labels(old.ids))
        self.attempts += 1
        result = find_loop(recent, old, self.settings)
        if not result.matched:
            self.outcomes[result.status] = self.outcomes.get(result.status, 0) + 1
            return none
        # the answer's pairs, once thinned by the association's separation test, still enough
        if result.pairs.shape[0] < self.settings.min_inliers:
            self.outcomes["too-few"] = self.outcomes.get("too-few", 0) + 1
            return none
        # every pair within the drift the distance travelled allows, or no closure at all (a
        # group whose shape fits far away is a coincidence, not a revisit)
        rows = _positions(recent.ids, result.pairs[:, 0])
        cols = _positions(old.ids, result.pairs[:, 1])
        if not reach[rows, cols].all():
            self.outcomes["beyond-drift"] = self.outcomes.get("beyond-drift", 0) + 1
            return none
        if not turn_within_drift(recent, old, rows, cols, result.T_first_second, self.settings):
            self.outcomes["turned"] = self.outcomes.get("turned", 0) + 1
            return none
        self.outcomes["merged"] = self.outcomes.get("merged", 0) + 1
        merge_objects(state, result.pairs, t)
        self.closures.extend((t, int(n), int(o)) for n, o in result.pairs.tolist())
        return result.pairs


def drift_gate(
    recent: ObjectSummary, old: ObjectSummary, travelled: np.ndarray, settings: AssociationSettings
) -> np.ndarray:
    """Which (recent, old) pairs could be one object seen again: ``‖x_n − x_o‖²`` at most the
    ``χ²₃`` gate times ``λ_max(Σ_n) + λ_max(Σ_o) + (ρ L_o)²``, with ``L_o`` the distance the robot
    travelled since ``o`` was last seen and ``ρ`` the association's drift ratio (a map deforms
    by a fraction of the distance covered; no constant in metres). ``(n_recent, n_old)``."""
    delta = recent.means[:, None, :] - old.means[None, :, :]
    sq = np.einsum("abi,abi->ab", delta, delta)
    top_r = np.linalg.eigvalsh(recent.covs)[:, -1] if len(recent) else np.zeros(0)
    top_o = np.linalg.eigvalsh(old.covs)[:, -1] if len(old) else np.zeros(0)
    allowed = top_r[:, None] + top_o[None, :] + (settings.drift_ratio * travelled[None, :]) ** 2
    return sq <= settings.gate_threshold * allowed


def turn_within_drift(
    recent: ObjectSummary,
    old: ObjectSummary,
    rows: np.ndarray,
    cols: np.ndarray,
    T_recent_old: np.ndarray,
    settings: AssociationSettings,
) -> bool:
    """Whether the turn of a revisit's transform is one the robot's drift can make.

    A map whose positions drift by a fraction ``ρ`` of the distance driven (the association's
    ``drift_ratio``) has turned by about ``2ρ`` radians over that drive: a heading error growing
    at a steady rate ``κ`` puts the position off by ``κ L² / 2 = ρ L`` after ``L``, having turned
    by ``κ L = 2ρ`` — whatever ``L``. The transform's rotation vector ``φ`` (``R = exp([φ]×)``)
    passes when ``φᵀ (I_φ⁻¹ + (2ρ)² I)⁻¹ φ`` is within the ``χ²₃`` gate, with ``I_φ`` the
    information the pairs hold on the rotation (each pair's position about the pairs' centre,
    weighted by its two covariances): a turn about an axis the pairs do not fix (a row of
    objects turned about itself) is free, a row matched with a row turned about the vertical
    or over is not. Unit-free: a ratio, a χ² quantile.
    """
    r = np.asarray(T_recent_old, dtype=float)[:3, :3]
    points = old.means[cols] @ r.T
    cov = recent.covs[rows] + r @ old.covs[cols] @ r.T
    weights = 1.0 / np.trace(cov, axis1=1, axis2=2)
    q = points - (weights / weights.sum()) @ points
    skew = np.zeros((q.shape[0], 3, 3))
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -q[:, 2], q[:, 1], -q[:, 0]
    skew -= np.swapaxes(skew, 1, 2)
    information = np.einsum("kji,kjl,klm->im", skew, np.linalg.inv(cov), skew)
    phi = Rotation.from_matrix(r).as_rotvec()
    # (I⁻¹ + d I)⁻¹ = (1 + d I)⁻¹ I, defined where I is singular too
    turn = (2 * settings.drift_ratio) ** 2
    allowed = np.linalg.solve(np.eye(3) + turn * information, information)
    return bool(phi @ allowed @ phi <= settings.gate_threshold)


def _positions(ids: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """Positions of ``wanted`` in ``ids`` (all present)."""
    order = np.argsort(ids)
    return order[np.searchsorted(ids[order], wanted)]


def _with_classes(summary: ObjectSummary, classes: np.ndarray) -> ObjectSummary:
    classes = np.asarray(classes, np.int64)
    if (classes < 0).any():  # an object without a class: compare shapes alone
        return summary
    return ObjectSummary(
        summary.robot, summary.ids, summary.means, summary.covs, classes, summary.views
    )


def find_loop(
    recent: ObjectSummary, old: ObjectSummary, settings: AssociationSettings | None = None
) -> AssociationResult:
    """Which recent objects are old ones seen again: the association of the two maps of one
    robot (:func:`~teamslam.association.associate`; ``recent`` plays the first role).

    Parameters
    ----------
    recent, old
        Summaries of the recent and the old objects of the same robot (their ``robot`` fields
        only tell the two roles apart: ``recent`` must have the smaller).
    settings
        The association's thresholds.

    Returns
    -------
    AssociationResult
        ``pairs`` ``(recent id, old id)`` when matched; no pair when too few or ambiguous.
    """
    return associate(recent, old, settings)


def merge_objects(
    state,
    pairs: np.ndarray,
    frame: int,
    factors: np.ndarray | None = None,
    offsets: np.ndarray | None = None,
) -> np.ndarray:
    """Merge object ``n`` into object ``o`` for each row ``(n, o)`` of ``pairs``.

    One EKF update with the stacked constraints ``x_n − x_o = 0`` (noise ``ε`` of
    :data:`MERGE_RELATIVE_NOISE` times each pair's prior variance), then every ``x_n`` leaves the
    state (concept page *Tracking*). An ``o`` of the persistent map re-enters the state first.
    ``o`` counts as last seen when the later of the two was.

    Parameters
    ----------
    state
        A :class:`~teamslam.msckf.filter.state.MsckfState`.
    pairs
        ``(k, 2)`` ids ``(n, o)``: each ``n`` in the state, each ``o`` in the state or the
        persistent map; all ``2k`` ids distinct.
    frame
        The current frame (when a re-entering ``o`` counts as seen at the latest).
    factors
        ``(k, 2)`` per pair the factors ``(r_n, r_o)`` by which the two objects' covariances
        are too small (:func:`difference_d2`'s); the constraint then carries the part of the
        widened difference covariance the held one lacks, ``max(D' − D, 0)`` (its positive
        eigenvalues), as noise: the two estimates differ by an offset the held covariances do
        not show, and pulling them together as if exact would move the rest of the state by
        it. ``None``: exact (as held).
    offsets
        ``(k,)`` per pair the largest variance on every axis by which the two estimates may
        differ beyond their covariances (the views' offsets, :func:`difference_d2`'s
        ``offset``). The constraint carries as noise the part of the pair's difference ``r``
        its covariance ``D`` (widened, with ``factors``) does not explain, the moment estimate
        ``(|r|² − tr D) / 3`` taken within ``[0, offset]``: two estimates that agree merge as
        before, two a view's offset apart do not pull the state by it. ``None``: none.

    Returns
    -------
    numpy.ndarray
        The applied error-state correction (before ``x_n`` left).
    """
    pairs = np.asarray(pairs, np.int64).reshape(-1, 2)
    if pairs.size == 0:
        return np.zeros(state.dim)
    if np.unique(pairs).size != pairs.size:
        raise ValueError("merge_objects: an object appears twice in the pairs")
    new, old = pairs[:, 0], pairs[:, 1]
    if (state.object_slots(new) < 0).any():
        raise ValueError("merge_objects: a new object is not in the state")
    back = old[state.retired.contains(old)] if len(state.retired) else old[:0]
    if back.size:
        state.reenter_objects(back, frame)
    slots_n, slots_o = state.object_slots(new), state.object_slots(old)
    if (slots_o < 0).any():
        raise ValueError("merge_objects: an old object is neither in the state nor retired")
    seen = np.maximum(state.object_last_seen[slots_n], state.object_last_seen[slots_o])
    if back.size:  # a retired object's own last sighting is older than the new one's
        seen[np.isin(old, back)] = state.object_last_seen[slots_n[np.isin(old, back)]]
    cols_n = state.object_columns(slots_n)  # (k, 3)
    cols_o = state.object_columns(slots_o)
    k = pairs.shape[0]
    jacobian = np.zeros((3 * k, state.dim))
    rows = np.arange(3 * k).reshape(k, 3)
    jacobian[rows, cols_n] = 1.0
    jacobian[rows, cols_o] = -1.0
    residual = (state.objects[slots_o] - state.objects[slots_n]).ravel()  # 0 − (x_n − x_o)
    cov = state.covariance(np.concatenate([cols_n, cols_o], axis=1))  # (k, 6, 6)
    diff_var = np.einsum("kii->k", cov[:, :3, :3] + cov[:, 3:, 3:] - 2 * cov[:, :3, 3:]) / 3
    noise = np.diag(np.repeat(MERGE_RELATIVE_NOISE * diff_var, 3))
    explained = _difference_cov(cov)
    if factors is not None:
        scale = np.sqrt(np.repeat(np.asarray(factors, float).reshape(k, 2), 3, axis=1))
        wide = cov * scale[:, :, None] * scale[:, None, :]
        extra = _difference_cov(wide) - explained
        values, vectors = np.linalg.eigh(0.5 * (extra + np.swapaxes(extra, 1, 2)))
        extra = (vectors * np.maximum(values, 0.0)[:, None, :]) @ np.swapaxes(vectors, 1, 2)
        for i in range(k):
            noise[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] += extra[i]
        explained = explained + extra
    if offsets is not None:
        r = residual.reshape(k, 3)
        unexplained = (np.einsum("ki,ki->k", r, r) - np.einsum("kii->k", explained)) / 3.0
        offset = np.clip(unexplained, 0.0, np.asarray(offsets, float).reshape(k))
        noise += np.diag(np.repeat(offset, 3))
    delta = state.update(jacobian, residual, noise)
    state.object_last_seen[slots_o] = seen
    state.retire_objects(slots_n)
    state.retired.take(new)
    return delta


def difference_d2(
    state,
    new: int,
    old: np.ndarray,
    factors: tuple[float, np.ndarray] | None = None,
    offset: np.ndarray | None = None,
) -> np.ndarray:
    """``d² = rᵀ D⁻¹ r`` of ``r = x_n − x_o`` for object ``new`` against each of ``old``.

    ``D = P_nn + P_oo − P_no − P_on`` from the joint state: an old object of the state shares
    the robot's pose uncertainty with the new one through the cross-covariance; one of the
    persistent map keeps only its own covariance (no cross term).

    Parameters
    ----------
    state
        A :class:`~teamslam.msckf.filter.state.MsckfState` holding ``new``.
    new
        The new object's id.
    old
        ``(k,)`` ids, each in the state or the persistent map.
    factors
        ``(r_n, (k,) r_o)``: each object's covariance widened by its factor, the cross term by
        ``√(r_n r_o)`` (``D P D``, ``√r`` on each object's coordinates: the factors by which
        covariances formed before the box noise's overconfidence factor are too small,
        :class:`~teamslam.msckf.filter.box_noise.FormedUnder`); ``None``: as held.
    offset
        ``(k,)`` a variance added to ``D`` on every axis per pair: what the two estimates may
        differ by beyond their covariances (the offset of the points their boxes showed from
        different views, the tracker's ``_view_offset``); ``None``: nothing.

    Returns
    -------
    numpy.ndarray
        ``(k,)`` squared Mahalanobis distances (χ²(3) when ``x_n`` and ``x_o`` are one object).
    """
    old = np.asarray(old, np.int64).reshape(-1)
    out = np.empty(old.size)
    slot_n = state.object_slots(np.array([new]))
    cols_n = state.object_columns(slot_n)[0]
    slots = state.object_slots(old)
    inside = slots >= 0
    if inside.any():
        cols_o = state.object_columns(slots[inside])
        cols = np.concatenate([np.broadcast_to(cols_n, cols_o.shape), cols_o], axis=1)
        cov = state.covariance(cols)  # (k, 6, 6)
        if factors is not None:
            b = np.asarray(factors[1], float)[inside]
            scale = np.sqrt(np.repeat(np.column_stack([np.full(b.size, factors[0]), b]), 3, 1))
            cov = cov * scale[:, :, None] * scale[:, None, :]  # D P D: each block widened
        diff = cov[:, :3, :3] + cov[:, 3:, 3:] - cov[:, :3, 3:] - cov[:, 3:, :3]
        if offset is not None:
            diff = diff + np.asarray(offset, float)[inside, None, None] * np.eye(3)
        r = state.objects[slot_n] - state.objects[slots[inside]]
        out[inside] = _squared_mahalanobis(r, diff)
    if (~inside).any():
        retired = state.retired.arrays()
        where = _positions(retired["ids"], old[~inside])
        own = state.covariance(cols_n)
        r = state.objects[slot_n] - retired["means"][where]
        if factors is None:
            diff = own[None] + retired["covs"][where]
        else:
            b = np.asarray(factors[1], float)[~inside][:, None, None]
            diff = float(factors[0]) * own[None] + b * retired["covs"][where]
        if offset is not None:
            diff = diff + np.asarray(offset, float)[~inside, None, None] * np.eye(3)
        out[~inside] = _squared_mahalanobis(r, diff)
    return out


def _difference_cov(cov: np.ndarray) -> np.ndarray:
    """``(k, 3, 3)`` covariance of ``x_n − x_o`` from joint ``(k, 6, 6)`` covariances."""
    return cov[:, :3, :3] + cov[:, 3:, 3:] - cov[:, :3, 3:] - cov[:, 3:, :3]


def _squared_mahalanobis(r: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """``rᵀ C⁻¹ r`` per row of ``r`` ``(k, 3)`` with ``cov`` ``(k, 3, 3)``."""
    return np.einsum("ki,ki->k", r, np.linalg.solve(cov, r[..., None])[..., 0])


class PositionRatio:
    """The likelihood ratio of a position difference for re-identification: one object seen
    twice against two objects.

    One object: the difference's ``d²`` (under the re-identification gate's covariance) is
    ``χ²(3)``. Two objects: learned in the run, from the ``d²`` of every new object against
    every old object of each re-identification call (of every class: the pairs are nearly all
    of two objects), kept as counts in ``log d²`` (bins a quarter of the kernel's width) and
    smoothed by a kernel as wide as the spread of ``log χ²(3)``. The two objects' density is
    shrunk towards one object's by one pseudo-pair, so ``N`` pairs counted can testify at most
    ``N + 1`` to one object: no evidence before any is counted, and a few far pairs cannot
    make a near one certain. Unit-free, whatever the camera or the scene.
    """

    #: ``log d²`` of the first bin's lower edge and of the last bin's upper edge (beyond: the
    #: end bins)
    LOG_RANGE = (-16.0, 32.0)

    def __init__(self) -> None:
        self.width = log_chi2_std(3)
        low, high = self.LOG_RANGE
        bins = int(np.ceil((high - low) / (0.25 * self.width)))
        self.edges = np.linspace(low, high, bins + 1)
        #: pairs of two objects counted per bin of ``log d²``
        self.counts = np.zeros(bins)

    def __len__(self) -> int:
        return int(self.counts.sum())

    def add(self, d2: np.ndarray) -> None:
        """Count the ``d²`` of pairs of (nearly always) two objects."""
        d2 = np.asarray(d2, float).ravel()
        d2 = d2[np.isfinite(d2) & (d2 > 0)]
        if d2.size:
            index = np.searchsorted(self.edges, np.log(d2), side="right") - 1
            np.add.at(self.counts, np.clip(index, 0, self.counts.size - 1), 1.0)

    def log_ratio(self, d2: np.ndarray) -> np.ndarray:
        """``log`` of the density of ``d²`` for one object over that for two (class
        docstring); 0 for every pair before any is counted."""
        d2 = np.maximum(np.asarray(d2, float).ravel(), 1e-300)
        n = self.counts.sum()
        if n == 0:
            return np.zeros(d2.size)
        centres = 0.5 * (self.edges[1:] + self.edges[:-1])
        used = self.counts > 0
        z = (np.log(d2)[:, None] - centres[used][None, :]) / self.width
        kernel = np.exp(-0.5 * z * z) @ self.counts[used] / (n * self.width * np.sqrt(2 * np.pi))
        one = stats.chi2.pdf(d2, 3)
        two = (n * kernel / d2 + one) / (n + 1.0)  # in d², one pseudo-pair of one object
        return np.log(np.maximum(one, 1e-300)) - np.log(np.maximum(two, 1e-300))

    def arrays(self) -> np.ndarray:
        """The counts (for a snapshot; :meth:`from_arrays`)."""
        return self.counts.copy()

    @classmethod
    def from_arrays(cls, counts: np.ndarray) -> PositionRatio:
        """The ratio of :meth:`arrays`' counts."""
        out = cls()
        counts = np.asarray(counts, float).ravel()
        if counts.size != out.counts.size or not np.isfinite(counts).all() or (counts < 0).any():
            raise ValueError(
                f"position ratio: {counts.size} counts where {out.counts.size} finite, "
                "non-negative ones belong"
            )
        out.counts = counts.copy()
        return out


def revisit_posterior(log_ratio: np.ndarray, prior: float) -> np.ndarray:
    """Posterior probability that a new object is each candidate old object seen again.

    Hypotheses: a new object (prior ``1 − π``) or one of the ``k`` candidates (``π / k``
    each); each candidate's evidence weighs in by its log likelihood ratio of *same object*
    against *another* (the new-object hypothesis its reference, ratio 1). So a candidate wins
    only against both a new object and its runner-up.

    Parameters
    ----------
    log_ratio
        ``(k,)`` log likelihood ratio of each candidate's evidence.
    prior
        ``π``, the probability that a new object is a revisit (learned in the run).

    Returns
    -------
    numpy.ndarray
        ``(k,)`` posterior probabilities (the rest is the new object's).
    """
    log_ratio = np.asarray(log_ratio, float).reshape(-1)
    if not log_ratio.size:
        return np.zeros(0)
    a = np.log(prior / log_ratio.size) + log_ratio
    b = np.log1p(-prior)
    top = max(float(a.max()), b)
    weights = np.exp(a - top)
    return weights / (np.exp(b - top) + weights.sum())
