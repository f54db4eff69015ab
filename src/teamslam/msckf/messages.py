"""The consensus messages: what one robot may tell a neighbour (distributed MSCKF paper, §V-B).

Two rounds per step:

1. :class:`MapIdsMessage` — the ids of the objects in the sender's map;
2. :class:`CommonMarginalMessage` — the sender's marginal (mean and covariance) of the objects it
   shares with the receiver, plus the number of neighbours the sender heard in round 1 (its
   degree this step), from which both ends compute the same Metropolis–Hastings weight.

Messages are plain data. How they travel is a :class:`~teamslam.msckf.transport.Transport`;
their byte layout on a network is :mod:`teamslam.runtime.wire`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CommonMarginalMessage", "MapIdsMessage", "Message"]


@dataclass(frozen=True)
class MapIdsMessage:
    """Round 1 of consensus: the ids of the objects in the sender's map.

    Attributes
    ----------
    ids
        Every object in the sender's map.
    moved
        One flag per id: whether the sender's marginal of that object has moved since the two
        robots last exchanged it (``None``: all have — average every common object).
    """

    sender: int
    receiver: int
    step: int
    ids: np.ndarray
    moved: np.ndarray | None = None

    def nbytes(self) -> int:
        """Payload size on a wire (header, the ids, one bit per id for ``moved``)."""
        return 32 + 8 * int(np.size(self.ids)) + (int(np.size(self.ids)) + 7) // 8


@dataclass(frozen=True)
class CommonMarginalMessage:
    """Round 2: the sender's marginal of the objects it shares with the receiver (eq. 19).

    Attributes
    ----------
    ids
        The shared objects' ids.
    mean, cov
        Their marginal, ``3·len(ids)`` long, in the order of ``ids``: ``cov`` is the joint
        ``(3k, 3k)`` covariance, or ``(k, 3, 3)`` — each object's own block — for a
        per-object message.
    degree
        How many neighbours the sender heard from in round 1 of this step.
    """

    sender: int
    receiver: int
    step: int
    ids: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    degree: int = 0

    @property
    def per_object(self) -> bool:
        """Whether ``cov`` holds each object's own 3×3 block only."""
        return np.ndim(self.cov) == 3

    @property
    def single_precision(self) -> bool:
        """Whether every number is exactly a float32 (sent in 4 bytes)."""
        mean, cov = np.asarray(self.mean), np.asarray(self.cov)
        return bool(
            np.array_equal(mean.astype(np.float32), mean)
            and np.array_equal(cov.astype(np.float32), cov)
        )

    def nbytes(self) -> int:
        """Payload size on a wire: ids, mean and the covariance's upper triangle(s)."""
        d = int(np.size(self.mean))
        k = int(np.size(self.ids))
        upper = 6 * k if self.per_object else d * (d + 1) // 2
        width = 4 if self.single_precision else 8
        return 32 + 8 * k + width * (d + upper)


Message = MapIdsMessage | CommonMarginalMessage
