"""Consensus messages over Zenoh, one process per robot, peer to peer.

Each agent's session listens on its own endpoint and connects to its neighbours' (peer mode,
multicast scouting off). A message from ``i`` to ``j`` at step ``t`` is published in the wire
format on ``teamslam/<team>/to/<j>/from/<i>/step/<t>/<kind>``; received bytes are decoded and
validated in the subscriber callback, and anything malformed, from another team, from an
unknown robot or whose sender differs from the key's is dropped and counted. Lock-step puts
wait for queue space (congestion control *block*: a step needs every message), asynchronous
ones keep *drop*. Optional injected loss and delay make lossy-radio experiments reproducible.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections import defaultdict

import numpy as np

from teamslam._optional import require
from teamslam.msckf.consensus.messages import MapIdsMessage, Message, MessageLags
from teamslam.msckf.consensus.transport import Mailbox
from teamslam.runtime.team_file import TeamFile
from teamslam.runtime.wire import WireError, decode, encode, team_id

__all__ = ["ZenohTransport"]

log = logging.getLogger(__name__)


def _kind(message: Message) -> str:
    return "ids" if isinstance(message, MapIdsMessage) else "marginal"


def _key_sender(key_expr) -> int | None:
    """The ``<i>`` of ``teamslam/<team>/to/<j>/from/<i>/...``; None if the key has no such part."""
    parts = str(key_expr).split("/")
    try:
        return int(parts[5]) if parts[4] == "from" else None
    except (IndexError, ValueError):
        return None


class ZenohTransport:
    """A :class:`~teamslam.msckf.consensus.transport.Transport` over a Zenoh peer session.

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
        zenoh = require("zenoh", "network", "a robot process (the Zenoh transport)")

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
        self.newest_step: dict[int, int] = {}  # per neighbour, the latest step it has spoken in
        self.stale_skipped = 0
        self._cond = threading.Condition()
        self._congestion_control = (
            zenoh.CongestionControl.BLOCK
            if team.sync == "lockstep"
            else zenoh.CongestionControl.DROP
        )
        me = team.robots[robot]
        config = zenoh.Config()
        config.insert_json5("mode", json.dumps("peer"))
        config.insert_json5("listen/endpoints", json.dumps([me.listen]))
        config.insert_json5(
            "connect/endpoints", json.dumps([team.robots[j].listen for j in me.neighbours])
        )
        config.insert_json5("scouting/multicast/enabled", "false")
        config.insert_json5("transport/shared_memory/enabled", json.dumps(team.shared_memory))
        if team.security is not None:
            from teamslam.runtime.security import apply_settings, zenoh_security_settings

            members = {r.id: r.name for r in team.robots}
            apply_settings(
                config, zenoh_security_settings(team.security, robot, team.team, members)
            )
        self.session = zenoh.open(config)
        self._subscriber = self.session.declare_subscriber(
            f"teamslam/{team.team}/to/{robot}/**", self._on_sample
        )
        # declared after the subscriber: a neighbour that sees this token also has our
        # subscription, so its first messages are not published into the void
        self._token = self.session.liveliness().declare_token(f"teamslam/{team.team}/alive/{robot}")
        self._done_token = None

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
        if _key_sender(sample.key_expr) != message.sender:
            with self._cond:
                self.rejected["sender differs from the key's"] += 1
            return
        attachment = sample.attachment
        sent = float(attachment.to_string()) if attachment is not None else None
        with self._cond:
            if message.step > self.newest_step.get(message.sender, -1):
                self.newest_step[message.sender] = message.step
            if sent is not None:
                self.latencies.append(time.time() - sent)
        self._mailbox.put(message)

    def alive_neighbours(self) -> set[int]:
        """Neighbours whose liveliness token is visible now."""
        return self._tokens("alive")

    def _tokens(self, kind: str) -> set[int]:
        """Neighbours whose ``kind`` liveliness token (``alive``, ``done``) is visible now."""
        replies = self.session.liveliness().get(f"teamslam/{self.team.team}/{kind}/*", timeout=1.0)
        seen = set()
        for reply in replies:
            if reply.ok is not None:
                try:
                    seen.add(int(str(reply.ok.key_expr).rsplit("/", 1)[1]))
                except ValueError:
                    continue
        return seen & set(self.team.robots[self.robot].neighbours)

    def finish(self, timeout: float) -> set[int]:
        """Say this robot is done, then wait until every neighbour is done or gone (or
        ``timeout``); returns the neighbours neither done nor gone at the end.

        Closing the session right after the last step can drop our last messages while they
        are still queued for a slow link, and a neighbour behind us then waits for them in
        vain. A neighbour is done only after its last step, which needed our last messages:
        once it is done (or gone), closing loses nothing it still needs."""
        self._done_token = self.session.liveliness().declare_token(
            f"teamslam/{self.team.team}/done/{self.robot}"
        )
        deadline = time.monotonic() + timeout
        while True:
            waiting = self.alive_neighbours() - self._tokens("done")
            if not waiting or time.monotonic() >= deadline:
                return waiting
            time.sleep(0.02)

    def reachable(self, step: int, robots: set[int]) -> set[int]:
        """Every robot asked for: whether a message arrives is known only afterwards."""
        return set(robots)

    def wait_for_peers(self, count: int, timeout: float) -> int:
        """Block until ``count`` neighbours are alive (or ``timeout``); returns how many are.

        Each neighbour still missing at the deadline is named in a warning (with the names of
        the authenticated links the session does have, on a secured team): a refused TLS
        handshake or access-control denial is otherwise silent in Zenoh.
        """
        deadline = time.monotonic() + timeout
        while True:
            alive = self.alive_neighbours()
            if len(alive) >= count or time.monotonic() >= deadline:
                break
            time.sleep(0.02)
        missing = sorted(set(self.team.robots[self.robot].neighbours) - alive)
        if missing and len(alive) < count:
            for line in self.missing_links_report(missing, timeout):
                log.warning("%s", line)
        return len(alive)

    def missing_links_report(self, missing: list[int], waited: float) -> list[str]:
        """One line per neighbour in ``missing``: no (authenticated) link after ``waited`` s."""
        team = self.team
        if team.security is None:
            return [
                f"robot {self.robot}: no link to neighbour robot {j} ({team.robots[j].listen}) "
                f"after {waited:g} s: not running or unreachable"
                for j in missing
            ]
        from teamslam.runtime.security import authenticated_peers

        seen = sorted(set(authenticated_peers(self.session).values()))
        members = {r.name for r in team.robots}
        strangers = [n for n in seen if n not in members]
        note = f"; authenticated links: {', '.join(seen) if seen else 'none'}"
        if strangers:
            note += f" (not members, denied: {', '.join(strangers)})"
        return [
            f"robot {self.robot}: no authenticated link to neighbour robot {j} "
            f"('{team.robots[j].name}' at {team.robots[j].listen}) after {waited:g} s: not "
            "running, unreachable, or the TLS handshake was refused (certificate not signed by "
            f"this team's CA, or not naming that host){note}"
            for j in missing
        ]

    def send(self, message: Message) -> None:
        """Publish a message to its receiver (subject to injected loss and delay).

        Lock-step: a message for a step its receiver has already left (it spoke in a later
        step: links deliver in order) is not sent — it would be discarded there — and is only
        counted in ``stale_skipped``; a robot that resumed behind its team catches up without
        talking. (Asynchronous robots use messages up to ``max_age_steps`` old: all are sent.)
        """
        with self._cond:
            stale = (
                self.team.sync == "lockstep"
                and self.newest_step.get(message.receiver, -1) > message.step
            )
        if stale:
            self.stale_skipped += 1
            return
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
        self.session.put(
            key,
            payload,
            attachment=repr(time.time()),
            congestion_control=self._congestion_control,
        )

    def collect(
        self,
        step: int,
        kind: type,
        senders: set[int],
        timeout: float,
        also: set[int] | frozenset[int] = frozenset(),
    ) -> list[Message]:
        """See :meth:`teamslam.msckf.consensus.transport.Transport.collect`.

        A sender from which a message of a later step has already arrived is not waited for:
        links deliver in order, so it has moved on (a robot that resumed behind its team
        catches up without waiting). Messages of ``step`` from ``also`` (neighbours reported
        lost) are taken when they are there; one of them is waited for again once it has
        spoken in the previous step or later — it is back, in phase with this robot.
        """
        with self._cond:
            back = {j for j in also if self.newest_step.get(j, -1) >= step - 1}
        return self._mailbox.collect(
            step, kind, set(senders) | set(also), timeout, set(senders) | back
        )

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
        """See :meth:`teamslam.msckf.consensus.transport.Transport.newest`."""
        return self._mailbox.newest(kind, senders, max_age, step, stamp_ns, max_age_ns, lags)

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
            if self._done_token is not None:
                self._done_token.undeclare()
            self._token.undeclare()
            self._subscriber.undeclare()
        finally:
            self.session.close()
