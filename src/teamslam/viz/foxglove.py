"""One robot's estimates served live over the Foxglove WebSocket protocol (``foxglove-sdk``).

:class:`FoxgloveView` runs the SDK's WebSocket server and, fed after each frame, logs the
robot's pose, path, map and transforms, and on image robots the left image with the detector's
boxes, their tracked ids and the camera's calibration, in Foxglove's well-known schemas
(protobuf), so that the Foxglove app connects to the robot with no ROS installed. Frames are
explicit: ``world`` and ``robot_<i>/base_link`` (and ``robot_<i>/camera_left`` for images), as
the ROS 2 publisher names them. Contract: a message is built only when a client subscribes to
its channel (the SDK says whether a channel has sinks), so with no client a frame costs a few
look-ups and no image is encoded; logging never blocks (the SDK queues per client and drops the
oldest message of a slow one); the view reads the estimates and never writes them.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from teamslam._optional import require
from teamslam.errors import InputError, OutputError

__all__ = ["TOPICS", "WHAT", "Boxes", "CameraModel", "FoxgloveView", "parse_address"]

#: what needs the extra, in the error when it is missing
WHAT = "a Foxglove live view (--foxglove)"

#: the view's channels by name: topic template (``{robot}`` is the robot's id) and what it shows
TOPICS = {
    "pose": ("/robot_{robot}/pose", "PoseInFrame: the robot's current pose in world"),
    "path": ("/robot_{robot}/path", "PosesInFrame: its poses so far in world"),
    "objects": ("/robot_{robot}/objects", "SceneUpdate: its map's objects, n-sigma ellipsoids"),
    "tf": ("/tf", "FrameTransforms: world → robot_<i>/base_link (→ camera_left)"),
    "image": ("/robot_{robot}/camera/left/compressed", "CompressedImage: the left image, JPEG"),
    "boxes": ("/robot_{robot}/camera/left/boxes", "ImageAnnotations: boxes, tracked ids"),
    "calibration": (
        "/robot_{robot}/camera/left/calibration",
        "CameraCalibration: the left camera's intrinsics, distortion and rectification",
    ),
    "latency": ("/robot_{robot}/latency", "JSON: the frame's latency in milliseconds"),
}

LATENCY_SCHEMA = {
    "type": "object",
    "title": "teamslam latency",
    "properties": {
        "frame": {"type": "integer", "description": "frame index"},
        "latency_ms": {
            "type": "number",
            "description": "from the arrival of the frame's input to its pose's publication",
        },
    },
}


@dataclass(frozen=True)
class Boxes:
    """A detector's boxes in one left image, with what the robot's tracker made of them.

    Attributes
    ----------
    boxes
        ``(D, 4)`` ``(x_min, y_min, x_max, y_max)`` in pixels of the image.
    ids
        ``(D,)`` object id the tracker gave each box (``-1``: none), or ``None``.
    classes
        ``(D,)`` class label of each box, or ``None``.
    """

    boxes: np.ndarray
    ids: np.ndarray | None = None
    classes: np.ndarray | None = None


#: Foxglove's distortion models of OpenCV's coefficients by their count: ``(k1, k2, p1, p2, k3)``
#: and ``(k1, k2, p1, p2, k3, k4, k5, k6)``
_DISTORTION_MODELS = {5: "plumb_bob", 8: "rational_polynomial"}


@dataclass(frozen=True)
class CameraModel:
    """The left camera as the Foxglove app needs it to draw the 3D scene over the image.

    Attributes
    ----------
    image_size
        ``(width, height)`` of the raw image, in pixels.
    K
        ``(3, 3)`` raw intrinsics.
    distortion
        OpenCV distortion coefficients of the raw image (``k1, k2, p1, p2[, k3[, k4, k5,
        k6]]``; longer vectors only with trailing zeros).
    R
        ``(3, 3)`` rotation from the raw to the rectified left frame.
    P
        ``(3, 4)`` projection of the rectified left image.
    """

    image_size: tuple[int, int]
    K: np.ndarray
    distortion: np.ndarray
    R: np.ndarray
    P: np.ndarray

    def __post_init__(self) -> None:
        self.distortion_model()  # a vector Foxglove cannot show is refused when made

    def distortion_model(self) -> tuple[str, list[float]]:
        """Foxglove's name of the distortion model and its coefficients.

        Raises
        ------
        InputError
            Coefficients beyond ``k6`` that are not zero (thin prism, tilt: no Foxglove
            model), named in one line.
        """
        d = np.asarray(self.distortion, float).ravel()
        n = int(np.flatnonzero(d)[-1]) + 1 if np.any(d) else 0  # trailing zeros say nothing
        if n > max(_DISTORTION_MODELS):
            raise InputError(
                f"camera distortion of {d.size} coefficients: coefficient {n} is not zero "
                "and Foxglove has no model for it"
            )
        size = min(m for m in _DISTORTION_MODELS if m >= n)
        d = np.concatenate([d[:n], np.zeros(size - n)])
        return _DISTORTION_MODELS[size], [float(x) for x in d]


def parse_address(text: str, default_host: str = "127.0.0.1") -> tuple[str, int]:
    """``[HOST:]PORT`` as ``(host, port)`` (``default_host`` when none is given; ``0``: a free
    port).

    Raises
    ------
    InputError
        Not ``[HOST:]PORT`` with a port in ``0..65535``.
    """
    host, sep, port = str(text).rpartition(":")
    if not sep:
        host = default_host
    host = host.strip("[]")  # [::1]:8765
    if (sep and not host) or not port.isascii() or not port.isdigit() or int(port) > 65535:
        raise InputError(f"expected [HOST:]PORT with a port in 0..65535, got {text!r}")
    return host, int(port)


def _timestamp(fm, stamp_ns: int):
    return fm.Timestamp(sec=int(stamp_ns) // 1_000_000_000, nsec=int(stamp_ns) % 1_000_000_000)


def _parts(fm, T: np.ndarray):
    """``(translation Vector3, rotation Quaternion)`` of a ``4×4`` pose."""
    x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
    return (
        fm.Vector3(x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3])),
        fm.Quaternion(x=float(x), y=float(y), z=float(z), w=float(w)),
    )


def _pose(fm, T: np.ndarray):
    position, orientation = _parts(fm, T)
    return fm.Pose(position=position, orientation=orientation)


def _poses(fm, Ts: np.ndarray) -> list:
    """The ``Pose`` of each of ``(n, 4, 4)`` poses (the rotations converted at once)."""
    quats = Rotation.from_matrix(Ts[:, :3, :3]).as_quat() if len(Ts) else np.zeros((0, 4))
    return [
        fm.Pose(
            position=fm.Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
            orientation=fm.Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
        )
        for p, q in zip(Ts[:, :3, 3].tolist(), quats.tolist(), strict=True)
    ]


def _palette() -> np.ndarray:
    """``(10, 3)`` the colours of matplotlib's ``tab10``, for ids and classes."""
    import matplotlib

    return np.asarray(matplotlib.colormaps["tab10"].colors, float)


