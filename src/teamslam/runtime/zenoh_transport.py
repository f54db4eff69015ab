"""Consensus messages over Zenoh, one process per robot, peer to peer.

Each agent opens a Zenoh session in peer mode that listens on its own endpoint and connects to
its neighbours' endpoints, with multicast scouting off (no router, closed networks work). A
message from ``i`` to ``j`` at step ``t`` is published on the key
``teamslam/<team>/to/<j>/from/<i>/step/<t>/<kind>`` in teamslam's wire format; each agent
subscribes to ``teamslam/<team>/to/<itself>/**``. Received bytes are decoded and validated in
the subscriber callback: anything malformed, from another team or from an unknown robot is
dropped and counted, never handed to the filter.

Optional injected loss (each send dropped with a probability) and delay (sleep before each
send) make lossy-radio experiments reproducible.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections import defaultdict

import numpy as np

from teamslam.msckf.messages import MapIdsMessage, Message
from teamslam.msckf.transport import Mailbox
from teamslam.runtime.team_file import TeamFile
from teamslam.runtime.wire import WireError, decode, encode, team_id

__all__ = ["ZenohTransport"]

log = logging.getLogger(__name__)


def _kind(message: Message) -> str:
    return "ids" if isinstance(message, MapIdsMessage) else "marginal"


class ZenohTransport:
    """A :class:`~teamslam.msckf.transport.Transport` over a Zenoh peer session.

    Parameters
    ----------
    team
        The team file.
    robot
        This robot's id.
    seed
        Seed of the injected message loss.
    """

    def __init__(self, team: TeamFile, robot: int, seed: int = 0) -> None:
        import zenoh

        self.team = team
        self.robot = robot
        self.team_id = team_id(team.team)
        self.rng = np.random.default_rng(seed + 7919 * robot)
        self.messages_sent = 0
        self.bytes_sent = 0
        self.injected_drops = 0
        self.rejected: dict[str, int] = defaultdict(int)
        self.latencies: list[float] = []
        self._mailbox = Mailbox()
        self._cond = threading.Condition()
        me = team.robots[robot]
        config = zenoh.Config()
        config.insert_json5("mode", json.dumps("peer"))
        config.insert_json5("listen/endpoints", json.dumps([me.listen]))
        config.insert_json5(
            "connect/endpoints", json.dumps([team.robots[j].listen for j in me.neighbours])
        )
        config.insert_json5("scouting/multicast/enabled", "false")
        self.session = zenoh.open(config)
        self._subscriber = self.session.declare_subscriber(
            f"teamslam/{team.team}/to/{robot}/**", self._on_sample
        )
        # declared after the subscriber: a neighbour that sees this token also has our
        # subscription, so its first messages are not published into the void
        self._token = self.session.liveliness().declare_token(f"teamslam/{team.team}/alive/{robot}")

    def _on_sample(self, sample) -> None:
        data = bytes(sample.payload.to_bytes())
        try:
            message = decode(data, self.team_id, self.team.n)
        except WireError as exc:
            reason = str(exc).split(" (")[0]
            with self._cond:
                first = reason not in self.rejected
                self.rejected[reason] += 1
            if first:
                log.warning(
                    "robot %d: dropped a message: %s (further ones are counted)", self.robot, exc
                )
            return
        if message.receiver != self.robot:
            with self._cond:
                self.rejected["addressed to another robot"] += 1
            return
        attachment = sample.attachment
        sent = float(attachment.to_string()) if attachment is not None else None
        with self._cond:
            if sent is not None:
                self.latencies.append(time.time() - sent)
        self._mailbox.put(message)

    def alive_neighbours(self) -> set[int]:
        """Neighbours whose liveliness token is visible now."""
        replies = self.session.liveliness().get(f"teamslam/{self.team.team}/alive/*", timeout=1.0)
        alive = set()
        for reply in replies:
            if reply.ok is not None:
                try:
                    alive.add(int(str(reply.ok.key_expr).rsplit("/", 1)[1]))
                except ValueError:
                    continue
        return alive & set(self.team.robots[self.robot].neighbours)

    def wait_for_peers(self, count: int, timeout: float) -> int:
        """Block until ``count`` neighbours are alive (or ``timeout``); returns how many are."""
        deadline = time.monotonic() + timeout
        while True:
            alive = len(self.alive_neighbours())
            if alive >= count or time.monotonic() >= deadline:
                return alive
            time.sleep(0.02)

    def send(self, message: Message) -> None:
        """Publish a message to its receiver (subject to injected loss and delay)."""
        payload = encode(message, self.team_id)
        self.messages_sent += 1
        self.bytes_sent += len(payload)
        if self.team.message_loss > 0 and self.rng.random() < self.team.message_loss:
            self.injected_drops += 1
            return
        if self.team.message_delay_ms > 0:
            time.sleep(self.team.message_delay_ms / 1000.0)
        key = (
            f"teamslam/{self.team.team}/to/{message.receiver}/from/{message.sender}"
            f"/step/{message.step}/{_kind(message)}"
        )
        self.session.put(key, payload, attachment=repr(time.time()))

    def collect(self, step: int, kind: type, senders: set[int], timeout: float) -> list[Message]:
        """See :meth:`teamslam.msckf.transport.Transport.collect`."""
        return self._mailbox.collect(step, kind, senders, timeout, None)

    def newest(self, kind: type, senders: set[int], max_age: int, step: int) -> list[Message]:
        """See :meth:`teamslam.msckf.transport.Transport.newest`."""
        return self._mailbox.newest(kind, senders, max_age, step)

    def statistics(self) -> dict:
        """Injected drops, messages rejected before decoding, and per-message latencies."""
        with self._cond:
            return {
                "injected_drops": self.injected_drops,
                "rejected_wire": int(sum(self.rejected.values())),
                "rejected_reasons": dict(self.rejected),
                "latencies": list(self.latencies),
            }

    def close(self) -> None:
        """Close the Zenoh session."""
        try:
            self._token.undeclare()
            self._subscriber.undeclare()
        finally:
            self.session.close()
