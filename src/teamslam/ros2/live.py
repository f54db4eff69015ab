"""Live ROS 2 topics in: a subscriber in ``rmw_zenoh``'s layout, stamp pairing, and decoders.

:class:`Ros2Subscriber` is the mirror of :class:`~teamslam.ros2.rmw_zenoh.Ros2Publisher`: it
subscribes to ``<domain_id>/<topic>/<DDS type name>/*``, takes a sample whose RIHS01 hash is the
one our typestore gives the topic's type, reads rmw_zenoh's attachment (sequence number, source
timestamp, publisher GID), decodes the CDR payload with :func:`teamslam.ros2.messages.typestore`
(the classes a bag reader gives) and hands a :class:`Received` to a callback. A sample it cannot
take (unknown type hash, no attachment, a payload that does not decode) is counted per topic
and named through ``on_error`` in one line; it never raises into Zenoh. Liveliness tokens
announce the node and one subscription per topic, as rmw_zenoh does.

:class:`ApproximateTimeSync` pairs messages of several topics by header stamp within a stated
tolerance; :func:`image_array`, :func:`stereo_rig` and :func:`odometry_pose` turn the messages
a robot receives into an image, a stereo rig and a pose.
"""

from __future__ import annotations

import re
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from teamslam.errors import InputError
from teamslam.ros2 import messages as m
from teamslam.ros2.rmw_zenoh import (
    DEFAULT_QOS,
    liveliness_key,
    open_session,
    parse_attachment,
)

__all__ = [
    "ApproximateTimeSync",
    "Received",
    "Ros2Subscriber",
    "check_topic_name",
    "image_array",
    "odometry_pose",
    "stereo_rig",
]

# an absolute ROS 2 topic name: tokens of letters, digits and underscores, not starting with a
# digit, separated by single slashes (what rmw_zenoh puts in a key expression unchanged)
_TOPIC = re.compile(r"^(/[A-Za-z_][A-Za-z0-9_]*)+$")


def check_topic_name(topic: str) -> str:
    """``topic`` if it is an absolute ROS 2 topic name (``/a/b_1``); else an InputError."""
    if not isinstance(topic, str) or not _TOPIC.match(topic) or "__" in topic:
        raise InputError(
            f"topic {topic!r} is not an absolute ROS 2 topic name like /robot_0/left/image_raw"
        )
    return topic


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


@dataclass(frozen=True)
class Received:
    """One message received on a topic.

    Attributes
    ----------
    topic
        The ROS topic name as published, e.g. ``/robot_0/left/image_raw``.
    msgtype
        The message type, e.g. ``sensor_msgs/msg/Image``.
    stamp_ns
        The message's header stamp (``sec·10⁹ + nanosec``); for a message without a header,
        the attachment's source timestamp.
    message
        The message as :func:`teamslam.ros2.messages.typestore` deserialises it (the classes a
        bag reader gives).
    received_ns
        ``time.monotonic_ns()`` when it arrived.
    sequence_number, source_ns, gid
        rmw_zenoh's attachment: the publisher's sequence number (from 1), its source timestamp
        (nanoseconds) and its 16-byte GID (0, 0 and empty when not received over Zenoh).
    """

    topic: str
    msgtype: str
    stamp_ns: int
    message: object
    received_ns: int
    sequence_number: int = 0
    source_ns: int = 0
    gid: bytes = b""


