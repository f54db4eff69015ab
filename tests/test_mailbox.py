"""Lock-step waiting (:meth:`~teamslam.msckf.consensus.transport.Mailbox.collect`): the
timeout counts only the time the robot itself was listening, so a robot that was held up
itself (suspended, starved of the processor) does not take a neighbour that speaks right after
for lost; a neighbour silent for good is still given up. Without a network, in one thread."""

from __future__ import annotations

import time

import numpy as np

from teamslam.msckf.consensus.messages import CommonMarginalMessage, MapIdsMessage
from teamslam.msckf.consensus.transport import Mailbox


def ids_message(sender: int, step: int) -> MapIdsMessage:
    return MapIdsMessage(sender, 0, step, np.array([1, 4, 9]), None, None, None)


class HeldClock:
    """The monotonic clock of a robot held up for ``held_s`` during its first wait; its
    neighbour, held up too, speaks on the robot's ``speaks_at``-th look at the clock."""

    def __init__(self, box: Mailbox, held_s: float, speaks_at: int) -> None:
        self.box, self.held_s, self.speaks_at = box, held_s, speaks_at
        self.calls = 0

    def __call__(self) -> float:
        self.calls += 1
        if self.calls == self.speaks_at:
            self.box.put(ids_message(1, 7))
        return time.monotonic() + (self.held_s if self.calls >= 3 else 0.0)


def test_a_robot_held_up_while_waiting_still_hears_the_neighbour_that_speaks_after_it():
    box = Mailbox()
    # looks: 1 sets the deadline, 2 before the first wait, 3 after it (60 s later: held up),
    # 4 before the second wait, 5 after it: the neighbour has spoken meanwhile
    box._clock = clock = HeldClock(box, held_s=60.0, speaks_at=5)
    got = box.collect(7, MapIdsMessage, {1}, 1.0, None)
    assert [(m.sender, m.step) for m in got] == [(1, 7)]
    assert clock.calls >= 5


def test_a_neighbour_silent_for_good_is_given_up_after_the_timeout():
    box = Mailbox()
    box.put(ids_message(1, 6))  # an older step's leftover: discarded, not an answer
    other_kind = CommonMarginalMessage(1, 0, 7, np.array([1]), np.zeros((1, 3)), np.eye(3)[None])
    box.put(other_kind)
    start = time.monotonic()
    assert box.collect(7, MapIdsMessage, {1}, 0.3, None) == []
    assert time.monotonic() - start >= 0.3
