"""ROS 2 messages from teamslam's poses and Gaussians.

Types come from ``rosbags``' typestore of ROS 2 Jazzy (the message definitions, CDR
serialisation, and the RIHS01 type hashes of REP 2011 that rmw_zenoh puts in its key
expressions and rosbag2 in its metadata) plus teamslam's own
``teamslam_msgs/msg/StereoObservations`` and the detector messages of ``vision_msgs`` 4
(``Detection2DArray`` and what it holds), which rosbags does not ship. Stamps are integer
nanoseconds; poses are 4×4 ``T_parent_child`` matrices; quaternions are ``(x, y, z, w)`` as in
ROS.
"""

from __future__ import annotations

import os
import tempfile
from functools import cache
from importlib import resources
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from teamslam._optional import require

__all__ = [
    "DETECTIONS_TYPE",
    "OBSERVATIONS_TYPE",
    "VISION_MSGS",
    "dds_type_name",
    "object_markers",
    "observations_msgdef",
    "path_msg",
    "pose_msg",
    "pose_msgs",
    "pose_stamped",
    "poses_stamped",
    "serialize",
    "tf_message",
    "type_hash",
    "typestore",
]

OBSERVATIONS_TYPE = "teamslam_msgs/msg/StereoObservations"
KIND_FEATURE = 0
KIND_OBJECT = 1
OBSERVATION_COLUMNS = ("u_left", "v_left", "u_right", "v_right")


# vision_msgs 4.x (Humble, Jazzy): the detector messages rosbags does not ship. Field lists only;
# the RIHS01 hash depends on fields alone, so these hash as the installed package does.
VISION_MSGS = {
    "vision_msgs/msg/Point2D": "float64 x\nfloat64 y\n",
    "vision_msgs/msg/Pose2D": "vision_msgs/Point2D position\nfloat64 theta\n",
    "vision_msgs/msg/BoundingBox2D": (
        "vision_msgs/Pose2D center\nfloat64 size_x\nfloat64 size_y\n"
    ),
    "vision_msgs/msg/ObjectHypothesis": "string class_id\nfloat64 score\n",
    "vision_msgs/msg/ObjectHypothesisWithPose": (
        "vision_msgs/ObjectHypothesis hypothesis\ngeometry_msgs/PoseWithCovariance pose\n"
    ),
    "vision_msgs/msg/Detection2D": (
        "std_msgs/Header header\nvision_msgs/ObjectHypothesisWithPose[] results\n"
        "vision_msgs/BoundingBox2D bbox\nstring id\n"
    ),
    "vision_msgs/msg/Detection2DArray": (
        "std_msgs/Header header\nvision_msgs/Detection2D[] detections\n"
    ),
}
DETECTIONS_TYPE = "vision_msgs/msg/Detection2DArray"


def observations_msgdef() -> str:
    """The text of ``StereoObservations.msg`` shipped with the package."""
    return (
        resources.files("teamslam.ros2")
        .joinpath("msg", "StereoObservations.msg")
        .read_text(encoding="utf-8")
    )


def rosbags(module: str, what: str = "ROS 2 interchange (bags, MCAP, topics)"):
    """The module ``rosbags.<module>`` (the ``ros2`` extra); ``what`` names the feature in the
    error when the extra is not installed."""
    return require(f"rosbags.{module}", "ros2", what)


@cache
def typestore():
    """The Jazzy typestore with ``teamslam_msgs/msg/StereoObservations`` and the detector
    messages of ``vision_msgs`` 4 (:data:`VISION_MSGS`) registered."""
    typesys = rosbags("typesys")

    store = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)
    store.register(typesys.get_types_from_msg(observations_msgdef(), OBSERVATIONS_TYPE))
    vision: dict = {}
    for name, text in VISION_MSGS.items():
        vision.update(typesys.get_types_from_msg(text, name))
    store.register(vision)
    return store


def schema_text(msgtype: str) -> str:
    """The ``ros2msg`` schema of ``msgtype``: its definition then each dependency's.

    For ``teamslam_msgs/msg/StereoObservations`` the definition is the shipped ``.msg`` text
    itself (with its comments), so a bag carries the documented definition.
    """
    text, _ = typestore().generate_msgdef(msgtype, ros_version=2)
    if msgtype == OBSERVATIONS_TYPE:
        separator = "=" * 80 + "\n"
        _, _, rest = text.partition(separator)
        text = observations_msgdef().rstrip("\n") + "\n" + separator + rest
    return text


def type_hash(msgtype: str) -> str:
    """The RIHS01 type hash of ``msgtype`` (``RIHS01_<64 hex digits>``)."""
    return typestore().hash_rihs01(msgtype)


def dds_type_name(msgtype: str) -> str:
    """``pkg/msg/Name`` as DDS names it for CDR: ``pkg::msg::dds_::Name_``."""
    pkg, kind, name = msgtype.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def serialize(message, msgtype: str | None = None) -> bytes:
    """CDR bytes (little endian, with the 4-byte encapsulation header) of ``message``."""
    return bytes(typestore().serialize_cdr(message, msgtype or message.__msgtype__))


