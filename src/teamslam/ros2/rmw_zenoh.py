"""Live ROS 2 topics over Zenoh, as ``rmw_zenoh`` lays them out — no ROS installation needed.

Following ``rmw_zenoh``'s design document: a topic is published on
``<domain_id>/<name>/<DDS type name>/RIHS01_<hash>`` (REP 2011 type hashes: Iron, Jazzy and
later, not Humble) with a CDR payload and the attachment rmw_zenoh subscribers require
(sequence number, source timestamp, publisher GID); liveliness tokens announce the node and one
publisher per topic so that ``ros2 topic list`` shows them. The session uses rmw_zenoh's
defaults: peer mode, router at ``tcp/localhost:7447``, multicast scouting off.
"""

from __future__ import annotations

import json
import threading
import time

import numpy as np

from teamslam._optional import require
from teamslam.ros2 import messages as m

__all__ = [
    "DEFAULT_QOS",
    "Ros2Publisher",
    "attachment",
    "liveliness_key",
    "mangle",
    "open_session",
    "parse_attachment",
    "parse_liveliness_key",
    "publisher_gid",
    "ros2_settings",
    "topic_key",
]

#: what needs the extras, in the error when one is missing
WHAT = "publishing ROS 2 topics (rmw_zenoh)"

POSE = "geometry_msgs/msg/PoseStamped"
PATH = "nav_msgs/msg/Path"
MARKERS = "visualization_msgs/msg/MarkerArray"
TF = "tf2_msgs/msg/TFMessage"
# reliable, volatile, keep-last depth 10 against rmw_zenoh's defaults (reliable, volatile,
# keep-last 42, infinite deadline/lifespan/lease, automatic liveliness)
DEFAULT_QOS = "::,10:,:,:,,"


def mangle(name: str) -> str:
    """rmw_zenoh's mangling: every ``/`` becomes ``%`` (an empty name becomes ``%``)."""
    return name.replace("/", "%") if name else "%"


def topic_key(domain_id: int, topic: str, msgtype: str, type_hash: str | None = None) -> str:
    """``<domain_id>/<fully qualified name>/<DDS type name>/<RIHS01 type hash>`` (the hash our
    typestore gives ``msgtype`` unless ``type_hash`` is given)."""
    type_hash = type_hash or m.type_hash(msgtype)
    return f"{domain_id}/{topic.strip('/')}/{m.dds_type_name(msgtype)}/{type_hash}"


def liveliness_key(
    domain_id: int,
    zid: str,
    node_id: int,
    node: str,
    entity_id: int | None = None,
    topic: str | None = None,
    msgtype: str | None = None,
    qos: str = DEFAULT_QOS,
    namespace: str = "",
    enclave: str = "",
    kind: str = "MP",
    type_hash: str | None = None,
) -> str:
    """The key of a node's (``NN``), a publisher's (``MP``) or a subscription's (``MS``)
    liveliness token (``type_hash``: our typestore's for ``msgtype`` unless given)."""
    head = f"@ros2_lv/{domain_id}/{zid}/{node_id}"
    tail = f"{mangle(enclave)}/{mangle(namespace)}/{mangle(node)}"
    if topic is None:
        return f"{head}/{node_id}/NN/{tail}"
    if kind not in ("MP", "MS"):
        raise ValueError(f"an entity token is MP (publisher) or MS (subscription), not {kind!r}")
    return (
        f"{head}/{entity_id}/{kind}/{tail}/{mangle(topic)}/{m.dds_type_name(msgtype)}/"
        f"{type_hash or m.type_hash(msgtype)}/{qos}"
    )


def parse_liveliness_key(key: str) -> dict | None:
    """The fields of an entity token's key (``MP`` or ``MS``): ``domain_id``, ``zid``,
    ``node_id``, ``entity_id``, ``kind``, ``node``, ``topic`` (unmangled), ``dds_type``,
    ``type_hash``, ``qos``; ``None`` for any other key (a node's token, or not rmw_zenoh's)."""
    parts = str(key).split("/")
    if len(parts) != 13 or parts[0] != "@ros2_lv" or parts[5] not in ("MP", "MS"):
        return None
    return {
        "domain_id": parts[1],
        "zid": parts[2],
        "node_id": parts[3],
        "entity_id": parts[4],
        "kind": parts[5],
        "node": parts[8].replace("%", "/"),
        "topic": parts[9].replace("%", "/"),
        "dds_type": parts[10],
        "type_hash": parts[11],
        "qos": parts[12],
    }


