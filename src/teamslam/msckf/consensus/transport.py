"""How agents hear each other: the :class:`Transport` seam and its in-memory implementation.

An agent learns about a neighbour only from messages through its own :class:`Transport`
endpoint: send, wait for one message of a kind and step from each of a set of neighbours
(:meth:`Transport.collect`), take each neighbour's newest no older than an age — in steps, or
in seconds of frame stamps (:meth:`Transport.newest`) —, wait for
the neighbours to come up. :class:`MemoryNetwork` implements it in one process, optionally over
lossy links (``links(step)``: a message over a link that is down is lost);
:class:`LyingNetwork` is one whose member ``liar`` sends, in its own name, every marginal
shifted far off with a tiny covariance (the attack the consensus innovation check is there
for); :mod:`teamslam.runtime.zenoh_transport` implements it over a network.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Protocol

import numpy as np

from teamslam.errors import InputError
from teamslam.msckf.consensus.messages import (
    CommonMarginalMessage,
    Message,
    MessageAge,
    MessageLags,
)

__all__ = ["LyingNetwork", "Mailbox", "MemoryNetwork", "MemoryTransport", "Transport"]


class Transport(Protocol):
    """One robot's endpoint: what an agent may do to talk to its neighbours.

    Attributes
    ----------
    messages_sent, bytes_sent
        What this endpoint has sent so far (lost messages included).
    """

    messages_sent: int
    bytes_sent: int

    def send(self, message: Message) -> None:
        """Send ``message`` to ``message.receiver`` (it may be lost)."""

    def collect(
        self,
        step: int,
        kind: type,
        senders: set[int],
        timeout: float,
        also: set[int] | frozenset[int] = frozenset(),
    ) -> list[Message]:
        """Wait until a ``kind`` message of ``step`` arrived from every sender, or ``timeout``.

        Returns one message per sender that was heard (the first to arrive), sorted by sender;
        messages of ``step`` from ``also`` (neighbours not awaited, e.g. reported lost) are
        taken too when they are there. Leftovers of older steps are discarded; later steps'
        messages stay buffered.
        """

    def newest(
        self,
        kind: type,
        senders: set[int],
        max_age: int,
        step: int,
        stamp_ns: int | None = None,
        max_age_ns: int | None = None,
        lags: MessageLags | None = None,
    ) -> list[Message]:
        """Each sender's newest ``kind`` message no older than ``step − max_age``, by sender;
        with ``max_age_ns``, none sent at a frame stamped before ``stamp_ns − max_age_ns``
        (:class:`~teamslam.msckf.consensus.messages.MessageAge`; with ``lags``, each sender's
        limit learned from its lags, and the messages found too old counted there)."""

    def wait_for_peers(self, count: int, timeout: float) -> int:
        """Block until ``count`` neighbours are reachable (or ``timeout``); how many are."""

    def reachable(self, step: int, robots: set[int]) -> set[int]:
        """Which of ``robots`` a message of ``step`` may reach (all, when it cannot be known)."""

    def statistics(self) -> dict:
        """Figures of the link layer: ``injected_drops``, ``rejected_wire`` (messages dropped
        before decoding), ``latencies`` (seconds, one per message received) where known."""

    def finish(self, timeout: float) -> set[int]:
        """Say this robot is done and wait, up to ``timeout`` s, until each neighbour is done
        or gone (so that messages still under way reach it before :meth:`close`); the
        neighbours neither done nor gone at the end."""

    def close(self) -> None:
        """Release the endpoint."""


class Mailbox:
    """Messages delivered to one robot, with the two ways of taking them out (thread-safe).

    A wait's ``timeout`` counts only the time the robot itself was listening: a wait that
    returns later than it asked (the process was suspended, or starved of the processor)
    moves its deadline by the lateness, so a robot held up itself does not take its
    neighbours for lost. ``clock``: the monotonic clock in seconds (replaceable in tests).
    """

    #: longest single wait (s): how soon the robot notices that it was itself held up
    wait_slice = 0.1

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._messages: list[Message] = []
        self._cond = threading.Condition()
        self._clock = clock

    def put(self, message: Message) -> None:
        """Deliver a message."""
        with self._cond:
            self._messages.append(message)
            self._cond.notify_all()

    def collect(
        self, step: int, kind: type, senders: set[int], timeout: float, awaited: set[int] | None
    ) -> list[Message]:
        """One ``kind`` message of ``step`` per sender (the first), waiting up to ``timeout``
        for every sender in ``awaited`` (default: ``senders``); sorted by sender. Older steps'
        leftovers are discarded, later steps' messages kept."""
        awaited = senders if awaited is None else awaited
        deadline = self._clock() + timeout
        with self._cond:
            while True:
                self._messages = [m for m in self._messages if m.step >= step]
                # a sender that already spoke in a later step has moved on (links keep order)
                have = {
                    m.sender
                    for m in self._messages
                    if m.step > step or (m.step == step and isinstance(m, kind))
                }
                asked_at = self._clock()
                remaining = deadline - asked_at
                if have >= awaited or remaining <= 0:
                    break
                asked = min(remaining, self.wait_slice)
                self._cond.wait(asked)
                late = self._clock() - asked_at - asked
                if late > 0:  # this robot was held up itself: not its neighbours' silence
                    deadline += late
            picked: dict[int, Message] = {}
            keep = []
            for m in self._messages:
                if (
                    m.step == step
                    and isinstance(m, kind)
                    and m.sender in senders
                    and m.sender not in picked
                ):
                    picked[m.sender] = m
                else:
                    keep.append(m)
            self._messages = keep
        return [picked[s] for s in sorted(picked)]

    def newest(
        self,
        kind: type,
        senders: set[int],
        max_age: int,
        step: int,
        stamp_ns: int | None = None,
        max_age_ns: int | None = None,
        lags: MessageLags | None = None,
    ) -> list[Message]:
        """Each sender's newest ``kind`` message no older than ``step − max_age`` (with
        ``max_age_ns``: sent at a frame stamped ``stamp_ns − max_age_ns`` or later), by sender;
        expired messages are discarded. Aged by stamp, a message without one is handed over
        once (the checks name it) and discarded. With ``lags``, every message here is shown to
        it first (:meth:`~teamslam.msckf.consensus.messages.MessageLags.seen`: the limits are
        learned from them) and each one discarded as expired is counted there."""
        age = MessageAge(step, max_age, stamp_ns, max_age_ns, lags)
        with self._cond:
            if lags is not None:
                for m in self._messages:
                    lags.seen(m, stamp_ns)
            best: dict[int, Message] = {}
            for m in self._messages:
                if (
                    isinstance(m, kind)
                    and m.sender in senders
                    and not age.expired(m)
                    and (m.sender not in best or m.step > best[m.sender].step)
                ):
                    best[m.sender] = m
            keep = []
            for m in self._messages:
                if age.expired(m):
                    if lags is not None:
                        lags.discarded(m)
                elif not (age.by_stamp and m.stamp_ns is None):
                    keep.append(m)
            self._messages = keep
        return [best[s] for s in sorted(best)]


