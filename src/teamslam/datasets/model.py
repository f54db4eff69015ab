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

__all__ = ["Calibration", "DatasetError", "FrameObservations", "RobotSequence", "TeamDataset"]


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
            raise DatasetError("calibration.T_cam_body must be a finite 4×4 matrix")
        if not np.allclose(t[:3, :3] @ t[:3, :3].T, np.eye(3), atol=1e-6):
            raise DatasetError("calibration.T_cam_body rotation is not orthonormal")
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
        ``(N + 1,)`` seconds, or ``None``.
    """

    T_world_body: np.ndarray
    odometry: np.ndarray
    features: FrameObservations
    objects: FrameObservations
    timestamps: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "T_world_body", np.asarray(self.T_world_body, dtype=float))
        object.__setattr__(self, "odometry", np.asarray(self.odometry, dtype=float))
        if self.timestamps is not None:
            object.__setattr__(self, "timestamps", np.asarray(self.timestamps, dtype=float))

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
        )

    def validate(self, where: str) -> None:
        """Raise :class:`DatasetError` naming ``where`` and the field on any inconsistency."""
        poses, odo = self.T_world_body, self.odometry
        if poses.ndim != 3 or poses.shape[1:] != (4, 4) or poses.shape[0] < 1:
            raise DatasetError(f"{where}.T_world_body must be (N + 1, 4, 4), got {poses.shape}")
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
            if obs.frames != n + 1:
                raise DatasetError(
                    f"{where}.{name}: {obs.frames} frames of observations for {n + 1} poses"
                )
        if self.timestamps is not None:
            ts = self.timestamps
            if ts.shape != (n + 1,) or not np.all(np.isfinite(ts)):
                raise DatasetError(f"{where}.timestamps must be ({n + 1},) finite")
            if np.any(np.diff(ts) <= 0):
                raise DatasetError(f"{where}.timestamps must increase")


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

    def __post_init__(self) -> None:
        self.object_ids = np.asarray(self.object_ids, dtype=np.int64)
        self.object_positions = np.asarray(self.object_positions, dtype=float).reshape(-1, 3)
        self.landmark_ids = np.asarray(self.landmark_ids, dtype=np.int64)
        self.landmark_positions = np.asarray(self.landmark_positions, dtype=float).reshape(-1, 3)
        self.track_landmarks = np.asarray(self.track_landmarks, dtype=np.int64).reshape(-1, 2)
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
        if self.sensor_model is not None:
            extra = [i for i in self.sensor_model.robots if i >= self.n_robots]
            if extra:
                raise DatasetError(f"sensor_model.robots names robot {extra[0]}, not in the team")

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
        return replace(self, robots=[self.robots[r] for r in robots], sensor_model=model)

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