def _types():
    return typestore().types


def time_msg(stamp_ns: int):
    """``builtin_interfaces/msg/Time`` of integer nanoseconds (negative stamps refused)."""
    stamp_ns = int(stamp_ns)
    if stamp_ns < 0:
        raise ValueError(f"ROS 2 stamps cannot be negative, got {stamp_ns} ns")
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    return _types()["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)


def stamp_ns(time) -> int:
    """Integer nanoseconds of a ``builtin_interfaces/msg/Time``."""
    return int(time.sec) * 1_000_000_000 + int(time.nanosec)


def header(stamp: int, frame_id: str):
    """``std_msgs/msg/Header``."""
    return _types()["std_msgs/msg/Header"](stamp=time_msg(stamp), frame_id=frame_id)


def pose_msgs(poses: np.ndarray) -> list:
    """``geometry_msgs/msg/Pose`` of each of ``(N, 4, 4)`` transforms (one batched conversion)."""
    t = _types()
    poses = np.asarray(poses, dtype=float).reshape(-1, 4, 4)
    if not len(poses):
        return []
    quats = Rotation.from_matrix(poses[:, :3, :3]).as_quat().tolist()
    Pose, Point, Quaternion = (
        t["geometry_msgs/msg/Pose"],
        t["geometry_msgs/msg/Point"],
        t["geometry_msgs/msg/Quaternion"],
    )
    return [
        Pose(
            position=Point(x=p[0], y=p[1], z=p[2]),
            orientation=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]),
        )
        for p, q in zip(poses[:, :3, 3].tolist(), quats, strict=True)
    ]


def pose_msg(T: np.ndarray):
    """``geometry_msgs/msg/Pose`` of a 4×4 transform."""
    return pose_msgs(np.asarray(T)[None])[0]


def pose_matrix(pose) -> np.ndarray:
    """4×4 transform of a ``geometry_msgs/msg/Pose`` (or ``Transform``)."""
    p = getattr(pose, "position", None) or pose.translation
    q = getattr(pose, "orientation", None) or pose.rotation
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    T[:3, 3] = (p.x, p.y, p.z)
    return T


def pose_stamped(T: np.ndarray, stamp: int, frame_id: str = "world"):
    """``geometry_msgs/msg/PoseStamped``."""
    return _types()["geometry_msgs/msg/PoseStamped"](
        header=header(stamp, frame_id), pose=pose_msg(T)
    )


def poses_stamped(poses: np.ndarray, stamps: np.ndarray, frame_id: str = "world") -> list:
    """``PoseStamped`` of each of ``(N, 4, 4)`` poses, stamped ``stamps`` (batched)."""
    PoseStamped = _types()["geometry_msgs/msg/PoseStamped"]
    return [
        PoseStamped(header=header(int(s), frame_id), pose=p)
        for p, s in zip(pose_msgs(poses), stamps, strict=True)
    ]


def path_msg(poses: np.ndarray | list, stamps: np.ndarray, frame_id: str = "world"):
    """``nav_msgs/msg/Path`` of ``(N, 4, 4)`` poses stamped ``stamps`` (or of ready
    ``PoseStamped`` messages); the path is stamped as its last pose."""
    stamped = poses if isinstance(poses, list) else poses_stamped(poses, stamps, frame_id)
    return _types()["nav_msgs/msg/Path"](header=header(int(stamps[-1]), frame_id), poses=stamped)


def tf_message(transforms: list[tuple[np.ndarray | object, str, str]], stamp: int):
    """``tf2_msgs/msg/TFMessage`` of ``(T_parent_child, parent, child)`` triples.

    ``T_parent_child`` is a 4×4 matrix or a ready ``geometry_msgs/msg/Pose``.
    """
    t = _types()
    out = []
    matrices = [T for T, _, _ in transforms if isinstance(T, np.ndarray)]
    converted = iter(pose_msgs(np.stack(matrices)) if matrices else [])
    poses = [next(converted) if isinstance(T, np.ndarray) else T for T, _, _ in transforms]
    for pose, (_, parent, child) in zip(poses, transforms, strict=True):
        p, q = pose.position, pose.orientation
        out.append(
            t["geometry_msgs/msg/TransformStamped"](
                header=header(stamp, parent),
                child_frame_id=child,
                transform=t["geometry_msgs/msg/Transform"](
                    translation=t["geometry_msgs/msg/Vector3"](x=p.x, y=p.y, z=p.z),
                    rotation=q,
                ),
            )
        )
    return t["tf2_msgs/msg/TFMessage"](transforms=out)


