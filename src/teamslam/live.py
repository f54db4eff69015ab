"""One robot fed by live topics (``teamslam agent --live``): frames made as messages arrive.

Messages reach :meth:`LiveRobot.feed` from a subscriber thread (thread-safe). Every odometry
message is kept; camera inputs — ``StereoObservations`` messages, or left/right images paired by
stamp (:class:`~teamslam.ros2.live.ApproximateTimeSync`, tolerance ``sync_tolerance_s``), with a
detector's ``Detection2DArray`` of the same stamp when ``detections`` is given — become
a frame once the odometry covers their stamp: the odometry pose at the frame's stamp as the
offline imports compute it (:func:`~teamslam.ros2.bags.import_bag` for observations,
:func:`~teamslam.ros2.image_bags.dataset_from_bag` for images), so a bag played live gives the
offline measurements. Frames wait in a bounded queue; when it is full the oldest unprocessed
frame is dropped (counted) and the next frame's odometry increment spans the gap. Without camera
input for ``camera_timeout_s`` of odometry stamps, odometry messages become frames of their own
(said once; said again when the camera returns). :meth:`LiveRobot.run` processes the frames in
the caller's thread: front-end, consensus (the team file's wait policy), filter, publication;
per frame the latency from the camera input's arrival to the pose's publication. The result is
:func:`~teamslam.runtime.agent_process.run_agent`'s one-robot result with a ``live`` summary.
"""

from __future__ import annotations

import bisect
import os
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from teamslam.datasets.model import Calibration
from teamslam.errors import EstimationError, InputError, OutputError
from teamslam.geometry import se3
from teamslam.msckf.agent import MsckfAgent, grown
from teamslam.msckf.consensus.transport import Transport
from teamslam.msckf.settings.values import MsckfConfig
from teamslam.msckf.team import Asynchronous, LockStep, RobotDriver
from teamslam.runtime.agent_process import (
    _atomic_json,
    _restore_lags,
    _save,
    _save_checkpoint,
)
from teamslam.runtime.team_file import TeamFile
from teamslam.textio import read_npz

__all__ = [
    "STAGES",
    "LiveInputs",
    "LiveRobot",
    "LiveSequence",
    "live_inputs",
    "live_settings",
    "run_live",
]

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
ODOMETRY = "nav_msgs/msg/Odometry"
OBSERVATIONS = "teamslam_msgs/msg/StereoObservations"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
DETECTIONS = "vision_msgs/msg/Detection2DArray"
#: the stages of a frame, as the real-time budget and the timings name them
STAGES = ("frontend", "consensus", "filter", "publish")


@dataclass(frozen=True)
class LiveInputs:
    """One robot's input topics and how they are paired.

    Attributes
    ----------
    odometry
        ``nav_msgs/msg/Odometry`` topic (every message kept).
    observations
        ``teamslam_msgs/msg/StereoObservations`` topic: already-made observations (no image
        front-end). Either this or ``left`` and ``right``.
    left, right
        Image topics of type ``image_type`` (``sensor_msgs/msg/Image`` or ``CompressedImage``).
    camera_info
        ``(left, right)`` ``sensor_msgs/msg/CameraInfo`` topics giving the rig (first message of
        each), unless a calibration is given.
    ground_truth
        ``geometry_msgs/msg/PoseStamped`` (or ``Odometry``) topic giving where the robot starts:
        its pose at the first frame (optional; read for the start only).
    detections
        With images: a ``vision_msgs/msg/Detection2DArray`` topic of a detector's boxes in the
        left images, each message stamped with its image's stamp; the robot names the objects
        it detects itself (tracking). A pair waits for the message of its stamp until one of a
        later stamp arrives or camera input ``camera_timeout_s`` later; without one it has no
        boxes (as the offline import).
    sync_tolerance_s
        Largest stamp difference of a left and a right image paired into one frame.
    queue
        Frames waiting for the filter at most; beyond, the oldest is dropped.
    camera_timeout_s
        Odometry seconds (by stamps) without camera input after which odometry messages become
        frames of their own.
    """

    odometry: str
    observations: str | None = None
    left: str | None = None
    right: str | None = None
    camera_info: tuple[str, str] | None = None
    image_type: str = IMAGE
    ground_truth: str | None = None
    detections: str | None = None
    sync_tolerance_s: float = 0.005
    queue: int = 8
    camera_timeout_s: float = 1.0

    def __post_init__(self) -> None:
        if (self.observations is None) == (self.left is None and self.right is None):
            raise InputError("live inputs: give an observations topic, or left and right images")
        if self.observations is None and (self.left is None or self.right is None):
            raise InputError("live inputs: images need both a left and a right topic")
        if self.detections is not None and self.observations is not None:
            raise InputError("live inputs: detections are boxes in images: they need images")
        if self.image_type not in (IMAGE, COMPRESSED):
            raise InputError(f"live inputs: images must be {IMAGE} or {COMPRESSED}")
        if not (np.isfinite(self.sync_tolerance_s) and self.sync_tolerance_s >= 0):
            raise InputError(f"--sync-tolerance must be seconds ≥ 0, got {self.sync_tolerance_s}")
        if self.queue < 1:
            raise InputError(f"--queue must be at least 1 frame, got {self.queue}")
        if not self.camera_timeout_s > 0:
            raise InputError(f"camera timeout must be > 0 s, got {self.camera_timeout_s}")

    @property
    def images(self) -> bool:
        """Whether the frames are images (else observations)."""
        return self.observations is None

    def topics(self) -> dict[str, str]:
        """``{topic: message type}`` to subscribe to."""
        out = {self.odometry: ODOMETRY}
        if self.images:
            out[self.left] = self.image_type
            out[self.right] = self.image_type
            for topic in self.camera_info or ():
                out[topic] = CAMERA_INFO
            if self.detections is not None:
                out[self.detections] = DETECTIONS
        else:
            out[self.observations] = OBSERVATIONS
        if self.ground_truth is not None:
            out[self.ground_truth] = POSE_STAMPED
        return out