def open_session(connect: list[str] | None = None, listen: list[str] | None = None, config=None):
    """A Zenoh session with rmw_zenoh's defaults (peer mode, router ``tcp/localhost:7447``,
    multicast scouting off), or with ``config`` (a ``zenoh.Config``) when given."""
    zenoh = require("zenoh", "network", WHAT)
    if config is None:
        config = zenoh.Config()
        config.insert_json5("mode", json.dumps("peer"))
        config.insert_json5("connect/endpoints", json.dumps(connect or ["tcp/localhost:7447"]))
        config.insert_json5("listen/endpoints", json.dumps(listen or ["tcp/localhost:0"]))
        config.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(config)


def publisher_gid(token_key: str) -> bytes:
    """rmw_zenoh's GID of an entity: XXH3-128 of its token key, low then high 64 bits (LE)."""
    xxhash = require("xxhash", "ros2", WHAT)
    value = xxhash.xxh3_128(token_key.encode()).intdigest()
    return (value & (2**64 - 1)).to_bytes(8, "little") + (value >> 64).to_bytes(8, "little")


def attachment(sequence_number: int, source_timestamp_ns: int, gid: bytes) -> bytes:
    """The sample attachment: int64 sequence number, int64 timestamp, GID length + bytes."""
    ext = require("zenoh.ext", "network", WHAT)
    Int64, z_serialize = ext.Int64, ext.z_serialize

    if len(gid) != 16:
        raise ValueError(f"a publisher GID has 16 bytes, got {len(gid)}")
    return z_serialize((Int64(sequence_number), Int64(source_timestamp_ns), bytes(gid))).to_bytes()


def parse_attachment(data: bytes) -> tuple[int, int, bytes]:
    """``(sequence number, source timestamp ns, gid)`` of an attachment; malformed → ValueError."""
    from teamslam.errors import InputError

    data = bytes(data)
    if len(data) != 33 or data[16] != 16:
        raise InputError(
            f"rmw_zenoh attachment must be 33 bytes (8 + 8 + 1 + 16), got {len(data)} bytes"
        )
    seq = int.from_bytes(data[:8], "little", signed=True)
    stamp = int.from_bytes(data[8:16], "little", signed=True)
    return seq, stamp, data[17:]


ROS2_SETTINGS = {
    "domain_id": 0,
    "connect": None,
    "listen": None,
    "period": 1.0,
    "path_every": 10,
    "objects_every": 10,
    "wait_s": 0.0,
}


def ros2_settings(section: dict | None, **overrides) -> dict:
    """The ``ros2`` section of a team file, checked, with defaults and non-None overrides.

    Keys: ``domain_id`` (0..232), ``connect`` / ``listen`` (lists of Zenoh endpoints),
    ``period`` (seconds between frames when the dataset has no timestamps), ``path_every``,
    ``objects_every`` (frames between Path / MarkerArray messages), ``wait_s`` (seconds to
    wait, at most, for a subscriber on every topic before the first frame).
    """
    from teamslam.errors import InputError

    section = dict(section or {})
    unknown = set(section) - set(ROS2_SETTINGS)
    if unknown:
        raise InputError(f"ros2: unknown setting(s) {', '.join(sorted(unknown))}")
    out = {**ROS2_SETTINGS, **section}
    out.update({k: v for k, v in overrides.items() if v is not None})
    domain = out["domain_id"]
    if isinstance(domain, bool) or not isinstance(domain, int) or not 0 <= domain <= 232:
        raise InputError(f"ros2.domain_id must be an integer in 0..232, got {domain!r}")
    for key in ("connect", "listen"):
        value = out[key]
        if value is not None and (
            not isinstance(value, list) or not all(isinstance(e, str) and "/" in e for e in value)
        ):
            raise InputError(f"ros2.{key} must be a list of Zenoh endpoints like tcp/HOST:PORT")
    period = out["period"]
    if isinstance(period, bool) or not isinstance(period, int | float) or not period > 0:
        raise InputError(f"ros2.period must be a positive number of seconds, got {period!r}")
    wait = out["wait_s"]
    if isinstance(wait, bool) or not isinstance(wait, int | float) or not 0 <= wait <= 3600:
        raise InputError(f"ros2.wait_s must be a number of seconds in [0, 3600], got {wait!r}")
    for key in ("path_every", "objects_every"):
        value = out[key]
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise InputError(f"ros2.{key} must be a positive integer, got {value!r}")
    return out