class FoxgloveView:
    """One robot's live view: a Foxglove WebSocket server fed after each frame.

    Parameters
    ----------
    robot
        The robot's id (names the topics, the server and the frame ``robot_<i>/base_link``).
    host, port
        Where the server listens (default loopback; port ``0``: a free one, see :attr:`port`).
    stamps_ns
        Stamp of every frame (integer nanoseconds) for a caller that gives none
        (``publish(t, poses, state)``, as a run over a dataset calls its publisher).
    path_every, objects_every
        Frames between path messages (the path grows with the run) and between map messages.
    n_sigma
        Size of the objects' ellipsoids.
    jpeg_quality
        Of the left image.
    T_cam_body
        The left camera's pose in the body (``camera_left`` in ``/tf``; images only).
    camera
        The left camera's calibration, logged with each image so that the Foxglove app draws
        the map over it (images only; may be set later through :attr:`camera`).

    Raises
    ------
    MissingExtra
        The ``foxglove`` extra is not installed.
    OutputError
        The server cannot listen there (one line, e.g. the port is taken).
    """

    def __init__(
        self,
        robot: int,
        host: str = "127.0.0.1",
        port: int = 8765,
        stamps_ns: np.ndarray | None = None,
        *,
        path_every: int = 10,
        objects_every: int = 1,
        n_sigma: float = 3.0,
        jpeg_quality: int = 80,
        T_cam_body: np.ndarray | None = None,
        camera: CameraModel | None = None,
    ) -> None:
        foxglove = require("foxglove", "foxglove", WHAT)
        self._fm = require("foxglove.messages", "foxglove", WHAT)
        channels = require("foxglove.channels", "foxglove", WHAT)
        self.robot = int(robot)
        self.world_frame = "world"
        self.base_frame = f"robot_{robot}/base_link"
        self.camera_frame = f"robot_{robot}/camera_left"
        self.stamps_ns = None if stamps_ns is None else np.asarray(stamps_ns, np.int64)
        self.path_every = max(int(path_every), 1)
        self.objects_every = max(int(objects_every), 1)
        self.n_sigma = float(n_sigma)
        self.jpeg_quality = int(jpeg_quality)
        self.T_cam_body = None if T_cam_body is None else np.asarray(T_cam_body, float)
        #: the left camera, for the calibration beside each image (images only)
        self.camera = camera
        self._palette = _palette()  # read now: matplotlib's import is not a frame's cost
        #: messages logged, by channel name (a message is built only for a subscribed channel)
        self.logged = dict.fromkeys(TOPICS, 0)
        self._shown: set[int] = set()  # object ids in the last map message
        self._context = foxglove.Context()  # this view's channels only
        topic = {name: t.format(robot=robot) for name, (t, _) in TOPICS.items()}
        ctx = self._context
        self._channels = {
            "pose": channels.PoseInFrameChannel(topic["pose"], context=ctx),
            "path": channels.PosesInFrameChannel(topic["path"], context=ctx),
            "objects": channels.SceneUpdateChannel(topic["objects"], context=ctx),
            "tf": channels.FrameTransformsChannel(topic["tf"], context=ctx),
            "image": channels.CompressedImageChannel(topic["image"], context=ctx),
            "boxes": channels.ImageAnnotationsChannel(topic["boxes"], context=ctx),
            "calibration": channels.CameraCalibrationChannel(topic["calibration"], context=ctx),
            "latency": foxglove.Channel(topic["latency"], schema=LATENCY_SCHEMA, context=ctx),
        }
        self.topics = topic
        try:
            self._server = foxglove.start_server(
                name=f"teamslam robot {robot}", host=host, port=int(port), context=ctx
            )
        except RuntimeError as exc:  # the SDK's FoxgloveError: cannot bind
            for channel in self._channels.values():
                channel.close()
            raise OutputError(f"Foxglove view on {host}:{port}: {exc}") from None
        self.host = host

    @property
    def port(self) -> int:
        """The port the server listens on."""
        return int(self._server.port)

    @property
    def url(self) -> str:
        """``ws://host:port``, what the Foxglove app opens."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    def subscribed(self, name: str) -> bool:
        """Whether a client subscribes to channel ``name`` (a key of :data:`TOPICS`)."""
        return bool(self._channels[name].has_sinks())

    def _colour(self, index: int, alpha: float = 1.0):
        r, g, b = self._palette[int(index) % len(self._palette)]
        return self._fm.Color(r=float(r), g=float(g), b=float(b), a=float(alpha))

    def _log(self, name: str, message, stamp_ns: int) -> None:
        self._channels[name].log(message, log_time=int(stamp_ns))
        self.logged[name] += 1

    def publish(
        self,
        frame: int,
        poses: np.ndarray,
        state,
        stamp_ns: int | None = None,
        *,
        image: np.ndarray | None = None,
        boxes: Boxes | None = None,
        labels_of: Callable[[np.ndarray], np.ndarray] | None = None,
        class_names: Mapping[int, str] | None = None,
        latency_ms: float | None = None,
    ) -> None:
        """Log frame ``frame`` on every subscribed channel.

        Parameters
        ----------
        frame
            The frame's index.
        poses
            ``(≥ frame + 1, 4, 4)`` the robot's filtered poses ``T_world_body`` so far.
        state
            Its :class:`~teamslam.msckf.filter.state.MsckfState` (the map: ``full_map()``).
        stamp_ns
            The frame's stamp (default: ``stamps_ns[frame]`` given at construction).
        image
            The left image (``uint8``, grey or BGR), on image robots.
        boxes
            The detector's boxes in it, with their tracked ids.
        labels_of
            The class label of each object id (``-1``: none), for the map.
        class_names
            The name of each class label (default: the label's number).
        latency_ms
            The frame's latency.
        """
        if stamp_ns is None:
            if self.stamps_ns is None:
                raise ValueError("give each frame's stamp to a view made without stamps")
            stamp_ns = int(self.stamps_ns[frame])
        fm = self._fm
        when = _timestamp(fm, stamp_ns)
        T_world_body = np.asarray(poses[frame], float)
        if self.subscribed("pose"):
            message = fm.PoseInFrame(
                timestamp=when, frame_id=self.world_frame, pose=_pose(fm, T_world_body)
            )
            self._log("pose", message, stamp_ns)
        if self.subscribed("tf"):
            self._log("tf", self._transforms(when, T_world_body), stamp_ns)
        if self.subscribed("path") and frame % self.path_every == 0:
            path = _poses(fm, np.asarray(poses[: frame + 1], float))
            message = fm.PosesInFrame(timestamp=when, frame_id=self.world_frame, poses=path)
            self._log("path", message, stamp_ns)
        if self.subscribed("objects") and frame % self.objects_every == 0:
            message = self._map(when, state, labels_of, class_names or {})
            self._log("objects", message, stamp_ns)
        if image is not None and self.subscribed("image"):
            self._log("image", self._image(when, image), stamp_ns)
        if image is not None and self.camera is not None and self.subscribed("calibration"):
            self._log("calibration", self._calibration(when), stamp_ns)
        if image is not None and boxes is not None and self.subscribed("boxes"):
            self._log("boxes", self._boxes(when, boxes, class_names or {}), stamp_ns)
        if latency_ms is not None and self.subscribed("latency"):
            message = {"frame": int(frame), "latency_ms": float(latency_ms)}
            self._log("latency", message, stamp_ns)

    def _transforms(self, when, T_world_body: np.ndarray):
        fm = self._fm
        out = []
        links = [(self.world_frame, self.base_frame, T_world_body)]
        if self.T_cam_body is not None:
            links.append((self.base_frame, self.camera_frame, np.linalg.inv(self.T_cam_body)))
        for parent, child, T_parent_child in links:
            translation, rotation = _parts(fm, T_parent_child)
            out.append(
                fm.FrameTransform(
                    timestamp=when,
                    parent_frame_id=parent,
                    child_frame_id=child,
                    translation=translation,
                    rotation=rotation,
                )
            )
        return fm.FrameTransforms(transforms=out)

    def _map(self, when, state, labels_of, class_names: Mapping[int, str]):
        """The map's objects: per id an entity with its ``n_sigma`` ellipsoid (a sphere scaled
        along the covariance's axes) and a text of its id and class; the ids gone since the
        last map message (merged by loop closure) deleted."""
        from teamslam.ros2.messages import ellipsoid_axes

        fm = self._fm
        ids, means, covs = state.full_map()
        labels = (
            np.full(ids.shape, -1, np.int64)
            if labels_of is None
            else np.asarray(labels_of(ids), np.int64)
        )
        scales, quats = ellipsoid_axes(covs, self.n_sigma)
        entities = []
        for oid, p, s, q, label in zip(ids, means, scales, quats, labels, strict=True):
            name = class_names.get(int(label), str(int(label))) if label >= 0 else ""
            position = fm.Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2]))
            orientation = fm.Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))
            colour = self._colour(label + 1 if label >= 0 else 7, 0.4)
            size = fm.Vector3(x=float(s[0]), y=float(s[1]), z=float(s[2]))
            metadata = [fm.KeyValuePair(key="id", value=str(int(oid)))]
            if name:
                metadata.append(fm.KeyValuePair(key="class", value=name))
            entities.append(
                fm.SceneEntity(
                    timestamp=when,
                    frame_id=self.world_frame,
                    id=str(int(oid)),
                    metadata=metadata,
                    spheres=[
                        fm.SpherePrimitive(
                            pose=fm.Pose(position=position, orientation=orientation),
                            size=size,
                            color=colour,
                        )
                    ],
                    texts=[
                        fm.TextPrimitive(
                            pose=fm.Pose(position=position),
                            billboard=True,
                            font_size=12.0,
                            scale_invariant=True,
                            color=fm.Color(r=1.0, g=1.0, b=1.0, a=1.0),
                            text=f"{int(oid)} {name}".rstrip(),
                        )
                    ],
                )
            )
        now = {int(i) for i in ids}
        deletions = [
            fm.SceneEntityDeletion(
                timestamp=when, type=fm.SceneEntityDeletionType.MatchingId, id=str(gone)
            )
            for gone in sorted(self._shown - now)
        ]
        self._shown = now
        return fm.SceneUpdate(deletions=deletions, entities=entities)

    def _image(self, when, image: np.ndarray):
        cv2 = require("cv2", "images", "the left image of a Foxglove view")
        ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        if not ok:
            raise OutputError(f"robot {self.robot}: the left image cannot be encoded as JPEG")
        return self._fm.CompressedImage(
            timestamp=when, frame_id=self.camera_frame, data=jpeg.tobytes(), format="jpeg"
        )

    def _calibration(self, when):
        camera = self.camera
        model, d = camera.distortion_model()
        width, height = camera.image_size

        def flat(matrix) -> list[float]:
            return [float(x) for x in np.asarray(matrix, float).ravel()]

        return self._fm.CameraCalibration(
            timestamp=when,
            frame_id=self.camera_frame,
            width=int(width),
            height=int(height),
            distortion_model=model,
            D=d,
            K=flat(camera.K),
            R=flat(camera.R),
            P=flat(camera.P),
        )

    def _boxes(self, when, boxes: Boxes, class_names: Mapping[int, str]):
        """Each box a closed outline (coloured by its tracked id, grey without one) and a text
        of its id and class at its top-left corner."""
        fm = self._fm
        xyxy = np.asarray(boxes.boxes, float).reshape(-1, 4)
        n = xyxy.shape[0]
        ids = np.full(n, -1, np.int64) if boxes.ids is None else np.asarray(boxes.ids)
        classes = np.full(n, -1, np.int64) if boxes.classes is None else boxes.classes
        outlines, texts = [], []
        grey = fm.Color(r=0.6, g=0.6, b=0.6, a=1.0)
        for (x0, y0, x1, y1), oid, label in zip(xyxy, ids, classes, strict=True):
            colour = grey if oid < 0 else self._colour(int(oid))
            corners = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
            outlines.append(
                fm.PointsAnnotation(
                    timestamp=when,
                    type=fm.PointsAnnotationType.LineLoop,
                    points=[fm.Point2(x=float(x), y=float(y)) for x, y in corners],
                    outline_color=colour,
                    thickness=2.0,
                )
            )
            name = class_names.get(int(label), str(int(label))) if label >= 0 else ""
            text = " ".join(t for t in (str(int(oid)) if oid >= 0 else "", name) if t)
            if text:
                texts.append(
                    fm.TextAnnotation(
                        timestamp=when,
                        position=fm.Point2(x=float(x0), y=float(max(y0 - 2.0, 0.0))),
                        text=text,
                        font_size=12.0,
                        text_color=colour,
                        background_color=fm.Color(r=0.0, g=0.0, b=0.0, a=0.6),
                    )
                )
        return fm.ImageAnnotations(timestamp=when, points=outlines, texts=texts)

    def close(self) -> None:
        """Stop the server and close the channels."""
        self._server.stop()
        for channel in self._channels.values():
            channel.close()
