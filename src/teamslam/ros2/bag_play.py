"""``teamslam bag play``: a ROS 2 bag's messages published live in ``rmw_zenoh``'s layout.

Messages are read in log-time order (rosbag2 sqlite3 or MCAP, through ``rosbags``' AnyReader)
and each recorded CDR payload is forwarded as is — never re-serialised — on
``<domain_id>/<topic>/<DDS type name>/<RIHS01 hash>`` with rmw_zenoh's attachment (a sequence
number per publisher from 1, the recorded log time as source timestamp, the publisher's GID).
A message logged at ``t`` is published at ``start + (t − t0) / rate`` on the monotonic clock
(:func:`publish_time`); rate 0 publishes as fast as possible, still in order. Liveliness tokens
announce the player's node and one publisher per topic, so ``ros2 topic list`` sees them.
Publication is reliable and blocks rather than drops when a subscriber is slow.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from teamslam._optional import require
from teamslam.errors import InputError
from teamslam.ros2 import messages as m
from teamslam.ros2.rmw_zenoh import (
    WHAT,
    attachment,
    liveliness_key,
    open_session,
    parse_liveliness_key,
    publisher_gid,
    topic_key,
)

__all__ = ["PlayResult", "bag_topics", "play_bag", "publish_time"]

NODE = "teamslam_bag_player"


def publish_time(log_ns: int, t0_ns: int, start_ns: int, rate: float) -> int:
    """When a message logged at ``log_ns`` is published: ``start + (log − t0) / rate``
    nanoseconds on the monotonic clock, rounded to the nanosecond; with ``rate`` 0, ``start``
    (as fast as possible)."""
    if rate < 0 or rate != rate:
        raise InputError(f"play rate must be a number ≥ 0, got {rate}")
    if rate == 0:
        return int(start_ns)
    offset = int(log_ns) - int(t0_ns)
    if rate == 1:
        return int(start_ns) + offset
    return int(start_ns) + round(offset / rate)


@dataclass
class PlayResult:
    """What :func:`play_bag` published.

    Attributes
    ----------
    counts
        Messages published per topic (over every pass).
    passes
        Complete passes over the bag.
    stopped
        Whether it was stopped (Ctrl-C or the ``stop`` event) before the end.
    gids
        Each topic's publisher GID.
    keys
        Each topic's key expression.
    """

    counts: dict[str, int] = field(default_factory=dict)
    passes: int = 0
    stopped: bool = False
    gids: dict[str, bytes] = field(default_factory=dict)
    keys: dict[str, str] = field(default_factory=dict)


def _open(bag: Path):
    AnyReader = m.rosbags("highlevel", "playing a ROS 2 bag").AnyReader
    if not bag.exists():
        raise InputError(f"{bag}: no such bag")
    try:
        reader = AnyReader([bag], default_typestore=m.typestore())
        reader.open()
    except Exception as exc:  # rosbags raises several kinds on a malformed bag
        raise InputError(f"{bag}: cannot read the bag ({_one_line(exc)})") from None
    return reader


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def _hash(reader, msgtype: str) -> str | None:
    """The RIHS01 hash of ``msgtype`` from the bag's own definition, else teamslam's."""
    for store in (reader.typestore, m.typestore()):
        if msgtype in store.types:
            return store.hash_rihs01(msgtype)
    return None


def bag_topics(bag: str | Path) -> dict[str, tuple[str, int]]:
    """``{topic: (msgtype, messages)}`` of a bag; a malformed bag raises InputError."""
    reader = _open(Path(bag))
    try:
        out: dict[str, tuple[str, int]] = {}
        for c in reader.connections:
            msgtype, count = out.get(c.topic, (c.msgtype, 0))
            out[c.topic] = (msgtype, count + c.msgcount)
        return out
    finally:
        reader.close()


def _messages(reader, connections, bag: Path) -> Iterator[tuple[str, int, bytes]]:
    """``(topic, log time ns, raw CDR)`` in log-time order; a read failure → InputError."""
    it = iter(reader.messages(connections=connections))
    while True:
        try:
            conn, log_ns, raw = next(it)
        except StopIteration:
            return
        except Exception as exc:  # a corrupt chunk or record, as rosbags reports it
            raise InputError(f"{bag}: cannot read the bag ({_one_line(exc)})") from None
        yield conn.topic, int(log_ns), bytes(raw)


class _Subscribers:
    """Subscriptions announced (``MS`` tokens) on the played topics, by node; a node counts once
    its node token (``NN``) is also there. rmw_zenoh declares a node before its entities; a live
    teamslam robot declares its node token after its subscriptions, so that, one session's
    declarations arriving in order, a robot counted has every one of its subscriptions routed."""

    def __init__(self, session, domain_id: int, topics: set[str]) -> None:
        zenoh = require("zenoh", "network", WHAT)
        self._put = zenoh.SampleKind.PUT
        self.topics = topics
        self.tokens: set[str] = set()
        self.node_tokens: set[tuple[str, str]] = set()
        self.lock = threading.Lock()
        self.listener = session.liveliness().declare_subscriber(
            f"@ros2_lv/{domain_id}/**", self._on_token, history=True
        )

    def _on_token(self, sample) -> None:
        key = str(sample.key_expr)
        parts = key.split("/")
        if len(parts) == 9 and parts[0] == "@ros2_lv" and parts[5] == "NN":
            with self.lock:
                if sample.kind == self._put:
                    self.node_tokens.add((parts[2], parts[3]))
                else:
                    self.node_tokens.discard((parts[2], parts[3]))
            return
        fields = parse_liveliness_key(key)
        if fields is None or fields["kind"] != "MS" or fields["topic"] not in self.topics:
            return
        with self.lock:
            if sample.kind == self._put:
                self.tokens.add(key)
            else:
                self.tokens.discard(key)

    def nodes(self) -> int:
        with self.lock:
            fields = [parse_liveliness_key(k) for k in self.tokens]
            return len({(f["zid"], f["node_id"]) for f in fields} & self.node_tokens)

    def topics_subscribed(self) -> set[str]:
        with self.lock:
            return {parse_liveliness_key(k)["topic"] for k in self.tokens}


def play_bag(
    bag: str | Path,
    *,
    rate: float = 1.0,
    topics: Sequence[str] | None = None,
    loop: bool = False,
    domain_id: int = 0,
    start_delay: float = 0.0,
    wait_subscribers: int = 0,
    wait_timeout: float | None = None,
    connect: list[str] | None = None,
    listen: list[str] | None = None,
    config=None,
    stop: threading.Event | None = None,
    on_start: Callable[[PlayResult], None] | None = None,
) -> PlayResult:
    """Publish a bag's messages live on rmw_zenoh's layout with their recorded timing.

    Parameters
    ----------
    bag
        A rosbag2 directory, or an ``.mcap`` / ``.db3`` file.
    rate
        Speed factor of the recorded timing (2: twice as fast); 0: as fast as possible.
    topics
        Only these topics (default: all); a topic the bag does not have is an error.
    loop
        Play again from the start after the end, until stopped.
    domain_id
        ``ROS_DOMAIN_ID``.
    start_delay
        Seconds to wait before the first message (after the subscribers, if waited for).
    wait_subscribers
        Before the first message, wait until this many nodes have announced a subscription to
        one of the played topics (liveliness tokens) and each such topic's publisher is matched.
    wait_timeout
        Give up waiting for subscribers after this many seconds (InputError); ``None``: wait
        until stopped.
    connect, listen, config
        The Zenoh session (:func:`~teamslam.ros2.rmw_zenoh.open_session`).
    stop
        Set it to stop playing (as Ctrl-C does).
    on_start
        Called once the publishers are declared, before any wait, with the (empty) result:
        its ``keys`` and ``gids`` are set.

    Returns
    -------
    PlayResult
        Messages per topic, passes, whether stopped, and the publishers' GIDs and keys.
    """
    zenoh = require("zenoh", "network", WHAT)
    bag = Path(bag)
    if rate < 0 or rate != rate:
        raise InputError(f"--rate must be a number ≥ 0, got {rate}")
    if start_delay < 0:
        raise InputError(f"--start-delay must be ≥ 0 seconds, got {start_delay}")
    if wait_subscribers < 0:
        raise InputError(f"--wait-subscribers must be ≥ 0, got {wait_subscribers}")
    if not 0 <= int(domain_id) <= 232:
        raise InputError(f"--domain-id must be in 0..232, got {domain_id}")
    reader = _open(bag)
    stop = stop or threading.Event()
    result = PlayResult()
    session = None
    tokens = []
    try:
        available: dict[str, str] = {}
        for c in reader.connections:
            if available.setdefault(c.topic, c.msgtype) != c.msgtype:
                raise InputError(f"{bag}: topic {c.topic} holds two types")
        wanted = list(available) if topics is None else list(dict.fromkeys(topics))
        missing = [t for t in wanted if t not in available]
        if missing:
            raise InputError(
                f"{bag}: no topic {', '.join(missing)} "
                f"(the bag has {', '.join(sorted(available)) or 'no topics'})"
            )
        if not wanted:
            raise InputError(f"{bag}: no messages to play")
        hashes = {}
        for topic in wanted:
            hashes[topic] = _hash(reader, available[topic])
            if hashes[topic] is None:
                raise InputError(
                    f"{bag}: topic {topic}: type {available[topic]} has no definition in the "
                    "bag and is not one teamslam knows"
                )
        connections = [c for c in reader.connections if c.topic in wanted]
        session = open_session(connect, listen, config)
        zid = str(session.info.zid())
        tokens.append(session.liveliness().declare_token(liveliness_key(domain_id, zid, 0, NODE)))
        publishers = {}
        for entity_id, topic in enumerate(wanted, start=1):
            msgtype, type_hash = available[topic], hashes[topic]
            token_key = liveliness_key(
                domain_id, zid, 0, NODE, entity_id, topic, msgtype, type_hash=type_hash
            )
            key = topic_key(domain_id, topic, msgtype, type_hash)
            publishers[topic] = [
                session.declare_publisher(
                    key,
                    reliability=zenoh.Reliability.RELIABLE,
                    congestion_control=zenoh.CongestionControl.BLOCK,
                ),
                publisher_gid(token_key),
                1,
            ]
            tokens.append(session.liveliness().declare_token(token_key))
            result.keys[topic] = key
            result.gids[topic] = publishers[topic][1]
            result.counts[topic] = 0
        if on_start is not None:
            on_start(result)
        if wait_subscribers:
            _wait_for_subscribers(
                session, domain_id, publishers, wait_subscribers, wait_timeout, stop
            )
        if start_delay and stop.wait(start_delay):
            result.stopped = True
            return result
        while not stop.is_set():
            start = time.monotonic_ns()
            t0 = None
            for topic, log_ns, raw in _messages(reader, connections, bag):
                t0 = log_ns if t0 is None else t0
                delay = publish_time(log_ns, t0, start, rate) - time.monotonic_ns()
                if (delay > 0 and stop.wait(delay / 1e9)) or stop.is_set():
                    break
                entry = publishers[topic]
                entry[0].put(raw, attachment=attachment(entry[2], log_ns, entry[1]))
                entry[2] += 1
                result.counts[topic] += 1
            else:
                result.passes += 1
                if loop and t0 is not None:
                    continue
                break
        result.stopped = stop.is_set()
    except KeyboardInterrupt:
        result.stopped = True
    finally:
        for token in tokens:
            token.undeclare()
        if session is not None:
            session.close()
        reader.close()
    return result


def _wait_for_subscribers(
    session,
    domain_id: int,
    publishers: dict,
    n: int,
    timeout: float | None,
    stop: threading.Event,
) -> None:
    seen = _Subscribers(session, domain_id, set(publishers))
    deadline = None if timeout is None else time.monotonic() + timeout
    try:
        while not stop.is_set():
            if seen.nodes() >= n and all(
                publishers[t][0].matching_status.matching for t in seen.topics_subscribed()
            ):
                return
            if deadline is not None and time.monotonic() > deadline:
                raise InputError(
                    f"waited {timeout:g} s for {n} subscribing node(s) on the bag's topics, "
                    f"saw {seen.nodes()}"
                )
            stop.wait(0.02)
    finally:
        seen.listener.undeclare()
