"""A detector's boxes in a ROS 2 bag: ``vision_msgs/msg/Detection2DArray`` topics.

:func:`read_detection_topic` gives one :class:`~teamslam.frontend.detections.ImageDetections`
per image stamp: a message belongs to the image whose stamp equals its ``header.stamp`` (as a
detector node stamps its output with its input's stamp). Each ``Detection2D`` is an
axis-aligned box (``bbox.center.theta`` must be 0) whose class is the ``class_id`` of its
highest-scoring hypothesis. Box coordinates are read as detectors publish them — pixel edges,
so a box over the whole image has centre ``(W/2, H/2)`` and size ``(W, H)`` — and returned in
the OpenCV pixel-centre convention, clipped to the image. :func:`write_detection_topic` writes
such a topic (MCAP). Malformed messages raise :class:`~teamslam.errors.InputError` naming the
topic, the stamp and the detection. Live, :func:`message_detections` reads one message the
same way, its class labels from a :class:`LiveClassTable`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from teamslam.errors import InputError
from teamslam.frontend.detections import (
    DetectionsRead,
    ImageDetections,
    _assemble,
    _Box,
    _image_size,
)
from teamslam.ros2 import messages as m
from teamslam.ros2.bags import _check_type, _read_topics

__all__ = [
    "LiveClassTable",
    "class_table",
    "detection_records",
    "message_detections",
    "read_detection_topic",
    "write_detection_topic",
]


def class_table(names: Sequence[str]) -> dict[str, int]:
    """The default labels of ``vision_msgs`` class ids (strings), given every id of a topic in
    the order met: when every id spells an integer ``≥ 0``, that integer; otherwise each distinct
    id numbered ``0, 1, …`` in order of first appearance (for all ids, so a number and a name
    never share a label)."""
    distinct = list(dict.fromkeys(names))
    if all(n.isascii() and n.isdigit() for n in distinct):
        return {n: int(n) for n in distinct}
    return {n: i for i, n in enumerate(distinct)}


class LiveClassTable:
    """The class labels of a live ``Detection2DArray`` topic, message by message: those
    :func:`class_table` gives the whole topic when its ids are all integers (that integer) or
    all names (numbered ``0, 1, …`` in order of first appearance). A topic that mixes the two
    is refused: its labels would depend on ids not seen yet."""

    def __init__(self) -> None:
        self.table: dict[str, int] = {}
        self._numeric: bool | None = None

    def label(self, name: str, where: str) -> int:
        """The label of class id ``name``.

        Raises
        ------
        InputError
            ``name`` is a number where names came before, or the other way round.
        """
        if name in self.table:
            return self.table[name]
        numeric = name.isascii() and name.isdigit()
        if self._numeric is not None and numeric != self._numeric:
            raise InputError(
                f"{where}: class id {name!r} mixes numbers and names on one topic (live labels "
                "need all of one kind)"
            )
        self._numeric = numeric
        self.table[name] = int(name) if numeric else len(self.table)
        return self.table[name]

    def state_dict(self) -> dict[str, np.ndarray]:
        """The labels given so far (a checkpoint's): names in order of first appearance."""
        return {"names": np.array(list(self.table), dtype=str)}

    @classmethod
    def from_state(cls, state: dict[str, np.ndarray]) -> LiveClassTable:
        """The table of a :meth:`state_dict`: the same label for every name seen before it."""
        table = cls()
        for name in np.asarray(state["names"], dtype=str).tolist():
            table.label(name, "checkpoint")
        return table


def message_detections(
    msg, where: str, image_size: tuple[int, int], classes: LiveClassTable
) -> ImageDetections:
    """The boxes of one ``Detection2DArray`` message, read as :func:`read_detection_topic`
    reads each message of a bag (clipped to ``image_size``, labels from ``classes``).

    Raises
    ------
    InputError
        A malformed detection, named with ``where`` and its index.
    """
    try:
        detections = list(msg.detections)
    except (AttributeError, TypeError):
        raise InputError(f"{where}: not a {m.DETECTIONS_TYPE}") from None
    rows = []
    for k, det in enumerate(detections):
        at = f"{where}, detection {k}"
        name, score, box = _detection(det, at)
        rows.append(_Box(0, box, classes.label(name, at), score, None))
    return _assemble(rows, 1, _image_size(image_size), None, 0).images[0]


def read_detection_topic(
    bag: str | Path,
    topic: str,
    stamps_ns: Sequence[int] | np.ndarray,
    image_size: tuple[int, int],
    *,
    classes: Mapping[str, int] | None = None,
) -> DetectionsRead:
    """The boxes of a ``Detection2DArray`` topic, one :class:`ImageDetections` per image stamp.

    Parameters
    ----------
    bag
        A ROS 2 bag (folder or ``.mcap``).
    topic
        The ``vision_msgs/msg/Detection2DArray`` topic.
    stamps_ns
        The images' stamps (integer nanoseconds), in the order wanted.
    image_size
        ``(W, H)`` of the images: boxes are clipped to it.
    classes
        ``{class_id: label}`` for the topic's class ids (every id must be in it); by default
        :func:`class_table` of the ids met.

    Returns
    -------
    DetectionsRead
        Per image stamp its boxes (none when no message has its stamp; counted as
        ``images_without_file``); ``class_table`` is the mapping used. A message stamped with
        no image's stamp is an error.
    """
    image_size = _image_size(image_size)
    stamps = np.asarray(stamps_ns, dtype=np.int64).ravel()
    index = {int(s): i for i, s in enumerate(stamps)}
    if len(index) != len(stamps):
        raise InputError(f"{topic}: two images share a stamp")
    items = _read_topics(Path(bag), {topic})[topic]
    _check_type(topic, items, (m.DETECTIONS_TYPE,))
    found = []  # (image, stamp, detection index, class id, score, box)
    for stamp, msg in items:
        if stamp not in index:
            raise InputError(f"{topic}: a message stamped {stamp} ns matches no image stamp")
        for k, det in enumerate(msg.detections):
            where = f"{topic}, message at {stamp} ns, detection {k}"
            found.append((index[stamp], stamp, k, *_detection(det, where)))
    names = [name for *_, name, _, _ in found]
    table = class_table(names) if classes is None else dict(classes)
    bad = [v for v in table.values() if isinstance(v, bool) or not isinstance(v, int) or v < 0]
    if bad:
        raise InputError(f"class table: labels must be integers ≥ 0, got {bad[0]!r}")
    rows = []
    for image, stamp, k, name, score, box in found:
        if name not in table:
            raise InputError(
                f"{topic}, message at {stamp} ns, detection {k}: class id {name!r} is not in "
                "the class table"
            )
        rows.append(_Box(image, box, table[name], score, None))
    return _assemble(
        rows, len(stamps), image_size, None, len(stamps) - len(items), class_table=table
    )


def _detection(det, where: str) -> tuple[str, float, tuple[float, float, float, float]]:
    """``(class id, score, pixel-centre box)`` of one ``Detection2D``."""
    try:
        hypotheses = [(r.hypothesis.class_id, float(r.hypothesis.score)) for r in det.results]
        centre = det.bbox.center
        cx, cy, theta = float(centre.position.x), float(centre.position.y), float(centre.theta)
        sx, sy = float(det.bbox.size_x), float(det.bbox.size_y)
    except AttributeError:
        raise InputError(
            f"{where}: not a vision_msgs 4 Detection2D (results[].hypothesis.class_id, "
            "bbox.center.position)"
        ) from None
    if not hypotheses:
        raise InputError(f"{where}: no class hypothesis (results is empty)")
    values = (cx, cy, sx, sy, theta, *(s for _, s in hypotheses))
    if not all(math.isfinite(v) for v in values):
        raise InputError(f"{where}: a box value or score is not finite")
    if theta != 0.0:
        raise InputError(f"{where}: rotated box (theta {theta:g}); boxes must be axis-aligned")
    if sx <= 0 or sy <= 0:
        raise InputError(f"{where}: box size {sx:g} x {sy:g} is not positive")
    name, score = max(hypotheses, key=lambda h: h[1])
    if not 0.0 <= score <= 1.0:
        raise InputError(f"{where}: score {score:g} is outside [0, 1]")
    box = (cx - sx / 2 - 0.5, cy - sy / 2 - 0.5, cx + sx / 2 - 0.5, cy + sy / 2 - 0.5)
    return name, score, box


def write_detection_topic(
    out: str | Path,
    topic: str,
    stamps_ns: Sequence[int] | np.ndarray,
    detections: Sequence[ImageDetections],
    *,
    class_names: Sequence[str] | None = None,
    frame_id: str = "camera",
) -> dict[str, int]:
    """Write one ``Detection2DArray`` per image stamp to an MCAP bag ``out``.

    Each box becomes a ``Detection2D`` with one hypothesis: ``class_names[label]`` (or the label
    as a string) and the box's score; boxes are written in pixel edges (the inverse of
    :func:`read_detection_topic`). ``vision_msgs`` has no field for embeddings: they are not
    written. Returns the messages per topic.
    """
    records = detection_records(
        topic, stamps_ns, detections, class_names=class_names, frame_id=frame_id
    )
    return m.write_mcap_records(records, Path(out))


def detection_records(
    topic: str,
    stamps_ns: Sequence[int] | np.ndarray,
    detections: Sequence[ImageDetections],
    *,
    class_names: Sequence[str] | None = None,
    frame_id: str = "camera",
) -> list[tuple[int, str, str, bytes]]:
    """The ``(stamp, topic, msgtype, cdr bytes)`` records of :func:`write_detection_topic`, to
    write beside other topics in one bag."""
    if len(stamps_ns) != len(detections):
        raise InputError(f"{len(stamps_ns)} stamps for {len(detections)} images of detections")
    t = m.typestore().types
    Detection2D, Array = t["vision_msgs/msg/Detection2D"], t[m.DETECTIONS_TYPE]
    Hypothesis = t["vision_msgs/msg/ObjectHypothesisWithPose"]
    BoundingBox2D, Pose2D = t["vision_msgs/msg/BoundingBox2D"], t["vision_msgs/msg/Pose2D"]
    Point2D, Inner = t["vision_msgs/msg/Point2D"], t["vision_msgs/msg/ObjectHypothesis"]
    PoseWithCovariance = t["geometry_msgs/msg/PoseWithCovariance"]
    no_pose = PoseWithCovariance(pose=m.pose_msg(np.eye(4)), covariance=np.zeros(36))
    records = []
    for stamp, image in zip(stamps_ns, detections, strict=True):
        hdr = m.header(int(stamp), frame_id)
        dets = []
        for box, label, score in zip(
            image.boxes.tolist(), image.classes.tolist(), image.scores.tolist(), strict=True
        ):
            x_min, y_min, x_max, y_max = box
            name = str(label) if class_names is None else class_names[label]
            dets.append(
                Detection2D(
                    header=hdr,
                    results=[
                        Hypothesis(hypothesis=Inner(class_id=name, score=score), pose=no_pose)
                    ],
                    bbox=BoundingBox2D(
                        center=Pose2D(
                            position=Point2D(
                                x=(x_min + x_max) / 2 + 0.5, y=(y_min + y_max) / 2 + 0.5
                            ),
                            theta=0.0,
                        ),
                        size_x=x_max - x_min,
                        size_y=y_max - y_min,
                    ),
                    id="",
                )
            )
        msg = Array(header=hdr, detections=dets)
        records.append((int(stamp), topic, m.DETECTIONS_TYPE, m.serialize(msg)))
    return records
