"""The team dataset: what a team of stereo robots recorded, plus the truth to score it against.

Frames and conventions
----------------------
* ``T_world_body`` — ground-truth body poses; the body frame of the published data is
  x forward, y left, z up. Robots may start anywhere in the world frame.
* ``odometry[k] = T_body_k⁻¹ · T_body_{k+1}`` — relative motion from frame ``k`` to ``k + 1``
  expressed in body frame ``k`` (right-multiplied: ``T_{k+1} = T_k · odometry[k]``).
* ``T_cam_body`` — maps body coordinates into the left optical frame (x right, y down,
  z forward): ``p_cam = T_cam_body · p_body``.
* Observations are stereo ``(u_l, v_l, u_r, v_r)`` in the units of ``K`` (pixels; normalised
  coordinates when ``K = I``). Per frame they are ragged — a different set of ids each frame
  — and are stored as flat arrays plus offsets (:class:`FrameObservations`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from teamslam.errors import InputError
from teamslam.geometry.camera import StereoCamera

if TYPE_CHECKING:
    from teamslam.datasets.sensor_model import SensorModel

__all__ = [
    "OBJECT_ID_SCOPES",
    "Calibration",
    "DatasetError",
    "FrameDetections",
    "FrameObservations",
    "RobotSequence",
    "TeamDataset",
]

#: What an object id means: ``global`` — the same object has the same id in every robot's data
#: (ids from an oracle, e.g. instance annotations); ``per-robot`` — each robot numbers its own
#: objects, and equal ids of two robots say nothing; ``none`` — no ids at all: each robot has
#: per-frame detections (:class:`FrameDetections`) and its filter tracks them itself.
OBJECT_ID_SCOPES = ("global", "per-robot", "none")


class DatasetError(InputError):
    """A dataset (in memory or on disk) is malformed; the message names the field."""


@dataclass(frozen=True)
class Calibration:
    """Stereo calibration of every robot's camera (the team shares one rig model).

    Attributes
    ----------
    camera
        Intrinsics and right-camera pose of the rectified stereo pair.
    T_cam_body
        4×4 transform from the body frame to the left optical frame.
    image_size
        ``(width, height)`` in pixels, or ``None`` when unknown.
    """

    camera: StereoCamera
    T_cam_body: np.ndarray
    image_size: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        t = np.asarray(self.T_cam_body, dtype=float)
        if t.shape != (4, 4) or not np.all(np.isfinite(t)):
            raise DatasetError("T_cam_body must be a finite 4×4 matrix")
        if not np.allclose(t[:3, :3] @ t[:3, :3].T, np.eye(3), atol=1e-6):
            raise DatasetError("T_cam_body rotation is not orthonormal")
        object.__setattr__(self, "T_cam_body", t)


@dataclass(frozen=True)
class FrameObservations:
    """Ragged per-frame observations ``{id -> (u_l, v_l, u_r, v_r)}`` as flat arrays.

    Frame ``k`` holds ``ids[offsets[k]:offsets[k+1]]`` and the matching rows of
    ``measurements``.

    Attributes
    ----------
    offsets
        ``(frames + 1,)`` int64, non-decreasing, ``offsets[0] = 0``, ``offsets[-1] = len(ids)``.
    ids
        ``(M,)`` int64 landmark / track ids; unique within a frame.
    measurements
        ``(M, 4)`` float64, finite.
    """

    offsets: np.ndarray
    ids: np.ndarray
    measurements: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "offsets", np.asarray(self.offsets, dtype=np.int64))
        object.__setattr__(self, "ids", np.asarray(self.ids, dtype=np.int64))
        object.__setattr__(
            self, "measurements", np.asarray(self.measurements, dtype=np.float64).reshape(-1, 4)
        )
        self.validate("observations")

    def validate(self, where: str) -> None:
        """Raise :class:`DatasetError` naming ``where`` if the arrays are inconsistent."""
        o, ids, z = self.offsets, self.ids, self.measurements
        if o.ndim != 1 or o.size < 1:
            raise DatasetError(f"{where}: offsets must be a non-empty vector")
        if o[0] != 0 or o[-1] != ids.size:
            raise DatasetError(
                f"{where}: offsets must start at 0 and end at the number of ids ({ids.size}), "
                f"got {o[0]}..{o[-1]}"
            )
        if np.any(np.diff(o) < 0):
            raise DatasetError(f"{where}: offsets are not monotone")
        if ids.ndim != 1 or z.shape != (ids.size, 4):
            raise DatasetError(f"{where}: {ids.size} ids but measurements of shape {z.shape}")
        if not np.all(np.isfinite(z)):
            bad = int(np.flatnonzero(~np.isfinite(z).all(axis=1))[0])
            frame = int(np.searchsorted(o, bad, side="right") - 1)
            raise DatasetError(f"{where}: non-finite measurement in frame {frame}")
        if ids.size:
            frame_of = np.repeat(np.arange(o.size - 1), np.diff(o))
            pairs = np.stack([frame_of, ids], axis=1)
            if np.unique(pairs, axis=0).shape[0] != ids.size:
                raise DatasetError(f"{where}: an id appears twice in one frame")

    @property
    def frames(self) -> int:
        """Number of frames."""
        return self.offsets.size - 1

    def frame(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """``(ids, measurements)`` of frame ``k`` (views, not copies)."""
        a, b = self.offsets[k], self.offsets[k + 1]
        return self.ids[a:b], self.measurements[a:b]

    def head(self, frames: int) -> FrameObservations:
        """The first ``frames`` frames."""
        end = self.offsets[min(frames, self.frames)]
        return FrameObservations(
            self.offsets[: frames + 1], self.ids[:end], self.measurements[:end]
        )

    def counts(self) -> np.ndarray:
        """Observations per frame."""
        return np.diff(self.offsets)

    @classmethod
    def empty(cls, frames: int) -> FrameObservations:
        """No observations in any of ``frames`` frames."""
        return cls(np.zeros(frames + 1, dtype=np.int64), np.zeros(0), np.zeros((0, 4)))

    @classmethod
    def from_frames(
        cls, frames: Sequence[Mapping[int, Sequence[float]] | tuple[np.ndarray, np.ndarray]]
    ) -> FrameObservations:
        """Build from a list over frames of ``{id: (u_l, v_l, u_r, v_r)}`` or ``(ids, z)``."""
        ids, meas, counts = [], [], []
        for f in frames:
            if isinstance(f, tuple):
                fid, fz = np.asarray(f[0], dtype=np.int64), np.asarray(f[1], dtype=float)
            else:
                fid = np.fromiter((int(k) for k in f), dtype=np.int64, count=len(f))
                fz = (
                    np.stack([np.asarray(v, dtype=float) for v in f.values()])
                    if len(f)
                    else np.zeros((0, 4))
                )
            ids.append(fid)
            meas.append(fz.reshape(-1, 4))
            counts.append(fid.size)
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        return cls(
            offsets,
            np.concatenate(ids) if ids else np.zeros(0, np.int64),
            np.concatenate(meas) if meas else np.zeros((0, 4)),
        )

    def to_dicts(self) -> list[dict[int, np.ndarray]]:
        """A list over frames of ``{id: measurement}``."""
        out = []
        for k in range(self.frames):
            ids, z = self.frame(k)
            out.append({int(i): row.copy() for i, row in zip(ids, z, strict=True)})
        return out


@dataclass(frozen=True)
class FrameDetections:
    """Ragged per-frame object detections without ids, as flat arrays.

    Frame ``k`` holds rows ``offsets[k]:offsets[k+1]``. What a detector gives (filter-visible):
    the stereo box centre ``(u_l, v_l, u_r, v_r)``, optionally a class label and a score. What
    the detection truly is (:attr:`truth`) is ground truth, for evaluation only.

    Attributes
    ----------
    offsets
        ``(frames + 1,)`` int64, non-decreasing, ``offsets[0] = 0``, ``offsets[-1] = M``.
    measurements
        ``(M, 4)`` float64 stereo coordinates (non-finite rows are rejected by the filter).
    classes
        ``(M,)`` int64 class labels ``≥ 0``, or ``None`` when the detector gives none.
    scores
        ``(M,)`` float64 detector scores in ``[0, 1]``, or ``None``.
    truth
        ``(M,)`` int64 team object id of each detection, ``-1`` for a false one, or ``None``
        when unknown. Never read by a filter.
    sizes
        ``(M, 2)`` float64 box width and height in the left image (units of ``K``), or
        ``None``.
    appearance
        ``(M, D)`` float32 appearance descriptor of each detection (finite; a descriptor the
        front-end computed from the image inside the box, or the user's embedding), or
        ``None``. Compared only with descriptors of the same dataset
        (:mod:`teamslam.msckf.objects.appearance`).
    """

    offsets: np.ndarray
    measurements: np.ndarray
    classes: np.ndarray | None = None
    scores: np.ndarray | None = None
    truth: np.ndarray | None = None
    sizes: np.ndarray | None = None
    appearance: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "offsets", np.asarray(self.offsets, dtype=np.int64))
        z = np.asarray(self.measurements, dtype=np.float64)
        object.__setattr__(self, "measurements", z.reshape(-1, 4) if z.size == 0 else z)
        for name, dtype in (("classes", np.int64), ("scores", np.float64), ("truth", np.int64)):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, np.asarray(value).astype(dtype).reshape(-1))
        for name, dtype in (("sizes", np.float64), ("appearance", np.float32)):
            value = getattr(self, name)
            if value is not None:
                value = np.asarray(value).astype(dtype)
                object.__setattr__(self, name, value.reshape(len(value), -1))
        self.validate("detections")

    def validate(self, where: str) -> None:
        """Raise :class:`DatasetError` naming ``where`` and the field if inconsistent."""
        o, z = self.offsets, self.measurements
        if o.ndim != 1 or o.size < 1:
            raise DatasetError(f"{where}: offsets must be a non-empty vector")
        if z.ndim != 2 or z.shape[1] != 4:
            raise DatasetError(f"{where}: measurements must be (M, 4), got {z.shape}")
        if o[0] != 0 or o[-1] != len(z):
            raise DatasetError(
                f"{where}: offsets must start at 0 and end at the number of detections "
                f"({len(z)}), got {o[0]}..{o[-1]}"
            )
        if np.any(np.diff(o) < 0):
            raise DatasetError(f"{where}: offsets are not monotone")
        for name in ("classes", "scores", "truth"):
            value = getattr(self, name)
            if value is not None and value.shape != (len(z),):
                raise DatasetError(
                    f"{where}.{name}: {value.shape[0]} entries for {len(z)} detections"
                )
        if self.classes is not None and np.any(self.classes < 0):
            raise DatasetError(f"{where}.classes: class labels must be ≥ 0")
        if self.scores is not None:
            s = self.scores
            if not np.all(np.isfinite(s) & (s >= 0) & (s <= 1)):
                raise DatasetError(f"{where}.scores must lie in [0, 1]")
        if self.truth is not None and np.any(self.truth < -1):
            raise DatasetError(f"{where}.truth: object ids must be ≥ 0, or -1 for false ones")
        if self.sizes is not None:
            if self.sizes.shape != (len(z), 2):
                raise DatasetError(
                    f"{where}.sizes: shape {self.sizes.shape}, expected ({len(z)}, 2)"
                )
            if not np.all(np.isfinite(self.sizes) & (self.sizes > 0)):
                raise DatasetError(f"{where}.sizes: box sizes must be finite and > 0")
        if self.appearance is not None:
            a = self.appearance
            if a.ndim != 2 or a.shape[0] != len(z) or a.shape[1] < 1:
                raise DatasetError(
                    f"{where}.appearance: shape {a.shape}, expected ({len(z)}, D) with D ≥ 1"
                )
            if not np.all(np.isfinite(a)):
                raise DatasetError(f"{where}.appearance: descriptors must be finite")

    @property
    def frames(self) -> int:
        """Number of frames."""
        return self.offsets.size - 1

    def frame(self, k: int) -> tuple[np.ndarray, np.ndarray | None]:
        """``(measurements, classes)`` of frame ``k`` (views; classes ``None`` when absent)."""
        a, b = self.offsets[k], self.offsets[k + 1]
        return self.measurements[a:b], None if self.classes is None else self.classes[a:b]

    def sizes_of(self, k: int) -> np.ndarray | None:
        """``(D_k, 2)`` box sizes of frame ``k`` (a view), or ``None``."""
        if self.sizes is None:
            return None
        return self.sizes[self.offsets[k] : self.offsets[k + 1]]

    def appearance_of(self, k: int) -> np.ndarray | None:
        """``(D_k, D)`` appearance descriptors of frame ``k`` (a view), or ``None``."""
        if self.appearance is None:
            return None
        return self.appearance[self.offsets[k] : self.offsets[k + 1]]

    def head(self, frames: int) -> FrameDetections:
        """The first ``frames`` frames."""
        end = self.offsets[min(frames, self.frames)]

        def cut(a):
            return None if a is None else a[:end]

        return FrameDetections(
            self.offsets[: frames + 1],
            self.measurements[:end],
            cut(self.classes),
            cut(self.scores),
            cut(self.truth),
            cut(self.sizes),
            cut(self.appearance),
        )

    @classmethod
    def from_observations(
        cls,
        objects: FrameObservations,
        truth: np.ndarray | None = None,
        classes: np.ndarray | None = None,
    ) -> FrameDetections:
        """The detections of ``objects`` with their ids dropped (same rows, same order).

        ``truth`` gives each row's team object id (default: the ids themselves); ``classes``
        the ``(C, 2)`` rows ``(object id, class)`` of the objects (rows without a class make
        every detection class-less).
        """
        labels = None
        if classes is not None and len(classes):
            order = np.argsort(classes[:, 0])
            pos = np.clip(np.searchsorted(classes[order, 0], objects.ids), 0, len(classes) - 1)
            if np.all(classes[order[pos], 0] == objects.ids):
                labels = classes[order[pos], 1]
        return cls(
            objects.offsets,
            objects.measurements,
            labels,
            None,
            objects.ids.copy() if truth is None else truth,
        )


@dataclass(frozen=True)
class RobotSequence:
    """What one robot recorded, with its ground truth.

    Attributes
    ----------
    T_world_body
        ``(N + 1, 4, 4)`` ground-truth poses.
    odometry
        ``(N, 4, 4)`` measured relative poses, ``T_{k+1} ≈ T_k · odometry[k]``.
    features
        Geometric-feature observations per frame, keyed by track id.
    objects
        Object detections (box centres) per frame, keyed by object id.
    timestamps
        ``(N + 1,)`` seconds, finite, ``≥ 0`` and increasing, or ``None``. Negative stamps are
        refused rather than shifted: every export (ROS 2 stamps are unsigned) then writes the
        times the data holds.
    object_classes
        ``(C, 2)`` int64 rows ``(object id, class label)`` from the robot's detector, or
        ``None`` when it gives no class. Filter-visible, like the detections themselves.
    detections
        Object detections without ids (:class:`FrameDetections`), or ``None``. A robot whose
        ``objects`` hold no observation and that has detections tracks them itself
        (:mod:`teamslam.msckf.objects.tracking`); with ids the detections are not read by the
        filter.
    object_appearance_ids, object_appearance
        ``(C,)`` int64 object ids and ``(C, D)`` float32 the robot's appearance descriptor of
        each (finite, any scale), or both ``None``. One descriptor per object, like
        ``object_classes``: what a robot with ids sends its neighbours to tell its objects apart
        (the association between robots compares one summary per object; a robot that tracks
        its detections keeps such summaries itself). Filter-visible.
    """

    T_world_body: np.ndarray
    odometry: np.ndarray
    features: FrameObservations
    objects: FrameObservations
    timestamps: np.ndarray | None = None
    object_classes: np.ndarray | None = None
    detections: FrameDetections | None = None
    object_appearance_ids: np.ndarray | None = None
    object_appearance: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "T_world_body", np.asarray(self.T_world_body, dtype=float))
        if (self.object_appearance_ids is None) != (self.object_appearance is None):
            raise DatasetError("object_appearance_ids and object_appearance come together")
        if self.object_appearance is not None:
            ids = np.asarray(self.object_appearance_ids)
            if ids.dtype.kind not in "iu":
                raise DatasetError("object_appearance_ids must be integers")
            object.__setattr__(self, "object_appearance_ids", ids.astype(np.int64).reshape(-1))
            try:
                looks = np.asarray(self.object_appearance, dtype=np.float32)
            except (TypeError, ValueError):
                raise DatasetError("object_appearance must be a numeric array") from None
            object.__setattr__(self, "object_appearance", looks)
        object.__setattr__(self, "odometry", np.asarray(self.odometry, dtype=float))
        if self.timestamps is not None:
            object.__setattr__(self, "timestamps", np.asarray(self.timestamps, dtype=float))
        if self.object_classes is not None:
            classes = np.asarray(self.object_classes)
            if classes.dtype.kind not in "iu" or classes.size % 2:
                raise DatasetError("object_classes must be integer rows (object id, class)")
            object.__setattr__(self, "object_classes", classes.astype(np.int64).reshape(-1, 2))

    @property
    def frames(self) -> int:
        """Number of frames ``N + 1``."""
        return self.T_world_body.shape[0]

    def head(self, frames: int) -> RobotSequence:
        """The first ``frames`` frames (the whole sequence when it is shorter)."""
        if frames >= self.frames:
            return self
        return RobotSequence(
            T_world_body=self.T_world_body[:frames],
            odometry=self.odometry[: frames - 1],
            features=self.features.head(frames),
            objects=self.objects.head(frames),
            timestamps=None if self.timestamps is None else self.timestamps[:frames],
            object_classes=self.object_classes,
            detections=None if self.detections is None else self.detections.head(frames),
            object_appearance_ids=self.object_appearance_ids,
            object_appearance=self.object_appearance,
        )

    def appearance_of_objects(self, ids: np.ndarray) -> np.ndarray | None:
        """``(n, D)`` float64 the descriptors of objects ``ids`` (zero rows where the robot has
        none), or ``None`` without :attr:`object_appearance`."""
        if self.object_appearance is None:
            return None
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        out = np.zeros((ids.size, self.object_appearance.shape[1]))
        keys = self.object_appearance_ids
        if keys.size and ids.size:
            order = np.argsort(keys, kind="stable")
            pos = np.minimum(np.searchsorted(keys[order], ids), keys.size - 1)
            hit = keys[order[pos]] == ids
            out[hit] = self.object_appearance[order[pos[hit]]]
        return out

    def validate(self, where: str) -> None:
        """Raise :class:`DatasetError` naming ``where`` and the field on any inconsistency."""
        poses, odo = self.T_world_body, self.odometry
        if poses.ndim != 3 or poses.shape[1:] != (4, 4):
            raise DatasetError(
                f"{where}.T_world_body must be (N + 1, 4, 4) poses, got shape {poses.shape}"
            )
        if poses.shape[0] < 2:
            raise DatasetError(
                f"{where} has {poses.shape[0]} frame{'' if poses.shape[0] == 1 else 's'} "
                f"(T_world_body holds {poses.shape[0]} poses); a robot needs at least two: "
                "one step of odometry to estimate"
            )
        n = poses.shape[0] - 1
        if odo.shape != (n, 4, 4):
            raise DatasetError(f"{where}.odometry must be ({n}, 4, 4), got {odo.shape}")
        for name, arr in (("T_world_body", poses), ("odometry", odo)):
            if not np.all(np.isfinite(arr)):
                k = int(np.flatnonzero(~np.isfinite(arr).all(axis=(1, 2)))[0])
                raise DatasetError(f"{where}.{name}: non-finite pose at frame {k}")
            r = arr[:, :3, :3]
            err = np.abs(r @ np.swapaxes(r, 1, 2) - np.eye(3)).max(axis=(1, 2)) if len(r) else []
            if len(r) and np.max(err) > 1e-4:
                k = int(np.argmax(err))
                raise DatasetError(f"{where}.{name}: rotation at frame {k} is not orthonormal")
        for name, obs in (("features", self.features), ("objects", self.objects)):
            obs.validate(f"{where}.{name}")
            if name == "objects" and np.any(obs.ids < 0):
                j = int(np.flatnonzero(obs.ids < 0)[0])
                frame = int(np.searchsorted(obs.offsets, j, side="right") - 1)
                raise DatasetError(
                    f"{where}.objects: object id {int(obs.ids[j])} in frame {frame}; object ids "
                    "must be ≥ 0"
                )
            if obs.frames != n + 1:
                raise DatasetError(
                    f"{where}.{name}: {obs.frames} frames of observations for {n + 1} poses"
                )
        if self.detections is not None:
            self.detections.validate(f"{where}.detections")
            if self.detections.frames != n + 1:
                raise DatasetError(
                    f"{where}.detections: {self.detections.frames} frames of detections for "
                    f"{n + 1} poses"
                )
        if self.timestamps is not None:
            ts = self.timestamps
            if ts.shape != (n + 1,):
                raise DatasetError(
                    f"{where}.timestamps must be one per frame, ({n + 1},), got shape {ts.shape}"
                )
            bad = ~np.isfinite(ts) | (ts < 0)
            if np.any(bad):
                k = int(np.flatnonzero(bad)[0])
                raise DatasetError(
                    f"{where}.timestamps[{k}] is {ts[k]:g} s; timestamps must be finite and ≥ 0 "
                    "(seconds since an epoch before the recording, as ROS 2 stamps)"
                )
            if np.any(np.diff(ts) <= 0):
                k = int(np.flatnonzero(np.diff(ts) <= 0)[0])
                raise DatasetError(
                    f"{where}.timestamps must increase, but [{k + 1}] = {ts[k + 1]:g} s follows "
                    f"[{k}] = {ts[k]:g} s"
                )
        if self.object_classes is not None:
            classes = self.object_classes
            if np.unique(classes[:, 0]).size != len(classes):
                raise DatasetError(f"{where}.object_classes names an object twice")
            if np.any(classes[:, 1] < 0):
                raise DatasetError(f"{where}.object_classes: class labels must be ≥ 0")
        if self.object_appearance is not None:
            ids, looks = self.object_appearance_ids, self.object_appearance
            if looks.ndim != 2 or looks.shape[0] != ids.size or looks.shape[1] < 1:
                raise DatasetError(
                    f"{where}.object_appearance: shape {looks.shape}, expected ({ids.size}, D) "
                    "with D ≥ 1 for its object ids"
                )
            if np.unique(ids).size != ids.size:
                raise DatasetError(f"{where}.object_appearance_ids names an object twice")
            if not np.all(np.isfinite(looks)):
                raise DatasetError(f"{where}.object_appearance: descriptors must be finite")


@dataclass
class TeamDataset:
    """A team of robots with a shared calibration and the true map.

    Attributes
    ----------
    name
        A short name.
    calibration
        The stereo rig and body-to-camera transform.
    robots
        One :class:`RobotSequence` per robot.
    object_ids, object_positions
        Ground-truth object positions ``(K,)``, ``(K, 3)`` in the world frame.
    landmark_ids, landmark_positions
        Ground-truth geometric landmarks (simulated data only; empty otherwise).
    track_landmarks
        For simulated data: ``(T, 2)`` rows ``(track id, landmark id)`` naming the landmark each
        geometric track observes (track ids are unique over the whole team); empty otherwise.
    metadata
        Free-form description (generator parameters, where the files came from). Nothing
        reads settings from it.
    sensor_model
        The noise of the team's sensors (:class:`~teamslam.datasets.sensor_model.SensorModel`),
        or ``None`` when unknown (then ``teamslam run`` calibrates it from the data).
    object_id_scope
        ``"global"`` (an object has the same id in every robot's data) or ``"per-robot"``
        (each robot's own numbering); see :data:`OBJECT_ID_SCOPES`.
    object_identity
        Ground truth for ``per-robot`` ids, like the object positions: ``(K, 3)`` int64 rows
        ``(robot, the robot's object id, team object id)`` — rows with equal team object ids
        are the same object. For evaluation only, never read by a filter; empty when unknown
        and always empty for ``global`` ids (an id is its own team object id).
    """

    name: str
    calibration: Calibration
    robots: list[RobotSequence]
    object_ids: np.ndarray
    object_positions: np.ndarray
    landmark_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    landmark_positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    track_landmarks: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    metadata: dict = field(default_factory=dict)
    sensor_model: SensorModel | None = None
    object_id_scope: str = "global"
    object_identity: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int64))

    def __post_init__(self) -> None:
        self.object_ids = np.asarray(self.object_ids, dtype=np.int64)
        self.object_positions = np.asarray(self.object_positions, dtype=float).reshape(-1, 3)
        self.landmark_ids = np.asarray(self.landmark_ids, dtype=np.int64)
        self.landmark_positions = np.asarray(self.landmark_positions, dtype=float).reshape(-1, 3)
        self.track_landmarks = np.asarray(self.track_landmarks, dtype=np.int64).reshape(-1, 2)
        self.object_identity = np.asarray(self.object_identity, dtype=np.int64).reshape(-1, 3)
        self.validate()

    def validate(self) -> None:
        """Check every field; raise :class:`DatasetError` naming the first problem."""
        if not self.robots:
            raise DatasetError("a team dataset needs at least one robot")
        for i, robot in enumerate(self.robots):
            robot.validate(f"robot {i}")
        for name, ids, pos in (
            ("object", self.object_ids, self.object_positions),
            ("landmark", self.landmark_ids, self.landmark_positions),
        ):
            if ids.ndim != 1 or pos.shape != (ids.size, 3):
                raise DatasetError(
                    f"{name}_ids {ids.shape} and {name}_positions {pos.shape} disagree"
                )
            if np.unique(ids).size != ids.size:
                raise DatasetError(f"{name}_ids contain duplicates")
            if not np.all(np.isfinite(pos)):
                raise DatasetError(f"{name}_positions contain NaN or infinite values")
        if np.unique(self.track_landmarks[:, 0]).size != len(self.track_landmarks):
            raise DatasetError("track_landmarks names a track twice")
        self._validate_identity()
        if self.sensor_model is not None:
            extra = [i for i in self.sensor_model.robots if i >= self.n_robots]
            if extra:
                raise DatasetError(f"sensor_model.robots names robot {extra[0]}, not in the team")

    def _validate_identity(self) -> None:
        if self.object_id_scope not in OBJECT_ID_SCOPES:
            raise DatasetError(
                f"object_id_scope must be one of {', '.join(OBJECT_ID_SCOPES)}, "
                f"got {self.object_id_scope!r}"
            )
        identity = self.object_identity
        if identity.ndim != 2 or identity.shape[1] != 3:
            raise DatasetError(f"object_identity must be (K, 3), got {identity.shape}")
        if self.object_id_scope == "none":
            missing = [
                i for i, r in enumerate(self.robots) if r.detections is None or r.objects.ids.size
            ]
            if missing:
                raise DatasetError(
                    f"robot {missing[0]}: a dataset without object ids needs detections and no "
                    "object observations with ids"
                )
        if not identity.size:
            return
        if self.object_id_scope != "per-robot":
            raise DatasetError("object_identity is for per-robot object ids; these ids are global")
        robots = identity[:, 0]
        if np.any((robots < 0) | (robots >= self.n_robots)):
            bad = int(robots[(robots < 0) | (robots >= self.n_robots)][0])
            raise DatasetError(f"object_identity names robot {bad}, not in the team")
        if np.unique(identity[:, :2], axis=0).shape[0] != len(identity):
            raise DatasetError("object_identity names one robot's object twice")
        if np.any(identity[:, 2] < 0):
            raise DatasetError("object_identity: team object ids must be ≥ 0")

    def true_objects(self, robot: int) -> tuple[np.ndarray, np.ndarray]:
        """Which team object each of ``robot``'s object ids is (ground truth, evaluation only).

        Returns
        -------
        ids, team_ids
            The robot's object ids and their team object ids: the robot's observed ids mapped
            to themselves for ``global`` ids, the rows of :attr:`object_identity` otherwise
            (empty when the dataset has no identity truth).
        """
        if not 0 <= robot < self.n_robots:
            raise DatasetError(f"robot {robot} is not in a team of {self.n_robots}")
        if self.object_id_scope == "global":
            ids = np.unique(self.robots[robot].objects.ids)
            return ids, ids.copy()
        rows = self.object_identity[self.object_identity[:, 0] == robot]
        return rows[:, 1].copy(), rows[:, 2].copy()

    def head(self, frames: int) -> TeamDataset:
        """The first ``frames`` frames of every robot (truth, map and sensor model kept)."""
        return replace(self, robots=[r.head(frames) for r in self.robots])

    def subset(self, robots: list[int]) -> TeamDataset:
        """The team of just ``robots`` (in that order), renumbered from 0; map and truth kept."""
        if not robots or any(not 0 <= r < self.n_robots for r in robots):
            raise DatasetError(f"robots {robots} are not a subset of a team of {self.n_robots}")
        model = self.sensor_model
        if model is not None:
            own = {new: model.robots[old] for new, old in enumerate(robots) if old in model.robots}
            model = replace(model, robots=own)
        identity = self.object_identity
        if identity.size:
            new_of = np.full(self.n_robots, -1, dtype=np.int64)
            new_of[np.asarray(robots)] = np.arange(len(robots))
            identity = identity[np.isin(identity[:, 0], robots)].copy()
            identity[:, 0] = new_of[identity[:, 0]]
        return replace(
            self,
            robots=[self.robots[r] for r in robots],
            sensor_model=model,
            object_identity=identity,
        )

    @property
    def n_robots(self) -> int:
        """Number of robots."""
        return len(self.robots)

    def object_position(self, ids: np.ndarray) -> np.ndarray:
        """Ground-truth positions of the given object ids (NaN where unknown)."""
        ids = np.asarray(ids, dtype=np.int64)
        order = np.argsort(self.object_ids)
        sorted_ids = self.object_ids[order]
        pos = np.searchsorted(sorted_ids, ids)
        pos = np.clip(pos, 0, max(sorted_ids.size - 1, 0))
        found = sorted_ids.size > 0
        out = np.full((ids.size, 3), np.nan)
        if found:
            hit = sorted_ids[pos] == ids
            out[hit] = self.object_positions[order[pos[hit]]]
        return out