class Ros2Publisher:
    """One robot's pose, path and map as ROS 2 topics on an rmw_zenoh network.

    Topics: ``/robot_<i>/pose`` (PoseStamped, every frame), ``/tf`` (TFMessage ``world`` →
    ``robot_<i>/base_link``, every frame, as ``teamslam run --mcap`` writes it),
    ``/robot_<i>/path`` (Path, every ``path_every`` frames and the last) and
    ``/robot_<i>/objects`` (MarkerArray, spheres and 3σ ellipsoids, every ``objects_every``
    frames and the last), frame ``world``, stamped with ``stamps_ns`` (the dataset's
    timestamps, or frame index × period) — or, for a sequence that grows while it runs (a live
    robot), with the stamp each :meth:`publish` gives (no frame is then the last).

    Parameters
    ----------
    robot
        The robot's id (names the topics and the node ``teamslam_robot_<i>``).
    stamps_ns
        Stamp of every frame, integer nanoseconds; ``None``: given frame by frame.
    domain_id
        ``ROS_DOMAIN_ID``.
    connect, listen
        Zenoh endpoints (default: rmw_zenoh's, router ``tcp/localhost:7447``).
    path_every, objects_every
        Frames between Path and between MarkerArray messages.
    n_sigma
        Size of the object ellipsoids.
    wait_s
        Wait up to this long for a subscriber on every topic before returning.
    """

    def __init__(
        self,
        robot: int,
        stamps_ns: np.ndarray | None = None,
        domain_id: int = 0,
        connect: list[str] | None = None,
        listen: list[str] | None = None,
        path_every: int = 10,
        objects_every: int = 10,
        n_sigma: float = 3.0,
        wait_s: float = 0.0,
    ) -> None:
        zenoh = require("zenoh", "network", WHAT)
        self.robot = robot
        self.growing = stamps_ns is None
        self._stamps = np.zeros(64 if self.growing else 0, dtype=np.int64)
        self._given = 0  # growing: frames whose stamp was given
        if not self.growing:
            self._stamps = np.asarray(stamps_ns, dtype=np.int64)
        self.domain_id = int(domain_id)
        self.path_every = max(int(path_every), 1)
        self.objects_every = max(int(objects_every), 1)
        self.n_sigma = n_sigma
        self.node = f"teamslam_robot_{robot}"
        self.topics = {
            "pose": (f"/robot_{robot}/pose", POSE),
            "path": (f"/robot_{robot}/path", PATH),
            "objects": (f"/robot_{robot}/objects", MARKERS),
            "tf": ("/tf", TF),
        }
        self.base_frame = f"robot_{robot}/base_link"
        self.sphere_diameter: float | None = None
        self._published: list = []
        self.samples_sent = 0
        self.bytes_sent = 0
        self._lock = threading.Lock()
        self.session = open_session(connect, listen)
        self.zid = str(self.session.info.zid())
        node_id = 0
        self._tokens = [
            self.session.liveliness().declare_token(
                liveliness_key(self.domain_id, self.zid, node_id, self.node)
            )
        ]
        self._publishers: dict[str, tuple] = {}
        for entity_id, (name, (topic, msgtype)) in enumerate(self.topics.items(), start=1):
            token_key = liveliness_key(
                self.domain_id, self.zid, node_id, self.node, entity_id, topic, msgtype
            )
            publisher = self.session.declare_publisher(
                topic_key(self.domain_id, topic, msgtype),
                reliability=zenoh.Reliability.RELIABLE,
            )
            self._tokens.append(self.session.liveliness().declare_token(token_key))
            self._publishers[name] = [publisher, msgtype, publisher_gid(token_key), 1]
        if wait_s > 0:
            self.wait_for_subscribers(wait_s)

    @property
    def stamps_ns(self) -> np.ndarray:
        """The stamps of the frames (growing: those given so far)."""
        return self._stamps[: self._given] if self.growing else self._stamps

    @property
    def keys(self) -> dict[str, str]:
        """Topic key expression of each of ``pose``, ``path``, ``objects``, ``tf``."""
        return {name: str(p[0].key_expr) for name, p in self._publishers.items()}

    def gid(self, name: str) -> bytes:
        """The GID of the publisher of ``pose``, ``path``, ``objects`` or ``tf``."""
        return self._publishers[name][2]

    def matched(self) -> bool:
        """Whether every topic has a subscriber (Zenoh's matching status)."""
        return all(p[0].matching_status.matching for p in self._publishers.values())

    def wait_for_subscribers(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` until every topic has a subscriber; whether they do."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.matched():
                return True
            time.sleep(0.02)
        return self.matched()

    def _put(self, name: str, message) -> None:
        entry = self._publishers[name]
        publisher, msgtype, gid, seq = entry
        payload = m.serialize(message, msgtype)
        publisher.put(payload, attachment=attachment(seq, time.time_ns(), gid))
        entry[3] = seq + 1
        self.samples_sent += 1
        self.bytes_sent += len(payload)

    def publish(self, frame: int, poses: np.ndarray, state, stamp_ns: int | None = None) -> None:
        """Publish frame ``frame``: ``poses`` are the filtered poses of frames ``0..frame``,
        ``state`` the robot's :class:`~teamslam.msckf.filter.state.MsckfState` (its map);
        ``stamp_ns`` its stamp, given when the publisher was made without stamps (a growing
        sequence: frames in order; a resumed robot's first frame may come after others).

        Raises
        ------
        ValueError
            A stamp given to a publisher with stamps, or none to one without.
        """
        if self.growing == (stamp_ns is None):
            raise ValueError(
                "give each frame's stamp to a publisher made without stamps, and only to it"
            )
        with self._lock:
            if self.growing:
                self._stamp(frame, int(stamp_ns))
            stamps = self.stamps_ns
            stamp = int(stamps[frame])
            last = not self.growing and frame == len(stamps) - 1
            if len(self._published) != frame:  # a resumed run: the frames before this one
                self._published = m.poses_stamped(poses[:frame], stamps[:frame])
            self._published.append(m.pose_stamped(poses[frame], stamp))
            self._put("pose", self._published[-1])
            transform = [(self._published[-1].pose, "world", self.base_frame)]
            self._put("tf", m.tf_message(transform, stamp))
            if (frame + 1) % self.path_every == 0 or last:
                self._put("path", m.path_msg(self._published, stamps[: frame + 1]))
            if (frame + 1) % self.objects_every == 0 or last:
                ids, means, covs = state.full_map()  # in the state and retired, by id
            else:
                ids = np.zeros(0, dtype=np.int64)
            if ids.size:
                if self.sphere_diameter is None:
                    extent = float(np.ptp(means, axis=0).max())
                    self.sphere_diameter = 0.01 * extent if extent > 0 else 1.0
                markers = m.object_markers(
                    ids,
                    means,
                    covs,
                    stamp,
                    self.robot,
                    self.sphere_diameter,
                    n_sigma=self.n_sigma,
                )
                self._put("objects", markers)

    def stamp(self, frame: int, stamp_ns: int) -> None:
        """Record frame ``frame``'s stamp without publishing it (a publisher made without stamps:
        e.g. the frames a resumed robot did before, which its path starts with)."""
        if not self.growing:
            raise ValueError("this publisher was given every frame's stamp")
        with self._lock:
            self._stamp(frame, int(stamp_ns))

    def _stamp(self, frame: int, stamp_ns: int) -> None:
        if frame >= self._stamps.shape[0]:
            grown = np.zeros(max(2 * self._stamps.shape[0], frame + 1), dtype=np.int64)
            grown[: self._stamps.shape[0]] = self._stamps
            self._stamps = grown
        self._stamps[frame] = stamp_ns
        self._given = max(self._given, frame + 1)

    def close(self) -> None:
        """Withdraw the liveliness tokens and close the session."""
        with self._lock:
            for token in self._tokens:
                token.undeclare()
            self._tokens = []
            for entry in self._publishers.values():
                entry[0].undeclare()
            self.session.close()