class _Frames:
    """A growing robot's per-frame observations of one kind; the current frame is kept (the
    filter reads frame ``t`` at step ``t`` only)."""

    def __init__(self) -> None:
        self._frames: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.ids = np.zeros(0, np.int64)  # no observation at the start (read once, by the agent)

    def add(self, t: int, ids: np.ndarray, z: np.ndarray) -> None:
        self._frames[t] = (np.asarray(ids, np.int64), np.asarray(z, float).reshape(-1, 4))
        for old in [k for k in self._frames if k < t - 1]:
            del self._frames[old]

    def frame(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        return self._frames[t]


class _Detections:
    """A growing robot's per-frame detections without ids: what the tracker reads of a
    :class:`~teamslam.datasets.model.FrameDetections`; the current frame is kept."""

    def __init__(self) -> None:
        self._frames: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}
        self._dimension = 0

    def add(
        self,
        t: int,
        z: np.ndarray,
        classes: np.ndarray,
        appearance: np.ndarray,
        sizes: np.ndarray,
    ) -> None:
        looks = np.asarray(appearance, np.float32)
        if looks.size:
            self._dimension = looks.shape[1]
        else:  # no box (or an odometry frame): no descriptor, of the dimension seen
            looks = np.zeros((0, self._dimension), np.float32)
        self._frames[t] = (
            np.asarray(z, float).reshape(-1, 4),
            np.asarray(classes, np.int64),
            looks,
            np.asarray(sizes, float).reshape(-1, 2),
        )
        for old in [k for k in self._frames if k < t - 1]:
            del self._frames[old]

    def frame(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        z, classes, _, _ = self._frames[t]
        return z, classes

    def appearance_of(self, t: int) -> np.ndarray:
        return self._frames[t][2]

    def sizes_of(self, t: int) -> np.ndarray:
        """``(D_t, 2)`` the box sizes of frame ``t`` (the box-centre noise grows with them)."""
        return self._frames[t][3]

    @property
    def sizes(self) -> np.ndarray:
        """``(D, 2)`` the box sizes of the frames kept, in frame order: live boxes always carry
        their size (never ``None``, as a dataset's detections without sizes would be)."""
        kept = [self._frames[t][3] for t in sorted(self._frames)]
        return np.concatenate(kept) if kept else np.zeros((0, 2))

    @property
    def classes(self) -> np.ndarray:
        """``(D,)`` the class labels of the frames kept, in frame order: live boxes always carry
        one (the detection topic's class table; never ``None``, as a dataset's detections
        without classes would be)."""
        kept = [self._frames[t][1] for t in sorted(self._frames)]
        return np.concatenate(kept) if kept else np.zeros(0, np.int64)


class LiveSequence:
    """A robot's sequence while it is recorded: what :class:`~teamslam.msckf.agent.MsckfAgent`
    reads of a :class:`~teamslam.datasets.RobotSequence`, one frame appended at a time.

    ``T_world_body`` holds the start pose only (there is no truth live); the odometry
    increments are kept whole (the filter's odometry health reads those of its window). With
    ``detections``, frames carry a detector's boxes without ids (the filter tracks them).
    """

    object_classes = None
    object_appearance = None

    def __init__(self, T_world_start: np.ndarray, detections: bool = False) -> None:
        self.T_world_body = np.asarray(T_world_start, float).reshape(1, 4, 4)
        self._odometry = np.zeros((64, 4, 4))
        self._spans = np.ones(64)
        self.stamps_ns = np.zeros(64, np.int64)
        self.features = _Frames()
        self.objects = _Frames()
        self.detections = _Detections() if detections else None
        self._frames = 0

    @property
    def frames(self) -> int:
        """Frames appended so far."""
        return self._frames

    @property
    def odometry(self) -> np.ndarray:
        """``(frames - 1, 4, 4)`` odometry increments (a view)."""
        return self._odometry[: max(self._frames - 1, 0)]

    @property
    def odometry_spans(self) -> np.ndarray:
        """``(frames - 1,)`` frames each increment spans (1; more after frames were dropped):
        the filter gives it that many steps' noise."""
        return self._spans[: max(self._frames - 1, 0)]

    def append(
        self,
        stamp_ns: int,
        increment: np.ndarray | None,
        features: tuple[np.ndarray, np.ndarray],
        objects: tuple[np.ndarray, np.ndarray],
        span: int = 1,
        detections: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None,
    ) -> int:
        """Append a frame (``increment`` from the previous one, spanning ``span`` frames made;
        ``None`` for the first; ``detections``: its boxes' ``(z, classes, appearance, sizes)``);
        its index."""
        t = self._frames
        if (t == 0) != (increment is None):
            raise ValueError("the first frame has no odometry increment, every other one has")
        if t >= self.stamps_ns.shape[0]:
            self.stamps_ns = grown(self.stamps_ns, t + 1)
        if t > 0:
            if t - 1 >= self._odometry.shape[0]:
                self._odometry = grown(self._odometry, t)
                self._spans = np.concatenate(
                    [self._spans, np.ones(self._odometry.shape[0] - self._spans.size)]
                )
            self._odometry[t - 1] = increment
            self._spans[t - 1] = span
        self.stamps_ns[t] = stamp_ns
        self.features.add(t, *features)
        self.objects.add(t, *objects)
        if self.detections is not None:
            self.detections.add(t, *detections)
        self._frames = t + 1
        return t

    def appearance_of_objects(self, ids: np.ndarray) -> None:
        """No appearance descriptors are given live."""
        return None

    def step_interval_ns(self, t: int, window: int = 50) -> int:
        """How long a step of this robot lasts up to frame ``t`` (``t ≥ 1``), in stamps: the
        mean interval between its consecutive frames over the last ``window`` — the input's
        frame period times the frames it takes per step (more when it drops frames)."""
        if not 1 <= t < self._frames:
            raise ValueError(f"no step interval at frame {t} of {self._frames}")
        start = max(t - window, 0)
        return max((int(self.stamps_ns[t]) - int(self.stamps_ns[start])) // (t - start), 1)

    def snapshot(self) -> dict[str, np.ndarray]:
        """Start pose, increments and stamps, for a checkpoint."""
        return {
            "live_start": self.T_world_body[0],
            "live_odometry": self.odometry.copy(),
            "live_spans": self.odometry_spans.copy(),
            "live_stamps": self.stamps_ns[: self._frames].copy(),
        }

    @classmethod
    def restore(cls, snapshot: dict[str, np.ndarray], detections: bool = False) -> LiveSequence:
        """The sequence of a :meth:`snapshot` (frames without observations: their frames are
        past)."""
        sequence = cls(snapshot["live_start"], detections)
        stamps = np.asarray(snapshot["live_stamps"], np.int64)
        odometry = np.asarray(snapshot["live_odometry"], float).reshape(-1, 4, 4)
        if odometry.shape[0] != max(stamps.size - 1, 0):
            raise InputError(f"checkpoint: {odometry.shape[0]} increments for {stamps.size} frames")
        sequence._odometry = grown(odometry, max(64, stamps.size))
        spans = np.asarray(snapshot["live_spans"], float).reshape(-1)
        sequence._spans = np.ones(sequence._odometry.shape[0])
        sequence._spans[: spans.size] = spans
        sequence.stamps_ns = grown(stamps, max(64, stamps.size))
        sequence._frames = int(stamps.size)
        return sequence


class _PoseTrack:
    """A pose topic's messages by stamp, and its pose at a stamp as the offline imports compute
    it: for images (:func:`~teamslam.ros2.image_bags.dataset_from_bag`) interpolated on the pair
    Slerp over every message picks; for observations
    (:func:`~teamslam.ros2.bags.import_bag`) the message of the stamp (odometry: else
    interpolated; a start pose: else the nearest)."""

    def __init__(self, topic: str, images: bool, nearest: bool = False) -> None:
        self.topic = topic
        self.images = images
        self.nearest = nearest
        self.stamps: list[int] = []
        self.exact: list[np.ndarray] = []  # as import_bag reads a pose
        self.poses: list[np.ndarray] = []  # as dataset_from_bag reads it

    def add(self, stamp: int, msg) -> bool:
        """Keep a message; ``False`` (nothing kept) when its stamp is not after the last."""
        from teamslam.ros2.image_bags import _pose
        from teamslam.ros2.messages import pose_matrix

        if self.stamps and stamp <= self.stamps[-1]:
            return False
        try:
            pose = msg.pose.pose if hasattr(msg, "child_frame_id") else msg.pose
            exact = pose_matrix(pose)
            interpolated = _pose(msg)
        except (AttributeError, ValueError) as exc:
            raise InputError(f"{self.topic} at stamp {stamp} ns: not a pose ({exc})") from None
        if not (np.all(np.isfinite(exact)) and np.all(np.isfinite(interpolated))):
            raise InputError(f"{self.topic} at stamp {stamp} ns: non-finite pose")
        self.stamps.append(stamp)
        self.exact.append(exact)
        self.poses.append(interpolated)
        return True

    def message_at(self, stamp: int) -> np.ndarray:
        """The pose of the message stamped ``stamp`` (one there is)."""
        j = bisect.bisect_left(self.stamps, stamp)
        return (self.poses if self.images else self.exact)[j]

    def at(self, stamp: int, ended: bool) -> np.ndarray | None:
        """The pose at ``stamp``; ``None`` until the messages cover it."""
        from teamslam.ros2.image_bags import _interpolate

        stamps = self.stamps
        if not stamps or stamp > stamps[-1] or stamp < stamps[0]:
            return None
        j = bisect.bisect_right(stamps, stamp) - 1
        if not self.images:
            if stamps[j] == stamp:
                return self.exact[j]  # import_bag: the message of the frame's stamp
            if self.nearest:
                after = stamps[j + 1] - stamp
                return self.exact[j + 1 if after < stamp - stamps[j] else j]
            keys, a = self.exact, j
        else:
            # the pair Slerp over every message picks: the one ending at or after the stamp
            # (the first pair at the first stamp, which then needs a second message)
            a = max(bisect.bisect_left(stamps, stamp) - 1, 0)
            if len(stamps) < 2 and not ended:
                return None
            keys = self.poses
        window = slice(a, a + 2)
        t = np.array(stamps[window], np.float64) / 1e9
        q = np.array([stamp], np.int64) / 1e9
        return _interpolate(t, np.stack(keys[window]), q, self.topic)[0]

    def forget_before(self, stamp: int) -> None:
        """Drop the messages no pose at ``stamp`` or later needs (kept in blocks)."""
        keep = max(bisect.bisect_left(self.stamps, stamp) - 1, 0)
        if keep > 64:
            del self.stamps[:keep], self.poses[:keep], self.exact[:keep]


@dataclass
class _Frame:
    """A frame made from the inputs, waiting for the filter."""

    stamp_ns: int
    T_odom: np.ndarray  # the odometry's pose at the stamp
    kind: str  # "observations", "images" or "odometry"
    payload: object
    arrived_ns: int  # monotonic arrival of the input that completed it
    number: int  # frames made before it
    start: np.ndarray | None = None  # the ground truth's pose at it, until the filter starts


@dataclass
class _Counts:
    """What the inputs did: messages, refusals, drops per stage."""

    messages: dict[str, int] = field(default_factory=dict)
    dropped: dict[str, int] = field(
        default_factory=lambda: {
            "sync": 0,
            "queue": 0,
            "frontend": 0,
            "no_odometry": 0,
            "camera_gap": 0,
        }
    )
    refused_stamps: dict[str, int] = field(default_factory=dict)
    malformed: dict[str, int] = field(default_factory=dict)
    odometry_frames: int = 0
    camera_gaps: int = 0
    without_detections: int = 0


class LiveRobot:
    """One robot's filter on live inputs.

    Parameters
    ----------
    team
        The team file (result's team name, consensus wait policy, checkpoints).
    robot
        This robot's id.
    inputs
        Its topics (:class:`LiveInputs`).
    config
        Filter settings, or a function of the :class:`~teamslam.datasets.Calibration` giving
        them (called at the first frame: a rig from ``camera_info`` is known then).
    out
        Output directory (``robot_<id>/`` is written inside it).
    calibration
        The stereo calibration of observations.
    rig
        The :class:`~teamslam.frontend.camera.StereoRig` of images (default: from the
        ``camera_info`` topics).
    transport
        Its consensus endpoint (``None``: a robot that talks to nobody).
    publisher
        Optional; gets ``publish(t, poses[: t + 1], state)`` after every frame (e.g. a
        :class:`~teamslam.ros2.rmw_zenoh.Ros2Publisher`).
    view
        Optional :class:`~teamslam.viz.foxglove.FoxgloveView`, fed after every frame (after
        the publisher, so outside the frame's latency): the estimates, and on image robots the
        left image with the detector's boxes and their tracked ids.
    lost_after
        Silent frames after which a neighbour is reported lost.
    budget_ms
        Real-time budget per stage (``None``: none): the first overrun of each stage is said.
    say
        Where one-line notices go (default: standard error).
    """

    def __init__(
        self,
        team: TeamFile,
        robot: int,
        inputs: LiveInputs,
        config: MsckfConfig | Callable[[Calibration], MsckfConfig],
        out: str | Path,
        calibration: Calibration | None = None,
        rig=None,
        transport: Transport | None = None,
        publisher=None,
        view=None,
        lost_after: int = 3,
        budget_ms: float | None = None,
        say: Callable[[str], None] | None = None,
    ) -> None:
        self.team = team
        self.robot = robot
        self.inputs = inputs
        self.config = config
        self.out = Path(out) / f"robot_{robot}"
        self.calibration = calibration
        self.rig = rig
        self.transport = transport
        self.publisher = publisher
        self.view = view
        self._shown: tuple | None = None  # the frame's left image and boxes, for the view
        self.lost_after = lost_after
        self.budget_ms = budget_ms
        self.say = say or (lambda text: print(text, file=sys.stderr, flush=True))
        self.neighbours = team.robots[robot].neighbours if transport is not None else []
        self.counts = _Counts()
        self._connected = False
        self._cond = threading.Condition()
        self._queue: deque[_Frame] = deque()
        self._ended = False
        self._last_message_ns = time.monotonic_ns()
        # odometry: every message, by stamp
        self._odom = _PoseTrack(inputs.odometry, inputs.images)
        self._truth = (
            None
            if inputs.ground_truth is None
            else _PoseTrack(inputs.ground_truth, inputs.images, nearest=True)
        )
        self._started = False  # whether the filter has its first frame
        self._made = 0  # frames made
        self._pending: list[tuple[int, str, object, int]] = []  # camera frames awaiting odometry
        self._last_frame_stamp = -1
        self._last_camera_stamp: int | None = None
        self._camera_periods: deque[int] = deque(maxlen=20)
        self._camera_gap = False
        self._info: dict[str, object] = {}
        self._boxes: dict[int, object] = {}  # detection messages by stamp, awaiting their pair
        self._last_box_stamp: int | None = None
        self._classes = None  # the detection topic's class labels (LiveClassTable)
        self._sync = None
        self._warned: set[str] = set()
        # the worker's side
        self.sequence: LiveSequence | None = None
        self.driver: RobotDriver | None = None
        self.frontend = None
        self._first_feature_id = 0
        self._last_T_odom: np.ndarray | None = None
        self._last_number: int | None = None  # the last frame processed, as made
        self.latency_ns: list[int] = []
        self.step_seconds: list[float] = []
        self.stage_seconds = {s: 0.0 for s in STAGES}
        self.overruns = dict.fromkeys(STAGES, 0)
        # the process's CPU time (every thread) when the first frame began and the last ended
        self._cpu_span: list[float] = []

    # ------------------------------------------------------------------ inputs (any thread)
    def feed(self, received) -> None:
        """Take one message (a :class:`~teamslam.ros2.live.Received`); never raises for bad
        input: it is refused, counted and named once."""
        with self._cond:
            self._last_message_ns = time.monotonic_ns()
            topic = received.topic
            self.counts.messages[topic] = self.counts.messages.get(topic, 0) + 1
            try:
                if topic == self.inputs.odometry:
                    self._odometry(received)
                elif topic == self.inputs.observations:
                    self._camera(received.stamp_ns, "observations", received, received.received_ns)
                elif self.inputs.images and topic in (self.inputs.left, self.inputs.right):
                    self._image(received)
                elif topic == self.inputs.ground_truth:
                    if not self._started and not self._truth.add(
                        int(received.stamp_ns), received.message
                    ):
                        self._refuse_stamp(topic, received.stamp_ns, self._truth.stamps[-1])
                elif topic == self.inputs.detections:
                    self._detection_message(received)
                elif self.inputs.camera_info and topic in self.inputs.camera_info:
                    self._info.setdefault(topic, received.message)
                self._release()
            except InputError as exc:
                self._malformed(topic, str(exc))
            self._cond.notify_all()

    def finish(self) -> None:
        """End of input: the frames the odometry covers go to the queue, the others are
        dropped (counted as ``no_odometry``)."""
        with self._cond:
            if not self._ended:
                self._release(end=True)
                self.counts.dropped["no_odometry"] += len(self._pending)
                self._pending.clear()
                self._ended = True
            self._cond.notify_all()

    def _malformed(self, topic: str, text: str) -> None:
        self.counts.malformed[topic] = self.counts.malformed.get(topic, 0) + 1
        self._once(f"malformed {topic}", f"robot {self.robot}: {text}; further ones only counted")

    def _once(self, key: str, text: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            self.say(text)

    def _refuse_stamp(self, topic: str, stamp: int, last: int) -> None:
        self.counts.refused_stamps[topic] = self.counts.refused_stamps.get(topic, 0) + 1
        self.say(
            f"robot {self.robot}: {topic} stamp {stamp} ns is not after {last} ns "
            "(stamp jumped back): refused"
        )

    def _odometry(self, received) -> None:
        stamp, msg = int(received.stamp_ns), received.message
        if not self._odom.add(stamp, msg):
            self._refuse_stamp(received.topic, stamp, self._odom.stamps[-1])
            return
        # no camera input for a while: the odometry makes the frames
        last = self._last_camera_stamp
        if last is not None and stamp - last > self.inputs.camera_timeout_s * 1e9:
            if not self._camera_gap:
                self._camera_gap = True
                self.counts.camera_gaps += 1
                self.say(
                    f"robot {self.robot}: no camera input since stamp {last} ns "
                    f"(over {self.inputs.camera_timeout_s:g} s of odometry): continuing on "
                    "odometry"
                )
            period = int(np.median(self._camera_periods)) if self._camera_periods else 0
            if not self._pending and stamp - self._last_frame_stamp >= period:
                self._pending.append((stamp, "odometry", None, received.received_ns))

    def _detection_message(self, received) -> None:
        stamp = int(received.stamp_ns)
        if self._last_box_stamp is not None and stamp <= self._last_box_stamp:
            self._refuse_stamp(received.topic, stamp, self._last_box_stamp)
            return
        self._last_box_stamp = stamp
        if stamp > self._last_frame_stamp:  # a frame still to come may be stamped so
            self._boxes[stamp] = received.message

    def _boxes_at(self, stamp: int) -> tuple[bool, object]:
        """``(ready, message)``: the detection message of a pair's stamp (``None``: it has
        none — one of a later stamp came, its camera input is ``camera_timeout_s`` old, or the
        input ended); ``ready`` is ``False`` while it may still come."""
        msg = self._boxes.pop(stamp, None)
        for old in [s for s in self._boxes if s < stamp]:
            del self._boxes[old]
        if msg is not None:
            return True, msg
        later = self._last_box_stamp is not None and self._last_box_stamp > stamp
        newest = self._last_camera_stamp if self._last_camera_stamp is not None else stamp
        late = newest - stamp > self.inputs.camera_timeout_s * 1e9
        if later or late or self._ended:
            self.counts.without_detections += 1
            return True, None
        return False, None

    def _image(self, received) -> None:
        if self._sync is None:
            from teamslam.ros2.live import ApproximateTimeSync

            self._sync = ApproximateTimeSync(
                [self.inputs.left, self.inputs.right],
                round(self.inputs.sync_tolerance_s * 1e9),
                queue_size=4 * self.inputs.queue,
            )
        for pair in self._sync.add(received):
            left, right = pair[self.inputs.left], pair[self.inputs.right]
            arrived = max(left.received_ns, right.received_ns)
            self._camera(left.stamp_ns, "images", (left, right), arrived)
        dropped = self._sync.dropped
        self.counts.dropped["sync"] = int(
            sum(dropped.values()) if isinstance(dropped, dict) else dropped
        )

    def _camera(self, stamp: int, kind: str, payload, arrived_ns: int) -> None:
        stamp = int(stamp)
        last_camera = self._last_camera_stamp
        if self._camera_gap and (last_camera is None or stamp > last_camera):
            self._camera_gap = False
            self.say(f"robot {self.robot}: camera input again at stamp {stamp} ns")
        newest = max([self._last_frame_stamp] + [p[0] for p in self._pending])
        if stamp <= newest:
            if last_camera is not None and stamp > last_camera:
                # the odometry made frames while the camera was silent: this input comes
                # after one of them (counted, not a stamp that went back); the camera is back
                self.counts.dropped["camera_gap"] += 1
                self._last_camera_stamp = stamp
                return
            topic = self.inputs.observations or self.inputs.left
            self._refuse_stamp(topic, stamp, newest)
            return
        if last_camera is not None:
            self._camera_periods.append(stamp - last_camera)
        self._last_camera_stamp = stamp
        self._pending.append((stamp, kind, payload, arrived_ns))

    def _release(self, end: bool = False) -> None:
        """Move the pending frames the odometry covers to the queue, in stamp order."""
        if end:
            self._ended = True
        while self._pending:
            stamp, kind, payload, arrived = self._pending[0]
            if kind == "odometry":
                pose = self._odom.message_at(stamp)
            else:
                pose = self._odom.at(stamp, self._ended)
                if pose is None:
                    if (self._odom.stamps and stamp < self._odom.stamps[0]) or self._ended:
                        self._pending.pop(0)  # outside the odometry: never covered
                        self.counts.dropped["no_odometry"] += 1
                        continue
                    break
            start = None
            if self._truth is not None and not self._started:
                # until the filter starts, each frame may be the first: its start pose
                start = self._truth.at(stamp, self._ended)
                if start is None:
                    if self._ended or (self._truth.stamps and stamp < self._truth.stamps[0]):
                        self._pending.pop(0)  # no start pose for it: the next frame starts
                        self.counts.dropped["no_odometry"] += 1
                        continue
                    break
            if kind == "images" and self.inputs.detections is not None:
                ready, boxes = self._boxes_at(stamp)
                if not ready:
                    break
                payload = (*payload, boxes)
            self._pending.pop(0)
            if kind == "odometry":
                self.counts.odometry_frames += 1
            self._last_frame_stamp = stamp
            if len(self._queue) >= self.inputs.queue:
                self._queue.popleft()  # the oldest unprocessed frame
                self.counts.dropped["queue"] += 1
            self._queue.append(_Frame(stamp, pose, kind, payload, arrived, self._made, start))
            self._made += 1
        # poses older than every frame still to come are not needed again
        self._odom.forget_before(self._last_frame_stamp)

    # ------------------------------------------------------------------ the worker
    def _observations(self, frame: _Frame, where: str):
        """``(features, objects, detections)`` of a frame: its message's, or the front-end's on
        its images; ``detections`` (with a detection topic): its boxes' ``(z, classes,
        appearance, sizes)``, else ``None``."""
        from teamslam.ros2 import messages as m

        self._shown = None  # this frame's image, once read
        empty = (np.zeros(0, np.int64), np.zeros((0, 4)))
        no_boxes = None
        if self.inputs.detections is not None:
            no_boxes = (
                np.zeros((0, 4)),
                np.zeros(0, np.int64),
                np.zeros((0, 0), np.float32),
                np.zeros((0, 2)),
            )
        if frame.kind == "odometry":
            return empty, empty, no_boxes
        if frame.kind == "observations":
            msg = frame.payload.message
            try:
                ids = np.asarray(msg.ids, np.int64)
                kinds = np.asarray(msg.kinds)
                z = np.column_stack(
                    [np.asarray(getattr(msg, c), float) for c in m.OBSERVATION_COLUMNS]
                ).reshape(-1, 4)
            except (AttributeError, ValueError) as exc:
                raise InputError(f"{where}: not StereoObservations ({exc})") from None
            if kinds.size != ids.size or z.shape[0] != ids.size:
                raise InputError(f"{where}: fields of different lengths")
            if np.any((kinds != m.KIND_FEATURE) & (kinds != m.KIND_OBJECT)):
                raise InputError(f"{where}: unknown observation kind {set(kinds.tolist())}")
            features, objects = (
                (ids[kinds == kind], z[kinds == kind]) for kind in (m.KIND_FEATURE, m.KIND_OBJECT)
            )
            return features, objects, None
        from teamslam.ros2.image_bags import _check_size, _decode

        left, right, *boxes = frame.payload
        rig = self._ensure_rig()
        images = [
            _check_size(_decode(r.message, r.topic, r.stamp_ns), rig, r.topic, r.stamp_ns)
            for r in (left, right)
        ]
        if self.view is not None:
            self._shown = (images[0], None)
        motion = self._camera_motion(frame, rig)
        if self.inputs.detections is None:
            measured = self.frontend.process(*images, where=where, motion=motion)
            return (
                (measured.feature_ids, measured.features),
                (measured.object_ids, measured.objects),
                None,
            )
        # a detector's boxes, measured and described as the offline import does it
        from teamslam.datasets.images import _described

        given = self._given_boxes(boxes[0], frame.stamp_ns, rig)
        if self.view is not None:
            self._shown = (images[0], given)
        measured = self.frontend.process(*images, where=where, detections=given, motion=motion)
        described, looks = _described(measured.boxes, given, images[0], None)
        return (
            (measured.feature_ids, measured.features),
            empty,
            (described.z, described.classes, looks, described.sizes),
        )

    def _camera_motion(self, frame: _Frame, rig) -> np.ndarray | None:
        """After frames were dropped (the front-end did not see them): the rectified left
        camera's motion since the last frame processed by the odometry (``T_prev_cur``), so
        that the front-end looks for its tracks where they went; ``None`` after a frame it saw
        (the tracks are looked for where they were, as offline)."""
        if self._last_number is None or frame.number - self._last_number <= 1:
            return None
        T_cam_body = rig.T_rect_body
        increment = self._increment(frame.T_odom)
        return T_cam_body @ increment @ se3.inverse(T_cam_body[None])[0]

    def _given_boxes(self, msg, stamp: int, rig):
        """The :class:`~teamslam.frontend.detections.ImageDetections` of a pair's detection
        message (none: no box)."""
        from teamslam.frontend.detections import ImageDetections
        from teamslam.ros2.detection_bags import LiveClassTable, message_detections

        if msg is None:
            return ImageDetections(np.zeros((0, 4)), np.zeros(0, np.int64), np.zeros(0))
        if self._classes is None:
            self._classes = LiveClassTable()
        where = f"{self.inputs.detections}, message at {stamp} ns"
        return message_detections(msg, where, rig.image_size, self._classes)

    def _ensure_rig(self):
        """The stereo rig and front-end (from the calibration, else the camera_info topics)."""
        if self.frontend is not None:
            return self.rig
        from teamslam.frontend.camera import rig_from_camera_info
        from teamslam.frontend.config import FrontendConfig
        from teamslam.frontend.pipeline import StereoFrontend

        if self.rig is not None:
            rig = self.rig
        else:
            with self._cond:
                infos = [self._info.get(t) for t in self.inputs.camera_info or ()]
            if len(infos) != 2 or any(i is None for i in infos):
                raise InputError(
                    f"robot {self.robot}: no camera file and no camera_info on "
                    f"{self.inputs.camera_info}"
                )
            rig = rig_from_camera_info(*infos)
        self.calibration = Calibration(rig.camera, rig.T_rect_body, rig.image_size)
        self.rig = rig
        self.frontend = StereoFrontend(rig, FrontendConfig(), first_id=self._first_feature_id)
        return rig

    def _start(self, frame: _Frame) -> None:
        """The filter, at the first frame: it starts where the offline imports start it (the
        ground-truth topic's pose at the frame when one is given; else the odometry's pose for
        observations, the identity for images)."""
        if self.inputs.images:
            self._ensure_rig()
        if self.calibration is None:
            raise InputError(f"robot {self.robot}: observations need a camera calibration")
        with self._cond:
            self._started = True
        if frame.start is not None:
            start = frame.start
        else:
            start = np.eye(4) if self.inputs.images else frame.T_odom
        self.sequence = LiveSequence(start, detections=self.inputs.detections is not None)
        self._make_driver()

    def _make_driver(self) -> None:
        if callable(self.config):  # settings that scale with the rig, known now
            self.config = self.config(self.calibration)
        agent = MsckfAgent(self.robot, self.calibration, self.sequence, self.config)
        # asynchronous live robots drop frames: their steps are not comparable, their
        # messages are aged by the stamps of their frames, up to an age learned per neighbour
        wait = (
            LockStep(self.team.timeout_s)
            if self.team.sync == "lockstep"
            else Asynchronous(
                self.team.max_age_steps,
                by_stamp=True,
                max_age_s=self.team.max_age_s,
                lag_quantile=self.team.max_age_quantile,
            )
        )
        self.driver = RobotDriver(
            agent,
            self.transport,
            self.neighbours,
            wait,
            self.lost_after,
            consensus=bool(self.neighbours),
        )

    def _increment(self, T_odom: np.ndarray) -> np.ndarray:
        if self.inputs.images:  # dataset_from_bag's
            return (se3.inverse(self._last_T_odom[None]) @ T_odom[None])[0]
        return (np.linalg.inv(self._last_T_odom[None]) @ T_odom[None])[0]  # import_bag's

    def _budget(self, stage: str, seconds: float, t: int) -> None:
        self.stage_seconds[stage] += seconds
        if self.budget_ms is not None and seconds * 1e3 > self.budget_ms:
            self.overruns[stage] += 1
            self._once(
                f"budget {stage}",
                f"robot {self.robot}: {stage} took {seconds * 1e3:.1f} ms at frame {t}, over "
                f"the real-time budget of {self.budget_ms:g} ms (further overruns counted)",
            )

    def process_queued(self) -> bool:
        """Process the oldest queued frame without waiting, for a caller that schedules robots
        itself (e.g. several in one thread); whether there was one and it entered the filter.
        :meth:`run` is the robot's own loop."""
        with self._cond:
            if not self._queue:
                return False
            frame = self._queue.popleft()
        return self._process(frame)

    def _process(self, frame: _Frame) -> bool:
        """Run one frame; whether it entered the filter."""
        t = 0 if self.sequence is None else self.sequence.frames
        where = f"robot {self.robot}, frame at stamp {frame.stamp_ns} ns"
        if not self._cpu_span:
            self._cpu_span.append(time.process_time())
        begin = time.perf_counter()
        try:
            features, objects, detections = self._observations(frame, where)
        except InputError as exc:
            self.counts.dropped["frontend"] += 1
            self._once("frontend", f"{exc}: frame dropped; further ones only counted")
            return False
        self._budget("frontend", time.perf_counter() - begin, t)
        if self.sequence is None:
            self._start(frame)
        increment = None if t == 0 else self._increment(frame.T_odom)
        if self._last_number is not None:
            span = frame.number - self._last_number
        elif t > 0:  # resumed: the frames that went by while the robot was down, by stamps
            stamps = self.sequence.stamps_ns[:t]
            period = np.median(np.diff(stamps)) if t > 1 else frame.stamp_ns - stamps[-1]
            span = max(1, round((frame.stamp_ns - stamps[-1]) / period))
        else:
            span = 1
        self.sequence.append(frame.stamp_ns, increment, features, objects, span, detections)
        self._last_T_odom = frame.T_odom
        self._last_number = frame.number
        driver = self.driver
        step_begin = time.perf_counter()
        if driver.exchanges(t):
            for iteration in range(driver.iterations):
                driver.requests(t, iteration)
                driver.answer(t, iteration)
                driver.average(t, iteration)
        after_consensus = time.perf_counter()
        self._budget("consensus", after_consensus - step_begin, t)
        driver.step(t)
        driver.record(t)
        after_filter = time.perf_counter()
        self._budget("filter", after_filter - after_consensus, t)
        if self.publisher is not None:
            self._publish(t)
        self.latency_ns.append(time.monotonic_ns() - frame.arrived_ns)
        if self.view is not None:
            self._show(t)
        self._budget("publish", time.perf_counter() - after_filter, t)
        self.step_seconds.append(time.perf_counter() - step_begin)
        self._cpu_span[1:] = [time.process_time()]
        return True

    def _publish(self, t: int) -> None:
        publisher = self.publisher
        poses, state = self.driver.poses[: t + 1], self.driver.agent.state
        if not getattr(publisher, "growing", False):  # e.g. a recorder
            publisher.publish(t, poses, state)
            return
        stamps = self.sequence.stamps_ns
        for k in range(publisher.stamps_ns.size, t):  # resumed: the frames done before
            publisher.stamp(k, int(stamps[k]))
        publisher.publish(t, poses, state, stamp_ns=int(stamps[t]))

    def _show(self, t: int) -> None:
        """Feed the view frame ``t``: the estimates, the latency, and the left image of an
        image frame with the detector's boxes and the ids the tracker gave them."""
        from teamslam.viz.foxglove import Boxes

        agent = self.driver.agent
        image, given = self._shown if self._shown is not None else (None, None)
        self._shown = None
        boxes = None
        if given is not None:
            ids = agent.detection_ids
            if ids is None or len(ids) != len(given.boxes):  # not named this frame
                ids = None
            boxes = Boxes(given.boxes, ids, given.classes)
        if self.view.T_cam_body is None and self.rig is not None:
            self.view.T_cam_body = self.rig.T_cam_body
            self._view_camera()
        names = None
        if self._classes is not None:
            names = {label: name for name, label in self._classes.table.items()}
        tracker = agent.tracker
        self.view.publish(
            t,
            self.driver.poses[: t + 1],
            agent.state,
            stamp_ns=int(self.sequence.stamps_ns[t]),
            image=image,
            boxes=boxes,
            labels_of=None if tracker is None else tracker.labels_of,
            class_names=names,
            latency_ms=self.latency_ns[-1] / 1e6,
        )

    def _view_camera(self) -> None:
        """Give the view the left camera's calibration (said once if Foxglove has no model
        for its distortion; the image is still shown)."""
        from teamslam.viz.foxglove import CameraModel

        rig = self.rig
        try:
            self.view.camera = CameraModel(
                rig.image_size, rig.K_left, rig.distortion_left, rig.R_rect_left, rig.P_rect_left
            )
        except InputError as exc:
            self._once("view camera", f"robot {self.robot}: Foxglove view: {exc}; no calibration")

    def _checkpoint(self, t: int) -> None:
        extra = self.sequence.snapshot()
        extra["live_T_odom"] = self._last_T_odom
        extra["live_frontend_next_id"] = np.array(
            self.frontend.next_id if self.frontend is not None else 0, np.int64
        )
        if self.frontend is not None:  # its tracks: a resumed robot continues them exactly
            state = self.frontend.state_dict()
            extra.update({f"live_frontend_{k}": v for k, v in state.items()})
        if self._classes is not None:  # the detection topic's labels, named in order seen
            extra["live_class_names"] = self._classes.state_dict()["names"]
        if self.inputs.images and self.frontend is not None:
            from teamslam.ros2 import messages as m

            with self._cond:
                infos = [self._info.get(x) for x in self.inputs.camera_info or ()]
            if all(i is not None for i in infos) and len(infos) == 2:
                for side, info in zip(("left", "right"), infos, strict=True):
                    raw = m.serialize(info, CAMERA_INFO)
                    extra[f"live_camera_info_{side}"] = np.frombuffer(raw, np.uint8)
        _save_checkpoint(self.out, self.driver, t, extra)

    def resume(self) -> int:
        """Continue from the last checkpoint in the output directory, if any; the frames it
        holds (0 without one). Frames that arrived while the robot was down are not replayed:
        the next frame's odometry increment spans them."""
        self._mkdir()
        path = self.out / "checkpoint.npz"
        if not path.exists():
            return 0
        snapshot = read_npz(path)
        if "live_start" not in snapshot:
            raise InputError(f"{path}: not the checkpoint of a live robot")
        if self.inputs.images and self.rig is None:
            from teamslam.ros2 import messages as m

            for side, topic in zip(("left", "right"), self.inputs.camera_info or (), strict=True):
                key = f"live_camera_info_{side}"
                if key in snapshot:
                    raw = snapshot[key].tobytes()
                    self._info[topic] = m.typestore().deserialize_cdr(raw, CAMERA_INFO)
        self._first_feature_id = int(snapshot["live_frontend_next_id"])
        if self.inputs.images:
            self._ensure_rig()
            prefix = "live_frontend_"
            state = {k[len(prefix) :]: v for k, v in snapshot.items() if k.startswith(prefix)}
            if "last_ids" in state:  # the front-end's tracks (older checkpoints: none)
                try:
                    self.frontend.load_state_dict(state)
                except ValueError as exc:
                    raise InputError(f"{path}: {exc}") from None
        if "live_class_names" in snapshot:
            from teamslam.ros2.detection_bags import LiveClassTable

            try:
                self._classes = LiveClassTable.from_state({"names": snapshot["live_class_names"]})
            except InputError as exc:
                raise InputError(f"{path}: {exc}") from None
        if self.calibration is None:
            raise InputError(f"robot {self.robot}: observations need a camera calibration")
        self.sequence = LiveSequence.restore(snapshot, self.inputs.detections is not None)
        with self._cond:
            self._started = True
        self._make_driver()
        try:
            self.driver.agent.restore(snapshot)
            _restore_lags(self.driver, snapshot)
        except (InputError, KeyError, ValueError) as exc:
            raise InputError(f"{path}: {exc}") from None
        t = self.driver.agent.frame
        self.driver.restore(snapshot["poses"][: t + 1], snapshot["covs"][: t + 1])
        self._last_T_odom = np.asarray(snapshot["live_T_odom"], float)
        with self._cond:
            self._last_frame_stamp = int(self.sequence.stamps_ns[t])
        return t + 1

    def run(
        self,
        frames: int | None = None,
        idle_timeout_s: float | None = None,
        inputs_alive: Callable[[], bool] | None = None,
        stop: threading.Event | None = None,
    ) -> dict:
        """Process frames until ``frames`` are done, the input ends (:meth:`finish`, or no
        message for ``idle_timeout_s`` once ``inputs_alive()`` says the publishers are gone),
        ``stop`` is set or Ctrl-C; write the result; its summary. A restarted robot calls
        :meth:`resume` first, before any message is fed.

        Raises
        ------
        InputError
            No frame was made from the inputs (nothing is written).
        EstimationError
            The filter failed; the result of the frames done is written first.
        """
        self._mkdir()
        done = self._frames_done()
        _atomic_json(self.out / "progress.json", {"frame": done - 1, "pid": os.getpid()})
        self.connect()
        try:
            while frames is None or self._frames_done() < frames:
                frame = self._next(idle_timeout_s, inputs_alive, stop)
                if frame is None:
                    break
                if not self._process(frame):
                    continue
                t = self.sequence.frames - 1
                every = self.team.checkpoint_every
                if every and (t + 1) % every == 0:
                    self._checkpoint(t)
                if t % 5 == 0:
                    _atomic_json(self.out / "progress.json", {"frame": t, "pid": os.getpid()})
            self._finish_links()
        except KeyboardInterrupt:
            self.say(f"robot {self.robot}: interrupted; writing the result of the frames done")
        except EstimationError:
            self._write(complete=False)
            raise
        finally:
            if self.transport is not None:
                self.transport.close()
        if self.driver is None:
            raise InputError(
                f"robot {self.robot}: no frame was made from the inputs "
                f"({', '.join(f'{k}: {v}' for k, v in sorted(self.counts.messages.items()))}"
                f"{'' if self.counts.messages else 'no message'})"
            )
        return self._write(complete=True)

    def _finish_links(self) -> None:
        """At the end of the input: say this robot is done and wait, up to the team file's
        timeout, until every neighbour is done or gone, so that our last messages still under
        way reach a slower neighbour before the session closes (the neighbours neither done
        nor gone by then are named)."""
        if self.transport is None or not self.neighbours:
            return
        waiting = self.transport.finish(self.team.timeout_s)
        if waiting:
            self.say(
                f"robot {self.robot}: closing after {self.team.timeout_s:g} s with neighbours "
                f"{', '.join(map(str, sorted(waiting)))} neither done nor gone"
            )

    def connect(self) -> None:
        """Wait for the neighbours' links (a first run: every neighbour, up to the team file's
        timeout; a resumed robot: 1 s); call it before subscribing, so that no frame queues
        meanwhile (:meth:`run` calls it when not done)."""
        if self.transport is not None and not self._connected:
            self.transport.wait_for_peers(
                len(self.neighbours), self.team.timeout_s if self._frames_done() == 0 else 1.0
            )
        self._connected = True

    def _mkdir(self) -> None:
        try:
            self.out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OutputError(f"cannot write {self.out}: {exc.strerror or exc}") from exc

    def _frames_done(self) -> int:
        return 0 if self.sequence is None else self.sequence.frames

    def _next(self, idle_timeout_s, inputs_alive, stop) -> _Frame | None:
        """The oldest queued frame; ``None`` once the input has ended and the queue is empty."""
        with self._cond:
            while not self._queue:
                if self._ended or (stop is not None and stop.is_set()):
                    return None
                idle = (time.monotonic_ns() - self._last_message_ns) / 1e9
                if (
                    idle_timeout_s is not None
                    and idle > idle_timeout_s
                    and (inputs_alive is None or not inputs_alive())
                ):
                    self._release(end=True)
                    self.counts.dropped["no_odometry"] += len(self._pending)
                    self._pending.clear()
                    self._ended = True
                    continue
                self._cond.wait(0.05)
            return self._queue.popleft()

    def statistics(self) -> dict:
        """The live figures: latency percentiles (ms), drops per stage, refusals, stage times,
        and the stamp of every frame processed (``stamps_ns``, in the order of the poses)."""
        latency = np.asarray(self.latency_ns, float) / 1e6
        percentiles = {
            name: (float(np.percentile(latency, q)) if latency.size else None)
            for name, q in (("p50", 50), ("p90", 90), ("p99", 99), ("max", 100))
        }
        with self._cond:
            counts = self.counts
            return {
                "latency_ms": percentiles,
                "latency_from": "arrival of the frame's camera input to the pose's publication",
                "frames": self._frames_done(),
                "dropped": dict(counts.dropped),
                "refused_stamps": dict(counts.refused_stamps),
                "malformed": dict(counts.malformed),
                "messages": dict(counts.messages),
                "odometry_frames": counts.odometry_frames,
                "frames_without_detections": counts.without_detections,
                "camera_gaps": counts.camera_gaps,
                "stage_seconds": dict(self.stage_seconds),
                "cpu_seconds": (
                    self._cpu_span[-1] - self._cpu_span[0] if len(self._cpu_span) == 2 else 0.0
                ),
                "budget_ms": self.budget_ms,
                "budget_overruns": dict(self.overruns),
                "queue": self.inputs.queue,
                "sync_tolerance_s": self.inputs.sync_tolerance_s,
                "stamps_ns": (
                    []
                    if self.sequence is None
                    else self.sequence.stamps_ns[: self.sequence.frames].tolist()
                ),
            }

    def _write(self, complete: bool) -> dict:
        transport = self.transport if self.transport is not None else _NoTransport()
        return _save(
            self.out,
            self.driver,
            transport,
            self.robot,
            self.team,
            self.step_seconds,
            complete=complete,
            extra={"live": self.statistics()},
        )


class _NoTransport:
    """The statistics of a robot that talks to nobody."""

    def statistics(self) -> dict:
        return {}


# ---------------------------------------------------------------------- the agent command
#: what the team file's ``ros2.inputs`` section may hold (topic names take ``{id}``, the
#: robot's id, and ``{name}``, its name in the team file)
INPUT_KEYS = (
    "odometry",
    "observations",
    "left",
    "right",
    "camera_info",
    "compressed",
    "camera",
    "sync_tolerance_s",
    "queue",
    "camera_timeout_s",
    "ground_truth",
    "detections",
)


def live_inputs(
    team: TeamFile, robot: int, flags: dict | None = None
) -> tuple[LiveInputs, Path | None]:
    """Robot ``robot``'s :class:`LiveInputs` from the team file's ``ros2.inputs`` section with
    ``flags`` (the same keys; ``None`` values ignored) on top, and its camera file if one is
    named.

    Raises
    ------
    InputError
        An unknown key, a missing odometry topic, a topic that is no ROS 2 name (one line).
    """
    from teamslam.ros2.live import check_topic_name

    section = dict((team.ros2 or {}).get("inputs") or {})
    unknown = set(section) - set(INPUT_KEYS)
    if unknown:
        raise InputError(f"ros2.inputs: unknown key(s) {', '.join(sorted(unknown))}")
    section.update({k: v for k, v in (flags or {}).items() if v is not None})
    entry = team.robots[robot]

    def topic(key: str) -> str | None:
        value = section.get(key)
        if value is None:
            return None
        if not isinstance(value, str):
            raise InputError(f"ros2.inputs.{key} must be a topic name, got {value!r}")
        return check_topic_name(value.replace("{id}", str(robot)).replace("{name}", entry.name))

    if topic("odometry") is None:
        raise InputError("live inputs: give the odometry topic (--odometry or ros2.inputs)")
    info = section.get("camera_info")
    if isinstance(info, str):
        info = info.split(",")
    if info is not None:
        if not isinstance(info, list | tuple) or len(info) != 2:
            raise InputError("camera_info expects two topics, LEFT,RIGHT")
    camera_info = None
    if info is not None:
        camera_info = tuple(
            check_topic_name(
                str(t).strip().replace("{id}", str(robot)).replace("{name}", entry.name)
            )
            for t in info
        )
    images = topic("left") is not None or topic("right") is not None
    camera = section.get("camera")
    base = team.path.parent if team.path is not None else Path(".")
    camera_path = (
        None if camera is None else (Path(camera) if Path(camera).is_absolute() else base / camera)
    )
    if images and camera_info is None and camera_path is None:
        raise InputError("live images need the camera_info topics or a camera file (--camera)")
    if not images and camera_path is None and _dataset_of(team, robot) is None:
        raise InputError(
            "live observations need a camera file (--camera) or a dataset in the team file"
        )
    try:
        inputs = LiveInputs(
            topic("odometry"),
            observations=topic("observations"),
            left=topic("left"),
            right=topic("right"),
            camera_info=camera_info,
            image_type=COMPRESSED if section.get("compressed") else IMAGE,
            ground_truth=topic("ground_truth"),
            detections=topic("detections"),
            sync_tolerance_s=float(section.get("sync_tolerance_s", 0.005)),
            queue=int(section.get("queue", 8)),
            camera_timeout_s=float(section.get("camera_timeout_s", 1.0)),
        )
    except (TypeError, ValueError) as exc:
        raise InputError(f"ros2.inputs: {exc}") from None
    return inputs, camera_path


def _dataset_of(team: TeamFile, robot: int):
    entry = team.robots[robot]
    return entry.dataset or team.dataset


def live_settings(team: TeamFile, robot: int):
    """The filter settings of a live robot and the calibration they came with.

    With a dataset in the team file (a recording of this robot): the settings
    :func:`~teamslam.runtime.agent_process.robot_setup` gives it — the same as the offline
    ``agent`` — and its calibration. Without: a function of the rig giving the team file's
    settings over the camera-scaled defaults (nothing to calibrate from; give the noise levels
    in ``settings``), and no calibration.
    """
    from teamslam.runtime.agent_process import robot_setup

    if _dataset_of(team, robot) is not None:
        dataset, _, config = robot_setup(team, robot)
        if _needs_truth(config):
            raise InputError(
                f"filter.linearization={config.filter.linearization} needs ground truth: "
                "not on a live robot"
            )
        return config, dataset.calibration

    def settings(calibration: Calibration) -> MsckfConfig:
        from teamslam.datasets import FrameObservations, RobotSequence, TeamDataset
        from teamslam.msckf.configure import build_settings

        nothing = TeamDataset(
            name="live",
            calibration=calibration,
            robots=[
                RobotSequence(
                    np.eye(4)[None],
                    np.zeros((0, 4, 4)),
                    FrameObservations.empty(1),
                    FrameObservations.empty(1),
                )
            ],
            object_ids=np.zeros(0, np.int64),
            object_positions=np.zeros((0, 3)),
        )
        return build_settings(nothing, file=team.settings, calibrate="never").config

    return settings, None


def _needs_truth(config: MsckfConfig) -> bool:
    from teamslam.msckf.filter.linearization import linearization_policy

    return linearization_policy(config.filter.linearization).needs_truth


def publishers_alive(session, domain_id: int, topics) -> bool:
    """Whether any publisher's liveliness token (rmw_zenoh's ``MP``) names one of ``topics``."""
    from teamslam.ros2.rmw_zenoh import parse_liveliness_key

    wanted = {t.strip("/") for t in topics}
    for reply in session.liveliness().get(f"@ros2_lv/{domain_id}/**", timeout=1.0):
        sample = getattr(reply, "ok", None)
        fields = None if sample is None else parse_liveliness_key(str(sample.key_expr))
        if fields and fields["kind"] == "MP" and fields["topic"].strip("/") in wanted:
            return True
    return False


def run_live(
    team: TeamFile,
    robot: int,
    out: str | Path,
    flags: dict | None = None,
    *,
    resume: bool = False,
    frames: int | None = None,
    idle_timeout_s: float = 5.0,
    budget_ms: float | None = None,
    ros2_options: dict | None = None,
    publish: bool = True,
    transport: Transport | None = None,
    foxglove: tuple[str, int] | None = None,
) -> dict:
    """``teamslam agent --live``: robot ``robot`` of ``team`` on its live topics until
    ``frames`` are done, the input ends (no message for ``idle_timeout_s`` and no publisher
    of its topics left) or Ctrl-C; its summary (the result is written as ``agent`` writes it).
    With ``foxglove`` (``(host, port)``) a :class:`~teamslam.viz.foxglove.FoxgloveView`
    serves the robot's estimates there while it runs.

    Raises
    ------
    InputError
        A configuration error (before anything runs), or no frame made from the inputs.
    EstimationError
        The filter failed; the frames done are written first.
    """
    from teamslam.frontend.camera import load_camera
    from teamslam.ros2.bags import read_camera
    from teamslam.ros2.live import Ros2Subscriber
    from teamslam.ros2.rmw_zenoh import Ros2Publisher, open_session, ros2_settings
    from teamslam.runtime.zenoh_transport import ZenohTransport

    inputs, camera = live_inputs(team, robot, flags)
    section = {k: v for k, v in (team.ros2 or {}).items() if k != "inputs"}
    settings = ros2_settings(section, **(ros2_options or {}))
    config, calibration = live_settings(team, robot)
    rig = None
    if camera is not None:
        if not camera.is_file():
            raise InputError(f"{camera}: no such camera file")
        if inputs.images:
            rig = load_camera(camera)
        else:
            calibration = read_camera(camera)
    neighbours = team.robots[robot].neighbours
    if transport is None and neighbours:
        transport = ZenohTransport(team, robot)
    publisher = None
    session = None
    view = None
    try:
        if foxglove is not None:
            from teamslam.viz.foxglove import FoxgloveView

            view = FoxgloveView(robot, *foxglove)
            print(f"robot {robot}: Foxglove view at {view.url}", file=sys.stderr, flush=True)
        if publish:
            publisher = Ros2Publisher(
                robot,
                None,  # stamped frame by frame
                domain_id=settings["domain_id"],
                connect=settings["connect"],
                listen=settings["listen"],
                path_every=settings["path_every"],
                objects_every=settings["objects_every"],
            )
        live = LiveRobot(
            team,
            robot,
            inputs,
            config,
            out,
            calibration=calibration,
            rig=rig,
            transport=transport,
            publisher=publisher,
            view=view,
            budget_ms=budget_ms,
        )
        if resume:
            done = live.resume()
            if done:
                live.say(f"robot {robot}: resumed after frame {done - 1}")
        live.connect()
        session = open_session(settings["connect"], settings["listen"])
        topics = inputs.topics()
        subscriber = Ros2Subscriber(
            topics,
            live.feed,
            node=f"teamslam_robot_{robot}_inputs",
            domain_id=settings["domain_id"],
            session=session,
            on_error=live.say,
        )
        try:
            return live.run(
                frames=frames,
                idle_timeout_s=idle_timeout_s,
                inputs_alive=lambda: publishers_alive(session, settings["domain_id"], topics),
            )
        finally:
            subscriber.close()
    finally:
        if publisher is not None:
            publisher.close()
        if view is not None:
            view.close()
        if session is not None:
            session.close()
