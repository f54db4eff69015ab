"""What neighbours exchange to find their common objects: a compact summary of each map."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from teamslam.association.appearance import BINS
from teamslam.errors import InputError
from teamslam.gaussian import symmetrize

__all__ = ["ObjectSummary", "descriptor_codes", "descriptors_from_codes", "varint_sizes"]

#: Bytes per object on the wire: id (8), mean (3 × 8), upper triangle of the covariance
#: (6 × 8), the direction to the sender's cameras (3 × 4), and a class label (8) when the map
#: has classes.
BYTES_PER_OBJECT = 8 + 3 * 8 + 6 * 8 + 3 * 4
BYTES_PER_CLASS = 8
#: Bytes per descriptor component (int8: :func:`descriptor_codes`) when the map has
#: appearance, and of the summary's dimension (2) once per summary; its *same*-distance
#: histogram (:data:`~teamslam.association.appearance.BINS` counts) follows as LEB128 varints
#: (:func:`varint_sizes`).
BYTES_PER_APPEARANCE = 1
BYTES_APPEARANCE_HEADER = 2
#: The largest code of a descriptor component on the wire.
CODE_PEAK = 127


def descriptor_codes(appearance: np.ndarray) -> np.ndarray:
    """``(n, D)`` int8 wire codes of descriptors: each row scaled so that its largest absolute
    component is :data:`CODE_PEAK`, then rounded (a zero row stays zero).

    Descriptors are compared by direction alone (cosine distance), so no scale travels: the
    receiver takes the codes' direction (:func:`descriptors_from_codes`). With ``p`` the row's
    largest absolute unit component, the direction moves by at most ``√D · p / 127`` (the
    chord between the unit rows): each code is off by at most ½ on a row of norm ``127 / p``.
    """
    a = np.asarray(appearance, dtype=np.float64)
    peak = np.max(np.abs(a), axis=-1, keepdims=True, initial=0.0)
    scaled = np.divide(CODE_PEAK * a, peak, out=np.zeros_like(a), where=peak > 0)
    return np.clip(np.rint(scaled), -CODE_PEAK, CODE_PEAK).astype(np.int8)


def descriptors_from_codes(codes: np.ndarray) -> np.ndarray:
    """Unit rows (float64) of wire codes (:func:`descriptor_codes`; a zero row stays zero).
    Coding them again gives the same codes."""
    c = np.asarray(codes, dtype=np.float64)
    norms = np.linalg.norm(c, axis=-1, keepdims=True)
    return np.divide(c, norms, out=np.zeros_like(c), where=norms > 0)


def varint_sizes(values: np.ndarray) -> np.ndarray:
    """Bytes of each non-negative integer as an LEB128 varint (7 bits a byte, at least one)."""
    v = np.asarray(values, dtype=np.uint64).reshape(-1)
    bits = np.zeros(v.shape, np.int64)
    rest = v.copy()
    while rest.any():
        bits += rest > 0
        rest >>= np.uint64(1)
    return np.maximum((bits + 6) // 7, 1)


@dataclass(frozen=True)
class ObjectSummary:
    """One robot's objects as its neighbours see them: ids, means and marginal covariances.

    Attributes
    ----------
    robot
        The robot's id in the team; it orders the two sides of a link so that both ends
        compute the same association (see :func:`~teamslam.association.associate`).
    ids
        ``(n,)`` int64, the robot's own object ids (unique; unrelated to its neighbours' ids).
    means
        ``(n, 3)`` positions in the robot's world frame.
    covs
        ``(n, 3, 3)`` marginal covariances (symmetric positive definite).
    classes
        ``(n,)`` int64 class labels, or ``None`` when the robot's detector gives none.
        Objects of different classes are never matched.
    views
        ``(n, 3)`` where the robot's cameras were when they observed each object: the mean of
        the unit directions from the object to the camera over its observations, in the
        robot's world frame (a zero row: not known), or ``None`` (none known). It tells on which
        side of a near-planar group of objects the robot saw them from, which their positions
        alone cannot (see :func:`~teamslam.association.flipped`). Stored rounded to float32,
        as the wire carries it, so that both ends of a link compute with the same numbers.
    appearance
        ``(n, D)`` each object's appearance descriptor (any scale: compared by cosine
        distance; a zero row: not known), or ``None`` (the robot has none). Stored as the wire
        carries it: the unit direction of its int8 codes (:func:`descriptor_codes`).
    same_counts
        ``(BINS,)`` int64 histogram of cosine distances between descriptors of one object
        that the robot has seen (its held pairs with its neighbours, its tracker's samples;
        :mod:`~teamslam.association.appearance`), or ``None``; only with ``appearance``.
    """

    robot: int
    ids: np.ndarray
    means: np.ndarray
    covs: np.ndarray
    classes: np.ndarray | None = None
    views: np.ndarray | None = None
    appearance: np.ndarray | None = None
    same_counts: np.ndarray | None = None

    def __post_init__(self) -> None:
        where = f"object summary of robot {self.robot}"
        try:
            ids = np.asarray(self.ids, dtype=np.int64).reshape(-1)
            means = np.asarray(self.means, dtype=float)
            covs = np.asarray(self.covs, dtype=float)
        except (TypeError, ValueError) as exc:
            raise InputError(f"{where}: not numeric arrays ({exc})") from None
        n = ids.size
        means = means.reshape(n, 3) if means.size == 3 * n else means
        covs = covs.reshape(n, 3, 3) if covs.size == 9 * n else covs
        if means.shape != (n, 3):
            raise InputError(f"{where}: means must be ({n}, 3) for {n} ids, got {means.shape}")
        if covs.shape != (n, 3, 3):
            raise InputError(f"{where}: covs must be ({n}, 3, 3) for {n} ids, got {covs.shape}")
        if np.unique(ids).size != n:
            raise InputError(f"{where}: ids contain duplicates")
        if not (np.all(np.isfinite(means)) and np.all(np.isfinite(covs))):
            raise InputError(f"{where}: means or covs are not finite")
        covs = symmetrize(covs)
        eigenvalues = np.linalg.eigvalsh(covs) if n else np.zeros((0, 3))
        if n and np.min(eigenvalues[:, 0]) <= 0:
            bad = int(np.argmin(eigenvalues[:, 0]))
            raise InputError(f"{where}: covariance of object {ids[bad]} is not positive definite")
        classes = self.classes
        if classes is not None:
            classes = np.asarray(classes, dtype=np.int64).reshape(-1)
            if classes.shape != (n,):
                raise InputError(f"{where}: classes must be ({n},), got {classes.shape}")
        views = self.views
        if views is not None:
            try:
                views = np.asarray(views, dtype=float)
            except (TypeError, ValueError) as exc:
                raise InputError(f"{where}: views are not a numeric array ({exc})") from None
            views = views.reshape(n, 3) if views.size == 3 * n else views
            if views.shape != (n, 3):
                raise InputError(f"{where}: views must be ({n}, 3) for {n} ids, got {views.shape}")
            if not np.all(np.isfinite(views)):
                raise InputError(f"{where}: views are not finite")
            if n and np.max(np.abs(views)) > np.finfo(np.float32).max:
                raise InputError(f"{where}: views exceed the float32 range of the wire")
            views = views.astype(np.float32).astype(float)
        appearance, same_counts = self._appearance(where, n)
        object.__setattr__(self, "appearance", appearance)
        object.__setattr__(self, "same_counts", same_counts)
        object.__setattr__(self, "ids", ids)
        object.__setattr__(self, "means", means)
        object.__setattr__(self, "covs", covs)
        object.__setattr__(self, "classes", classes)
        object.__setattr__(self, "views", views)
        # the largest eigenvalue of each covariance, which the gates bound by: known already
        self.__dict__["_top"] = eigenvalues[:, -1]

    def _appearance(self, where: str, n: int) -> tuple[np.ndarray | None, np.ndarray | None]:
        appearance, counts = self.appearance, self.same_counts
        if appearance is None:
            if counts is not None:
                raise InputError(f"{where}: same_counts without appearance")
            return None, None
        try:
            appearance = np.asarray(appearance, dtype=float)
        except (TypeError, ValueError) as exc:
            raise InputError(f"{where}: appearance is not a numeric array ({exc})") from None
        if appearance.ndim != 2 or appearance.shape[0] != n or appearance.shape[1] < 1:
            raise InputError(
                f"{where}: appearance must be ({n}, D) for {n} ids, got {appearance.shape}"
            )
        if not np.all(np.isfinite(appearance)):
            raise InputError(f"{where}: appearance is not finite")
        # the wire's int8 codes, as unit rows (any scale: only directions are compared)
        appearance = descriptors_from_codes(descriptor_codes(appearance))
        if counts is None:
            counts = np.zeros(BINS, np.int64)
        try:
            counts = np.asarray(counts)
        except (TypeError, ValueError) as exc:
            raise InputError(f"{where}: same_counts is not an array ({exc})") from None
        if counts.shape != (BINS,) or counts.dtype.kind not in "iuf":
            raise InputError(f"{where}: same_counts must be ({BINS},) counts, got {counts.shape}")
        if not (np.all(counts >= 0) and np.all(counts == np.floor(counts))):
            raise InputError(f"{where}: same_counts must be whole numbers ≥ 0")
        if counts.max(initial=0) > np.iinfo(np.uint32).max:
            raise InputError(f"{where}: same_counts exceed the wire's uint32")
        return appearance, counts.astype(np.int64)

    def __len__(self) -> int:
        return int(self.ids.size)

    def top_variances(self) -> np.ndarray:
        """``(n,)`` the largest eigenvalue of each object's covariance (computed once per
        summary: the gates bound a pair's Mahalanobis distance by them)."""
        top = self.__dict__.get("_top")
        if top is None:
            top = np.linalg.eigvalsh(self.covs)[:, -1] if len(self) else np.zeros(0)
            self.__dict__["_top"] = top
        return top

    def nearest_distances(self) -> np.ndarray:
        """``(n,)`` the distance from each object to its nearest other object of the map
        (:func:`~teamslam.association.distances.nearest_distance`, computed once per
        summary)."""
        near = self.__dict__.get("_nearest")
        if near is None:
            from teamslam.association.distances import nearest_distance

            near = nearest_distance(self.means)
            self.__dict__["_nearest"] = near
        return near

    @property
    def nbytes(self) -> int:
        """Size of the summary on the wire (see :data:`BYTES_PER_OBJECT`)."""
        per = BYTES_PER_OBJECT + (BYTES_PER_CLASS if self.classes is not None else 0)
        if self.appearance is None:
            return len(self) * per
        per += BYTES_PER_APPEARANCE * self.appearance.shape[1]
        histogram = int(varint_sizes(self.same_counts).sum())
        return len(self) * per + BYTES_APPEARANCE_HEADER + histogram

    def sorted(self) -> ObjectSummary:
        """The same summary with its objects in increasing id order (itself when they are)."""
        if np.all(self.ids[1:] > self.ids[:-1]):
            return self
        order = np.argsort(self.ids, kind="stable")
        return self.take(order)

    def take(self, index: np.ndarray) -> ObjectSummary:
        """The objects at positions ``index`` (in that order).

        The rows are this summary's, already checked and rounded as the wire carries them, so
        they are taken as they are: checking them again would cost an eigen-decomposition per
        object.
        """
        index = np.asarray(index, dtype=np.int64)
        part = object.__new__(ObjectSummary)
        fields = {
            "robot": self.robot,
            "ids": self.ids[index],
            "means": self.means[index],
            "covs": self.covs[index],
            "classes": None if self.classes is None else self.classes[index],
            "views": None if self.views is None else self.views[index],
            "appearance": None if self.appearance is None else self.appearance[index],
            "same_counts": self.same_counts,
        }
        for name, value in fields.items():
            object.__setattr__(part, name, value)
        top = self.__dict__.get("_top")
        if top is not None:  # each covariance's eigenvalues are its own
            part.__dict__["_top"] = top[index]
        return part

    def select(self, ids: np.ndarray) -> ObjectSummary:
        """The objects whose ids are in ``ids`` (in this summary's order)."""
        return self.take(np.flatnonzero(np.isin(self.ids, np.asarray(ids, dtype=np.int64))))

    def updated(self, newer: ObjectSummary) -> ObjectSummary:
        """This summary with the objects of ``newer`` (a later, partial summary of the same
        robot) added or replacing theirs; ids increasing, ``newer``'s *same* histogram.

        What a neighbour holds of a map whose summaries since the last whole one carried only
        the objects new to it.
        """
        if newer.robot != self.robot:
            raise InputError(
                f"object summary of robot {newer.robot} added to one of robot {self.robot}"
            )
        if (self.classes is None) != (newer.classes is None) or (self.appearance is None) != (
            newer.appearance is None
        ):
            raise InputError(f"object summaries of robot {self.robot} carry different fields")
        if self.appearance is not None and self.appearance.shape[1] != newer.appearance.shape[1]:
            raise InputError(f"object summaries of robot {self.robot} differ in appearance size")
        kept = self.take(np.flatnonzero(~np.isin(self.ids, newer.ids)))

        def joined(a: np.ndarray | None, b: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else np.concatenate([a, b])

        both = ObjectSummary(
            self.robot,
            np.concatenate([kept.ids, newer.ids]),
            np.concatenate([kept.means, newer.means]),
            np.concatenate([kept.covs, newer.covs]),
            joined(kept.classes, newer.classes),
            None if kept.views is None or newer.views is None else joined(kept.views, newer.views),
            joined(kept.appearance, newer.appearance),
            newer.same_counts,
        )
        both = both.sorted()
        counted = self.__dict__.get("_within_counts")
        if counted is not None and len(kept) == len(self) and self.appearance is not None:
            # the within-map histogram grows by the new objects' pairs alone
            # (:func:`~teamslam.association.appearance.within_counts`)
            both.__dict__["_grown_from"] = (counted, self.appearance, newer.appearance)
        return both

    def transformed(self, T_new_old: np.ndarray) -> ObjectSummary:
        """The summary expressed in another frame: ``p_new = T_new_old · p_old``."""
        t = np.asarray(T_new_old, dtype=float)
        r = t[:3, :3]
        return ObjectSummary(
            self.robot,
            self.ids,
            self.means @ r.T + t[:3, 3],
            r @ self.covs @ r.T,
            self.classes,
            None if self.views is None else self.views @ r.T,
            self.appearance,
            self.same_counts,
        )
