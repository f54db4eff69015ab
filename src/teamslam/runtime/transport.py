"""How agents hear each other: the ``Transport`` seam and its in-process lock-step implementation.

An agent never reaches into another agent: everything it learns about a neighbour arrives as a
message through a :class:`Transport`. The in-process transport delivers, at each step, exactly
the messages sent over the edges that survived that step's link loss, in a deterministic order;
a network transport (one process per robot) implements the same two methods.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

__all__ = ["CommonMarginalMessage", "InProcessTransport", "MapIdsMessage", "Message", "Transport"]


@dataclass(frozen=True)
class MapIdsMessage:
    """Round 1 of consensus: the ids of the objects in the sender's map."""

    sender: int
    receiver: int
    step: int
    ids: np.ndarray

    def nbytes(self) -> int:
        """Payload size on a wire (header of four int64 plus the ids)."""
        return 32 + 8 * int(np.size(self.ids))


@dataclass(frozen=True)
class CommonMarginalMessage:
    """Round 2: the sender's marginal of the objects it shares with the receiver (eq. 19)."""

    sender: int
    receiver: int
    step: int
    ids: np.ndarray
    mean: np.ndarray
    cov: np.ndarray

    def nbytes(self) -> int:
        """Payload size on a wire: ids, mean and the covariance's upper triangle."""
        d = int(np.size(self.mean))
        return 32 + 8 * int(np.size(self.ids)) + 8 * d + 8 * (d * (d + 1) // 2)


Message = MapIdsMessage | CommonMarginalMessage


class Transport(Protocol):
    """What an agent may do to talk to its neighbours."""

    def send(self, message: Message) -> None:
        """Send a message to ``message.receiver``."""

    def receive(self, robot: int) -> list[Message]:
        """Take every message delivered to ``robot`` so far."""


@dataclass
class InProcessTransport:
    """Lock-step delivery inside one process, honouring each step's surviving edges.

    Attributes
    ----------
    active
        ``(n, n)`` adjacency of the links that work this step (set by the team runner).
    messages_sent, bytes_sent
        Per-robot counters.
    """

    n: int
    active: np.ndarray = field(default=None)  # type: ignore[assignment]
    messages_sent: np.ndarray = field(default=None)  # type: ignore[assignment]
    bytes_sent: np.ndarray = field(default=None)  # type: ignore[assignment]
    dropped: int = 0
    _mailbox: dict[int, list[Message]] = field(default_factory=lambda: defaultdict(list))

    def __post_init__(self) -> None:
        if self.active is None:
            self.active = np.zeros((self.n, self.n), dtype=bool)
        self.messages_sent = np.zeros(self.n, dtype=np.int64)
        self.bytes_sent = np.zeros(self.n, dtype=np.int64)

    def set_active(self, adjacency: np.ndarray) -> None:
        """The links usable from now on (one step)."""
        self.active = np.asarray(adjacency, dtype=bool)

    def send(self, message: Message) -> None:
        """Deliver if the sender–receiver link is up; otherwise the message is lost."""
        s, r = message.sender, message.receiver
        self.messages_sent[s] += 1
        self.bytes_sent[s] += message.nbytes()
        if 0 <= r < self.n and self.active[s, r]:
            self._mailbox[r].append(message)
        else:
            self.dropped += 1

    def receive(self, robot: int) -> list[Message]:
        """Messages delivered to ``robot``, in sending order."""
        return self._mailbox.pop(robot, [])