class MemoryNetwork:
    """Message delivery between the robots of one process, optionally over lossy links.

    Parameters
    ----------
    n
        Number of robots.
    links
        ``links(step)`` → ``(n, n)`` boolean adjacency of the links that work at ``step``
        (default: every link always works). A message over a link that is down is lost.
    """

    def __init__(self, n: int, links: Callable[[int], np.ndarray] | None = None) -> None:
        self.n = n
        self._links = links
        self.mailboxes = [Mailbox() for _ in range(n)]
        self.dropped = 0

    def link_up(self, sender: int, receiver: int, step: int) -> bool:
        """Whether the ``sender → receiver`` link works at ``step``."""
        if not (0 <= sender < self.n and 0 <= receiver < self.n) or sender == receiver:
            return False
        return True if self._links is None else bool(self._links(step)[sender, receiver])

    def endpoint(self, robot: int) -> MemoryTransport:
        """Robot ``robot``'s :class:`Transport`."""
        if not 0 <= robot < self.n:
            raise InputError(f"no robot {robot} in a network of {self.n}")
        return MemoryTransport(self, robot)

    def _deliver(self, message: Message) -> bool:
        if not self.link_up(message.sender, message.receiver, message.step):
            self.dropped += 1
            return False
        self.mailboxes[message.receiver].put(message)
        return True