class Ros2Subscriber:
    """Subscribes to topics in rmw_zenoh's layout (the mirror of ``Ros2Publisher``).

    Parameters
    ----------
    topics
        Topic name → message type (``pkg/msg/Name``); each type must be one the typestore knows.
    callback
        Called with each :class:`Received`, from Zenoh's threads but one call at a time (it
        must not call :meth:`close`; hand long work to a queue). An exception it raises is
        counted in :attr:`errors` and named through ``on_error``.
    node
        The node name in the liveliness tokens.
    domain_id
        ``ROS_DOMAIN_ID``.
    session
        An open Zenoh session to use (it stays open on :meth:`close`); by default one is opened
        with ``config``.
    config
        A ``zenoh.Config`` for the session opened here; by default rmw_zenoh's (peer, router
        ``tcp/localhost:7447``, no multicast scouting).
    on_error
        Called with a one-line text for each sample refused (a type hash not known: once per
        topic and hash) and each payload that does not decode.
    node_id, first_entity_id
        rmw_zenoh's node and entity ids in the tokens (unique in a session; the defaults do not
        meet :class:`~teamslam.ros2.rmw_zenoh.Ros2Publisher`'s node 0 and entities 1–3).

    Attributes
    ----------
    counts
        Messages delivered per topic.
    errors
        Samples refused per topic (unknown type hash, missing or malformed attachment, payload
        that does not decode, callback failure).
    """

    def __init__(
        self,
        topics: Mapping[str, str],
        callback: Callable[[Received], None],
        *,
        node: str = "teamslam_live_input",
        domain_id: int = 0,
        session=None,
        config=None,
        on_error: Callable[[str], None] | None = None,
        node_id: int = 1,
        first_entity_id: int = 100,
    ) -> None:
        if not topics:
            raise InputError("a subscriber needs at least one topic")
        known = set(m.typestore().types)
        self.topics: dict[str, str] = {}
        self._hash: dict[str, str] = {}
        for topic, msgtype in topics.items():
            check_topic_name(topic)
            if msgtype not in known:
                raise InputError(f"{topic}: message type {msgtype!r} is not one teamslam knows")
            self.topics[topic] = msgtype
            self._hash[topic] = m.type_hash(msgtype)
        domain_id = int(domain_id)
        if not 0 <= domain_id <= 232:
            raise InputError(f"domain id must be in 0..232, got {domain_id}")
        self.domain_id = domain_id
        self.node = node
        self.counts: dict[str, int] = dict.fromkeys(self.topics, 0)
        self.errors: dict[str, int] = dict.fromkeys(self.topics, 0)
        self._callback = callback
        self._on_error = on_error
        self._told: set[tuple[str, str]] = set()
        self._lock = threading.Lock()
        self._closed = False
        self._own_session = session is None
        self.session = open_session(config=config) if session is None else session
        self._tokens: list = []
        self._subscribers: list = []
        try:
            self._declare(node_id, first_entity_id)
        except BaseException:
            self.close()
            raise

    def _declare(self, node_id: int, first_entity_id: int) -> None:
        zid = str(self.session.info.zid())
        liveliness = self.session.liveliness()
        domain_id, node = self.domain_id, self.node
        for k, (topic, msgtype) in enumerate(self.topics.items()):
            prefix = f"{domain_id}/{topic.strip('/')}/{m.dds_type_name(msgtype)}/"
            self._subscribers.append(
                self.session.declare_subscriber(
                    prefix + "*", lambda sample, t=topic: self._on_sample(t, sample)
                )
            )
            self._tokens.append(
                liveliness.declare_token(
                    liveliness_key(
                        domain_id,
                        zid,
                        node_id,
                        node,
                        first_entity_id + k,
                        topic,
                        msgtype,
                        DEFAULT_QOS,
                        kind="MS",
                    )
                )
            )
        # the node's token last: a player waiting for subscribers counts a node once its node
        # token arrived, which on one session's ordered declarations is after every subscription
        self._tokens.append(liveliness.declare_token(liveliness_key(domain_id, zid, node_id, node)))

    def _error(self, topic: str, text: str, once: str | None = None) -> None:
        self.errors[topic] += 1
        if once is not None:
            if (topic, once) in self._told:
                return
            self._told.add((topic, once))
        if self._on_error is not None:
            try:
                self._on_error(text)
            except Exception:
                pass

    def _on_sample(self, topic: str, sample) -> None:
        received_ns = time.monotonic_ns()
        msgtype = self.topics[topic]
        type_hash = str(sample.key_expr).rsplit("/", 1)[-1]
        with self._lock:
            if self._closed:
                return
            if type_hash != self._hash[topic]:
                self._error(
                    topic,
                    f"{topic}: refused samples of {msgtype} with type hash {type_hash} "
                    f"(teamslam's is {self._hash[topic]}: another version of the message)",
                    once=type_hash,
                )
                return
            if sample.attachment is None:
                self._error(topic, f"{topic}: a sample without rmw_zenoh's attachment, refused")
                return
            try:
                seq, source_ns, gid = parse_attachment(sample.attachment.to_bytes())
            except InputError as exc:
                self._error(topic, f"{topic}: {exc}, refused")
                return
            try:
                message = m.typestore().deserialize_cdr(sample.payload.to_bytes(), msgtype)
            except Exception as exc:
                self._error(
                    topic,
                    f"{topic}: sample {seq} of publisher {gid.hex()} is not a {msgtype} "
                    f"({type(exc).__name__}: {_one_line(exc)}), refused",
                )
                return
            header = getattr(message, "header", None)
            stamp = m.stamp_ns(header.stamp) if header is not None else source_ns
            item = Received(topic, msgtype, stamp, message, received_ns, seq, source_ns, gid)
            self.counts[topic] += 1
            try:
                self._callback(item)
            except Exception as exc:
                self._error(
                    topic,
                    f"{topic}: the callback failed on stamp {stamp} ns: "
                    f"{type(exc).__name__}: {_one_line(exc)}",
                )

    def close(self) -> None:
        """Withdraw the tokens and subscriptions; close the session if it was opened here."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        for sub in self._subscribers:
            sub.undeclare()
        for token in self._tokens:
            token.undeclare()
        if self._own_session:
            self.session.close()

    def __enter__(self) -> Ros2Subscriber:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class ApproximateTimeSync:
    """Sets of one message per topic whose header stamps lie within ``tolerance_ns``.

    The rule (a simpler one than ``message_filters``' ApproximateTime, exact for sensors
    triggered together): each topic keeps a queue of its messages in stamp order, and stamps
    increase per topic (a message not after the last of its topic — a stamp that went back, or
    a repeat — is dropped). The oldest message of a queue is dropped as soon as it can have no
    partner: another topic's earliest stamp still possible (its oldest queued, or just after
    its last received) is more than ``tolerance_ns`` later. When every queue then holds a
    message, their oldest form a set (their stamps span at most ``tolerance_ns``), emitted at
    once, without waiting for a closer partner. A queue longer than ``queue_size`` drops its
    oldest. With a tolerance below half the period of the slowest topic, every set is the one a
    sensor triggered together.

    Parameters
    ----------
    topics
        The topics of a set.
    tolerance_ns
        Largest spread of stamps within a set, nanoseconds (``0``: exact stamps).
    queue_size
        Messages kept per topic while waiting for partners.

    Attributes
    ----------
    dropped
        Messages discarded without a partner, per topic.
    """

    def __init__(self, topics: Sequence[str], tolerance_ns: int, queue_size: int = 10) -> None:
        topics = list(topics)
        if not topics or len(set(topics)) != len(topics):
            raise InputError(f"a stamp synchroniser needs distinct topics, got {topics}")
        if isinstance(tolerance_ns, bool) or int(tolerance_ns) != tolerance_ns or tolerance_ns < 0:
            raise InputError(f"sync tolerance must be integer nanoseconds ≥ 0, got {tolerance_ns}")
        if isinstance(queue_size, bool) or int(queue_size) != queue_size or queue_size < 1:
            raise InputError(f"sync queue size must be a positive integer, got {queue_size}")
        self.topics = topics
        self.tolerance_ns = int(tolerance_ns)
        self.queue_size = int(queue_size)
        self._queues: dict[str, deque[Received]] = {t: deque() for t in topics}
        self._last: dict[str, int | None] = dict.fromkeys(topics)
        self.dropped: dict[str, int] = dict.fromkeys(topics, 0)

    def add(self, item: Received) -> list[dict[str, Received]]:
        """Add one message; the sets it completes, oldest first (usually none or one)."""
        topic = item.topic
        if topic not in self._queues:
            raise InputError(f"{topic} is not a topic of this synchroniser ({self.topics})")
        last = self._last[topic]
        if last is not None and item.stamp_ns <= last:
            self.dropped[topic] += 1
            return []
        self._last[topic] = item.stamp_ns
        queue = self._queues[topic]
        queue.append(item)
        if len(queue) > self.queue_size:
            queue.popleft()
            self.dropped[topic] += 1
        sets = []
        while True:
            self._drop_unpairable()
            if not all(self._queues.values()):
                return sets
            sets.append({t: self._queues[t].popleft() for t in self.topics})

    def _drop_unpairable(self) -> None:
        """Drop every oldest message that no later message can pair: some other topic's
        earliest stamp still to come (its oldest queued, or just after its last) is more than
        the tolerance later."""
        changed = True
        while changed:
            changed = False
            earliest = {
                t: q[0].stamp_ns if q else (None if self._last[t] is None else self._last[t] + 1)
                for t, q in self._queues.items()
            }
            latest = max((s for s in earliest.values() if s is not None), default=None)
            for t, q in self._queues.items():
                if q and latest is not None and latest - q[0].stamp_ns > self.tolerance_ns:
                    q.popleft()
                    self.dropped[t] += 1
                    changed = True

    def pending(self) -> dict[str, int]:
        """Messages waiting for partners, per topic."""
        return {t: len(q) for t, q in self._queues.items()}


# ------------------------------------------------------------------------------ decoders
def image_array(
    msg: object, topic: str = "image", size: tuple[int, int] | None = None
) -> np.ndarray:
    """The grey ``uint8`` image of a ``sensor_msgs/msg/Image`` or ``CompressedImage``.

    Parameters
    ----------
    msg
        The message, or a :class:`Received` holding one (its topic then names it).
    topic
        The topic, for errors.
    size
        ``(W, H)`` the image must have (the rig's), or ``None``.

    Raises
    ------
    InputError
        Naming the topic and the stamp: an encoding not one of ``mono8``, ``8UC1``, ``mono16``,
        ``bgr8``, ``rgb8``, ``bgra8``, ``rgba8``; a data size that does not match
        ``height × step``; a compressed image OpenCV cannot decode; a size not ``size``.
    """
    from teamslam.ros2.image_bags import _decode

    if isinstance(msg, Received):
        topic, msg = msg.topic, msg.message
    msgtype = getattr(msg, "__msgtype__", None)
    if msgtype not in ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage"):
        raise InputError(f"{topic}: a {msgtype} is not an image")
    stamp = m.stamp_ns(msg.header.stamp)
    img = _decode(msg, topic, stamp)
    if size is not None:
        w, h = size
        if img.shape != (h, w):
            raise InputError(
                f"{topic} at stamp {stamp} ns: image is {img.shape[1]}×{img.shape[0]}, "
                f"the camera says {w}×{h}"
            )
    return img


def stereo_rig(left_info: object, right_info: object, T_cam_body: np.ndarray | None = None):
    """The :class:`~teamslam.frontend.camera.StereoRig` of a rectified pair's two
    ``sensor_msgs/msg/CameraInfo`` (the inverse of what ``images_to_bag`` writes: ``K``, ``D``,
    ``R`` per camera and ``−fx·b`` in the right ``P[0, 3]``); :class:`Received` items accepted.
    A malformed pair raises InputError naming what was wrong."""
    from teamslam.frontend.camera import rig_from_camera_info

    left_info = left_info.message if isinstance(left_info, Received) else left_info
    right_info = right_info.message if isinstance(right_info, Received) else right_info
    for side, info in (("left", left_info), ("right", right_info)):
        if getattr(info, "__msgtype__", None) != "sensor_msgs/msg/CameraInfo":
            raise InputError(f"{side} camera info: a {getattr(info, '__msgtype__', info)!r}")
    return rig_from_camera_info(left_info, right_info, T_cam_body)


def odometry_pose(msg: object) -> tuple[np.ndarray, np.ndarray | None]:
    """``(T_world_body 4×4, covariance 6×6 or None)`` of a ``nav_msgs/msg/Odometry``.

    ``T_world_body`` is the pose of ``child_frame_id`` in ``header.frame_id`` (the odometry
    frame); the covariance is ROS's, over ``(x, y, z, rot x, rot y, rot z)``, and ``None`` when
    the message says it is unknown (all zeros, or ``−1`` first, as REP 103 drivers write). A
    quaternion that is not unit length (±1e-3) or a non-finite value raises InputError.
    """
    if isinstance(msg, Received):
        msg = msg.message
    if getattr(msg, "__msgtype__", None) != "nav_msgs/msg/Odometry":
        raise InputError(f"not a nav_msgs/msg/Odometry: {getattr(msg, '__msgtype__', msg)!r}")
    pose = msg.pose.pose
    q = np.array([pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w])
    p = np.array([pose.position.x, pose.position.y, pose.position.z])
    stamp = m.stamp_ns(msg.header.stamp)
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(p))):
        raise InputError(f"odometry at stamp {stamp} ns: a pose value is not finite")
    if abs(np.linalg.norm(q) - 1.0) > 1e-3:
        raise InputError(
            f"odometry at stamp {stamp} ns: quaternion of norm {np.linalg.norm(q):.6g}, not 1"
        )
    T = m.pose_matrix(pose)
    cov = np.asarray(msg.pose.covariance, dtype=float).reshape(6, 6)
    if not np.any(cov) or cov[0, 0] == -1.0:
        return T, None
    if not np.all(np.isfinite(cov)):
        raise InputError(f"odometry at stamp {stamp} ns: covariance is not finite")
    return T, cov
