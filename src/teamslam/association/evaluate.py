"""Scoring correspondences against ground truth (evaluation only; never read by a filter)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from teamslam.errors import InputError

__all__ = ["CorrespondenceScore", "score_correspondences"]


@dataclass(frozen=True)
class CorrespondenceScore:
    """Correct and wrong correspondences of one link, against the objects both robots hold.

    Attributes
    ----------
    correct, wrong
        Pairs naming the same object / different objects (or an object without truth).
    shared
        Objects both maps hold (by ground truth): what a perfect association would find.
    precision
        ``correct / (correct + wrong)``; 1 when there is no pair.
    recall
        ``correct / shared``; 1 when nothing is shared.
    """

    correct: int
    wrong: int
    shared: int

    @property
    def precision(self) -> float:
        total = self.correct + self.wrong
        return self.correct / total if total else 1.0

    @property
    def recall(self) -> float:
        return self.correct / self.shared if self.shared else 1.0

    def to_json(self) -> dict:
        """The counts and both ratios as a JSON-ready dict."""
        return {
            "correct": self.correct,
            "wrong": self.wrong,
            "shared": self.shared,
            "precision": self.precision,
            "recall": self.recall,
        }


def _lookup(ids: np.ndarray, keys: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``values[keys == id]`` for every id; -1 where the id has no entry."""
    order = np.argsort(keys, kind="stable")
    keys, values = keys[order], values[order]
    pos = np.clip(np.searchsorted(keys, ids), 0, max(keys.size - 1, 0))
    out = np.full(ids.shape, -1, dtype=np.int64)
    if keys.size:
        hit = keys[pos] == ids
        out[hit] = values[pos[hit]]
    return out


def score_correspondences(
    pairs: np.ndarray,
    own_ids: np.ndarray,
    their_ids: np.ndarray,
    own_truth: tuple[np.ndarray, np.ndarray] | None = None,
    their_truth: tuple[np.ndarray, np.ndarray] | None = None,
) -> CorrespondenceScore:
    """Precision and recall of correspondences ``(own id, their id)`` against the truth.

    Parameters
    ----------
    pairs
        ``(k, 2)`` rows ``(own id, their id)``.
    own_ids, their_ids
        The object ids each map holds (what could have been matched).
    own_truth, their_truth
        ``(robot's ids, team object ids)``: which true object each of the robot's ids is
        (:meth:`~teamslam.datasets.model.TeamDataset.true_objects`). ``None`` means the ids are
        team-wide already (an id is its own truth).

    Returns
    -------
    CorrespondenceScore
    """
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    own_ids = np.asarray(own_ids, dtype=np.int64).reshape(-1)
    their_ids = np.asarray(their_ids, dtype=np.int64).reshape(-1)
    if pairs.size and (
        not np.isin(pairs[:, 0], own_ids).all() or not np.isin(pairs[:, 1], their_ids).all()
    ):
        raise InputError("a correspondence names an id its map does not hold")

    def true_of(ids: np.ndarray, truth) -> np.ndarray:
        if truth is None:
            return ids.copy()
        keys, values = (np.asarray(x, dtype=np.int64).reshape(-1) for x in truth)
        if keys.shape != values.shape:
            raise InputError("truth ids and team object ids differ in length")
        return _lookup(ids, keys, values)

    own_true = true_of(own_ids, own_truth)
    their_true = true_of(their_ids, their_truth)
    shared = np.intersect1d(own_true[own_true >= 0], their_true[their_true >= 0]).size
    if not pairs.size:
        return CorrespondenceScore(0, 0, int(shared))
    a = true_of(pairs[:, 0], own_truth)
    b = true_of(pairs[:, 1], their_truth)
    correct = int(np.count_nonzero((a == b) & (a >= 0)))
    return CorrespondenceScore(correct, int(pairs.shape[0] - correct), int(shared))