def ellipsoid_axes(covs: np.ndarray, n_sigma: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """Diameters and orientations of the ``n_sigma`` ellipsoids of ``(m, 3, 3)`` covariances.

    Returns ``(scale (m, 3), quaternion (m, 4))``: the ellipsoid of points ``x`` with
    ``xᵀ Σ⁻¹ x ≤ n_sigma²`` has semi-axes ``n_sigma·√λ_k`` along the eigenvectors of ``Σ``; a
    Marker SPHERE takes diameters, so ``scale = 2·n_sigma·√λ``. Eigenvector frames are made
    right-handed before conversion to quaternions.
    """
    covs = np.asarray(covs, dtype=float).reshape(-1, 3, 3)
    vals, vecs = np.linalg.eigh(0.5 * (covs + np.swapaxes(covs, 1, 2)))
    flip = np.linalg.det(vecs) < 0
    vecs[flip, :, 2] *= -1.0
    scale = 2.0 * n_sigma * np.sqrt(np.clip(vals, 0.0, None))
    quats = Rotation.from_matrix(vecs).as_quat() if len(covs) else np.zeros((0, 4))
    return scale, quats


def _colour(index: int, alpha: float):
    import matplotlib

    r, g, b, _ = matplotlib.colormaps["tab10"](index % 10)
    return _types()["std_msgs/msg/ColorRGBA"](r=float(r), g=float(g), b=float(b), a=float(alpha))


def object_markers(
    ids: np.ndarray,
    means: np.ndarray,
    covs: np.ndarray | None,
    stamp: int,
    colour_index: int,
    sphere_diameter: float,
    frame_id: str = "world",
    n_sigma: float = 3.0,
):
    """``visualization_msgs/msg/MarkerArray``: per object a sphere and its 3σ ellipsoid.

    Spheres are in namespace ``objects`` and ellipsoids in ``objects_<n>sigma``, both with the
    object id as marker id, so a later array replaces an earlier one object by object.
    """
    t = _types()
    Marker = t["visualization_msgs/msg/Marker"]
    ids = np.asarray(ids, dtype=np.int64)
    means = np.asarray(means, dtype=float).reshape(-1, 3)
    hdr = header(stamp, frame_id)
    zero = t["builtin_interfaces/msg/Duration"](sec=0, nanosec=0)
    empty_image = t["sensor_msgs/msg/CompressedImage"](
        header=header(0, ""), format="", data=np.zeros(0, np.uint8)
    )
    empty_mesh = t["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, np.uint8))
    solid, shell = _colour(colour_index, 1.0), _colour(colour_index, 0.25)
    identity = t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)

    def marker(ns, oid, p, q, scale, colour):
        return Marker(
            header=hdr,
            ns=ns,
            id=int(oid),
            type=Marker.SPHERE,
            action=Marker.ADD,
            pose=t["geometry_msgs/msg/Pose"](
                position=t["geometry_msgs/msg/Point"](x=float(p[0]), y=float(p[1]), z=float(p[2])),
                orientation=q,
            ),
            scale=t["geometry_msgs/msg/Vector3"](
                x=float(scale[0]), y=float(scale[1]), z=float(scale[2])
            ),
            color=colour,
            lifetime=zero,
            frame_locked=False,
            points=[],
            colors=[],
            texture_resource="",
            texture=empty_image,
            uv_coordinates=[],
            text="",
            mesh_resource="",
            mesh_file=empty_mesh,
            mesh_use_embedded_materials=False,
        )

    markers = [
        marker("objects", oid, p, identity, (sphere_diameter,) * 3, solid)
        for oid, p in zip(ids, means, strict=True)
    ]
    if covs is not None:
        scales, quats = ellipsoid_axes(covs, n_sigma)
        Quaternion = t["geometry_msgs/msg/Quaternion"]
        markers += [
            marker(
                f"objects_{n_sigma:g}sigma",
                oid,
                p,
                Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
                s,
                shell,
            )
            for oid, p, s, q in zip(ids, means, scales, quats, strict=True)
        ]
    return t["visualization_msgs/msg/MarkerArray"](markers=markers)


def write_mcap_records(records: list[tuple[int, str, str, bytes]], out: Path) -> dict[str, int]:
    """Write ``(stamp ns, topic, type, CDR bytes)`` records, in stamp order, as one rosbag2 MCAP
    file (zstd chunks, each topic's schema and RIHS01 hash embedded); messages per topic.

    The file is written beside ``out`` and moved into place, so a partial file never replaces
    a complete one.
    """
    Writer = rosbags("rosbag2").Writer
    enums = rosbags("rosbag2.enums")
    CompressionFormat, CompressionMode = enums.CompressionFormat, enums.CompressionMode
    StoragePlugin = enums.StoragePlugin

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    counts: dict[str, int] = {}
    with tempfile.TemporaryDirectory(prefix=f".{out.name}.", dir=out.parent) as tmp:
        bag = Path(tmp) / "bag"
        writer = Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP)
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        with writer:
            connections = {}
            for stamp, topic, msgtype, data in sorted(records, key=lambda rec: rec[0]):
                if topic not in connections:
                    connections[topic] = writer.add_connection(
                        topic, msgtype, msgdef=schema_text(msgtype), rihs01=type_hash(msgtype)
                    )
                writer.write(connections[topic], stamp, data)
                counts[topic] = counts.get(topic, 0) + 1
        os.replace(next(bag.glob("*.mcap")), out)
    return counts
