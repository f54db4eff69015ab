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
test at ``1 − probability``; the model is :mod:`teamslam.association.appearance`'s, shared with
the association between robots). :class:`AppearanceMemory` keeps each object's summary: the mean
of its detections' unit descriptors. The rules and why: the concept page *Tracking*.
"""

from __future__ import annotations

import numpy as np

from teamslam.association.appearance import (
    BINS,
    AppearanceModel,
    cosine_distances,
    unit_rows,
)

__all__ = ["BINS", "AppearanceMemory", "AppearanceModel", "cosine_distances", "unit_rows"]


class AppearanceMemory:
    """Each object's appearance summary: the mean of its detections' unit descriptors."""

    def __init__(self, dimension: int) -> None:
        self.dimension = int(dimension)
        self._sums: dict[int, np.ndarray] = {}

    def summaries(self, ids: np.ndarray) -> np.ndarray:
        """``(K, D)`` summaries of ``ids`` (a zero row where an id has none: it compares with
        nothing, :func:`cosine_distances`)."""
        out = np.zeros((len(ids), self.dimension))
        for i, object_id in enumerate(np.asarray(ids).tolist()):
            s = self._sums.get(object_id)
            if s is not None:
                out[i] = s
        return out

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

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """``(ids, sums)``: every summary's object and its sum of unit descriptors."""
        ids = np.array(list(self._sums), np.int64)
        sums = np.array(list(self._sums.values()), float).reshape(ids.size, self.dimension)
        return ids, sums

    @classmethod
    def from_arrays(cls, ids: np.ndarray, sums: np.ndarray) -> AppearanceMemory:
        """The memory of :meth:`arrays`."""
        sums = np.asarray(sums, float)
        memory = cls(sums.shape[1])
        memory._sums = {
            int(i): s.copy() for i, s in zip(np.asarray(ids).tolist(), sums, strict=True)
        }
        return memory

    def forget(self, object_id: int) -> None:
        """Drop ``object_id``'s summary."""
        self._sums.pop(int(object_id), None)