class LyingNetwork(MemoryNetwork):
    """A :class:`MemoryNetwork` whose robot ``liar`` lies in every marginal it sends: each
    object's mean moved by ``offset`` (metres, world frame), information ``information`` times
    the identity (a covariance that claims millimetres).

    Parameters
    ----------
    n
        Number of robots.
    liar
        The lying robot (``None``: every robot is honest, the network is a
        :class:`MemoryNetwork`).
    offset, information
        The lie: the shift of every object and the claimed information (per coordinate).
    """

    def __init__(
        self,
        n: int,
        liar: int | None,
        offset: tuple[float, float, float] = (20.0, 0.0, 0.0),
        information: float = 1e6,
    ) -> None:
        super().__init__(n)
        self.liar = liar
        self.offset = np.asarray(offset, dtype=float)
        self.information = float(information)

    def _deliver(self, message: Message) -> bool:
        if message.sender == self.liar and isinstance(message, CommonMarginalMessage):
            from dataclasses import replace

            d = message.mean.size
            message = replace(
                message,
                mean=message.mean + np.tile(self.offset, d // 3),
                cov=None,
                info=self.information * np.eye(d),
            )
        return super()._deliver(message)


class MemoryTransport:
    """One robot's endpoint on a :class:`MemoryNetwork` (a :class:`Transport`)."""

    def __init__(self, network: MemoryNetwork, robot: int) -> None:
        self.network = network
        self.robot = robot
        self.messages_sent = 0
        self.bytes_sent = 0

    def send(self, message: Message) -> None:
        """Deliver if the link works at the message's step; otherwise it is lost."""
        self.messages_sent += 1
        self.bytes_sent += message.nbytes()
        self.network._deliver(message)

    def collect(
        self,
        step: int,
        kind: type,
        senders: set[int],
        timeout: float,
        also: set[int] | frozenset[int] = frozenset(),
    ) -> list[Message]:
        """See :meth:`Transport.collect`; senders whose link is down at ``step`` are not awaited."""
        reachable = {s for s in senders if self.network.link_up(s, self.robot, step)}
        box = self.network.mailboxes[self.robot]
        return box.collect(step, kind, set(senders) | set(also), timeout, reachable)

    def newest(
        self,
        kind: type,
        senders: set[int],
        max_age: int,
        step: int,
        stamp_ns: int | None = None,
        max_age_ns: int | None = None,
        lags: MessageLags | None = None,
    ) -> list[Message]:
        """See :meth:`Transport.newest`."""
        box = self.network.mailboxes[self.robot]
        return box.newest(kind, senders, max_age, step, stamp_ns, max_age_ns, lags)

    def reachable(self, step: int, robots: set[int]) -> set[int]:
        """The robots whose link from this one works at ``step``."""
        return {j for j in robots if self.network.link_up(self.robot, j, step)}

    def wait_for_peers(self, count: int, timeout: float) -> int:
        """Every robot of the network is reachable at once."""
        return min(count, self.network.n - 1)

    def statistics(self) -> dict:
        """Messages lost on links that were down (network-wide)."""
        return {"dropped": self.network.dropped}

    def finish(self, timeout: float) -> set[int]:
        """Nothing to wait for: a message is in its receiver's mailbox once sent."""
        return set()

    def close(self) -> None:
        """Nothing to release."""
