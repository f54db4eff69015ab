"""How alike two detections look, as a likelihood ratio learned from the run itself.

Descriptors (any dimension, any scale: a front-end's histogram or a user's embedding) are
compared by their cosine distance ``d = 1 − cos θ ∈ [0, 2]``. :class:`AppearanceModel` keeps
two histograms of ``d`` (binned by the chord ``√(2d)``, finer where descriptors agree):
*same* — a detection against the summary of the confirmed object that took it; *different* —
two detections of one frame, and a detection against the summaries of the other objects
assigned in its frame (a detector boxes an object once a frame). With a uniform Dirichlet
prior on both, ``log_ratio(d) = log p_same(d) − log p_different(d)`` is exactly 0 before any
sample and tends to 0 wherever the two agree (appearance that says nothing).
:attr:`informative` says whether the samples separate the two beyond chance (a one-sided rank
test at ``1 − probability``). :class:`AppearanceMemory` keeps each object's summary: the mean
of its detections' unit descriptors. The rules and why: the concept page *Tracking*.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import norm

__all__ = ["AppearanceMemory", "AppearanceModel", "cosine_distances", "unit_rows"]

#: Histogram bins over the chord length ``√(2d) ∈ [0, 2]``.
BINS = 40


def unit_rows(a: np.ndarray) -> np.ndarray:
    """Rows scaled to unit norm (a zero row stays zero)."""
    a = np.asarray(a, dtype=np.float64)
    n = np.linalg.norm(a, axis=-1, keepdims=True)
    return np.divide(a, n, out=np.zeros_like(a), where=n > 0)


def cosine_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(A, B)`` cosine distances ``1 − cos θ`` between the rows of ``a`` and of ``b``; NaN
    where either row is zero (a descriptor without content compares with nothing)."""
    ua, ub = unit_rows(a), unit_rows(b)
    d = np.clip(1.0 - ua @ ub.T, 0.0, 2.0)
    empty = ~ua.any(axis=1)[:, None] | ~ub.any(axis=1)[None, :]
    d[empty] = np.nan
    return d


class AppearanceModel:
    """The learned likelihood ratio of *same object* against *different objects*.

    Parameters
    ----------
    probability
        The confidence of :attr:`informative`'s test (the tracker's gate probability).
    """

    def __init__(self, probability: float) -> None:
        self.probability = float(probability)
        self.same = np.zeros(BINS)
        self.different = np.zeros(BINS)
        self._table = np.zeros(BINS)
        self._informative = False

    @staticmethod
    def _bins(d: np.ndarray) -> np.ndarray:
        chord = np.sqrt(2.0 * np.asarray(d, dtype=np.float64))
        return np.minimum((chord * (BINS / 2.0)).astype(np.int64), BINS - 1)

    def add(self, same: np.ndarray, different: np.ndarray) -> None:
        """Count samples of the distance between the same object's and different objects'
        descriptors (NaN ones left out); the ratio and the test are recomputed."""
        same, different = np.ravel(same), np.ravel(different)
        same, different = same[np.isfinite(same)], different[np.isfinite(different)]
        self.same += np.bincount(self._bins(np.ravel(same)), minlength=BINS)
        self.different += np.bincount(self._bins(np.ravel(different)), minlength=BINS)
        p_same = (self.same + 1.0) / (self.same.sum() + BINS)
        p_diff = (self.different + 1.0) / (self.different.sum() + BINS)
        self._table = np.log(p_same) - np.log(p_diff)
        self._informative = self.separation() > norm.ppf(self.probability)

    def log_ratio(self, d: np.ndarray) -> np.ndarray:
        """``log p(d | same) − log p(d | different)`` at cosine distances ``d`` (0 at NaN)."""
        d = np.asarray(d, dtype=np.float64)
        known = np.isfinite(d)
        return np.where(known, self._table[self._bins(np.where(known, d, 0.0))], 0.0)

    def auc(self) -> float:
        """Probability that a *same* sample lies nearer than a *different* one (ties half):
        the area under the ROC curve of the distance as a classifier (0.5 before samples)."""
        n_s, n_d = self.same.sum(), self.different.sum()
        if n_s == 0 or n_d == 0:
            return 0.5
        below = np.concatenate([[0.0], np.cumsum(self.different)[:-1]])
        wins = (self.same * (n_d - below - self.different)).sum()
        ties = (self.same * self.different).sum()
        return float((wins + 0.5 * ties) / (n_s * n_d))

    def separation(self) -> float:
        """The rank statistic's z-score for *same nearer than different* (0 without samples)."""
        n_s, n_d = self.same.sum(), self.different.sum()
        if n_s == 0 or n_d == 0:
            return 0.0
        se = np.sqrt((n_s + n_d + 1.0) / (12.0 * n_s * n_d))
        return float((self.auc() - 0.5) / se)

    @property
    def informative(self) -> bool:
        """Whether *same* is nearer than *different* beyond chance at ``probability``."""
        return self._informative


class AppearanceMemory:
    """Each object's appearance summary: the mean of its detections' unit descriptors."""

    def __init__(self, dimension: int) -> None:
        self.dimension = int(dimension)
        self._sums: dict[int, np.ndarray] = {}

    def __contains__(self, object_id: int) -> bool:
        return int(object_id) in self._sums

    def summaries(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(K, D)`` summaries of ``ids`` and which of them have one (zeros where not)."""
        out = np.zeros((len(ids), self.dimension))
        known = np.zeros(len(ids), bool)
        for i, object_id in enumerate(np.asarray(ids).tolist()):
            s = self._sums.get(object_id)
            if s is not None:
                out[i], known[i] = s, True
        return out, known

    def add(self, object_id: int, descriptors: np.ndarray) -> None:
        """Fold detections' descriptors (``(k, D)`` or ``(D,)``) into ``object_id``'s summary."""
        total = unit_rows(np.atleast_2d(descriptors)).sum(axis=0)
        if not total.any():  # a descriptor without content (a flat patch) says nothing
            return
        key = int(object_id)
        self._sums[key] = self._sums.get(key, 0.0) + total

    def merge(self, new: int, old: int) -> None:
        """Object ``new`` is ``old`` seen again: one summary under ``old``."""
        s = self._sums.pop(int(new), None)
        if s is not None:
            self._sums[int(old)] = self._sums.get(int(old), 0.0) + s

    def rename(self, old: int, new: int) -> None:
        """A summary kept under ``old`` belongs to ``new`` (``old`` forgotten)."""
        s = self._sums.pop(int(old), None)
        if s is not None:
            self._sums[int(new)] = s

    def forget(self, object_id: int) -> None:
        """Drop ``object_id``'s summary."""
        self._sums.pop(int(object_id), None)
