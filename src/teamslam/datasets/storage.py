"""teamslam's own on-disk team-dataset format (no pickle anywhere).

A dataset is a directory: ``manifest.json`` (format, version, calibration, sensor model, robots,
metadata), one ``robot_NNN.npz`` per robot (poses, odometry, ragged observations as flat arrays
plus offsets, optional detections) and ``map.npz`` (the truth). Arrays are compressed ``.npz``
read with ``allow_pickle=False``; manifest floats round-trip bit-exactly. Loading validates
every field and names the file and field of the first problem (a negative timestamp is
refused, not shifted); writing is atomic. Older
versions still load. Field by field, and what each version added: the docs' reference page
*Dataset format*.
"""

from __future__ import annotations

import json
import shutil
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from teamslam.datasets.model import (
    OBJECT_ID_SCOPES,
    Calibration,
    DatasetError,
    FrameDetections,
    FrameObservations,
    RobotSequence,
    TeamDataset,
)
from teamslam.datasets.sensor_model import SensorModel, SensorNoise
from teamslam.geometry.camera import StereoCamera
from teamslam.textio import open_npz

__all__ = ["FORMAT_NAME", "FORMAT_VERSION", "load_dataset", "save_dataset"]

FORMAT_NAME = "teamslam-team-dataset"
FORMAT_VERSION = 5
READABLE_VERSIONS = (1, 2, 3, 4, 5)
#: The version written when no robot carries detections (what that version holds is the same).
_VERSION_WITHOUT_DETECTIONS = 3
#: The version written when detections carry neither box sizes nor appearance.
_VERSION_WITHOUT_APPEARANCE = 4
_DETECTION_FIELDS = ("classes", "scores", "truth", "sizes", "appearance")
MANIFEST = "manifest.json"


def _robot_file(i: int) -> str:
    return f"robot_{i:03d}.npz"


def _format_version(dataset: TeamDataset) -> int:
    """The oldest format version that holds ``dataset`` (older readers keep reading it)."""
    if any(r.object_appearance is not None for r in dataset.robots):
        return FORMAT_VERSION
    detections = [r.detections for r in dataset.robots if r.detections is not None]
    if not detections:
        return _VERSION_WITHOUT_DETECTIONS
    if any(d.sizes is not None or d.appearance is not None for d in detections):
        return FORMAT_VERSION
    return _VERSION_WITHOUT_APPEARANCE


def save_dataset(dataset: TeamDataset, directory: str | Path) -> Path:
    """Write ``dataset`` to ``directory`` atomically (replacing a previous dataset there).

    Returns
    -------
    pathlib.Path
        The dataset directory.
    """
    dataset.validate()
    directory = Path(directory)
    if directory.exists() and not (directory / MANIFEST).exists() and any(directory.iterdir()):
        raise DatasetError(
            f"{directory} exists and is not a teamslam dataset; refusing to replace it"
        )
    directory.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{directory.name}.", dir=directory.parent))
    try:
        cal = dataset.calibration
        manifest = {
            "format": FORMAT_NAME,
            "version": _format_version(dataset),
            "name": dataset.name,
            "calibration": {
                "K": cal.camera.intrinsics.tolist(),
                "T_left_right": cal.camera.T_left_right.tolist(),
                "T_cam_body": cal.T_cam_body.tolist(),
                "image_size": list(cal.image_size) if cal.image_size else None,
            },
            "robots": [],
            "map": "map.npz",
            "object_ids": dataset.object_id_scope,
            "metadata": dataset.metadata,
        }
        if dataset.sensor_model is not None:
            manifest["sensor_model"] = dataset.sensor_model.to_json()
        for i, robot in enumerate(dataset.robots):
            arrays = {
                "T_world_body": robot.T_world_body,
                "odometry": robot.odometry,
                "feature_offsets": robot.features.offsets,
                "feature_ids": robot.features.ids,
                "feature_measurements": robot.features.measurements,
                "object_offsets": robot.objects.offsets,
                "object_ids": robot.objects.ids,
                "object_measurements": robot.objects.measurements,
            }
            if robot.timestamps is not None:
                arrays["timestamps"] = robot.timestamps
            if robot.object_classes is not None:
                arrays["object_classes"] = robot.object_classes
            if robot.object_appearance is not None:
                arrays["object_appearance_ids"] = robot.object_appearance_ids
                arrays["object_appearance"] = robot.object_appearance
            if robot.detections is not None:
                arrays["detection_offsets"] = robot.detections.offsets
                arrays["detection_measurements"] = robot.detections.measurements
                for name in _DETECTION_FIELDS:
                    if getattr(robot.detections, name) is not None:
                        arrays[f"detection_{name}"] = getattr(robot.detections, name)
            np.savez_compressed(staging / _robot_file(i), **arrays)
            manifest["robots"].append(
                {
                    "file": _robot_file(i),
                    "frames": robot.frames,
                    "timestamps": robot.timestamps is not None,
                }
            )
        truth = {
            "object_ids": dataset.object_ids,
            "object_positions": dataset.object_positions,
            "landmark_ids": dataset.landmark_ids,
            "landmark_positions": dataset.landmark_positions,
            "track_landmarks": dataset.track_landmarks,
        }
        if dataset.object_identity.size:
            truth["object_identity"] = dataset.object_identity
        np.savez_compressed(staging / "map.npz", **truth)
        (staging / MANIFEST).write_text(json.dumps(manifest, indent=2) + "\n")
        if directory.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{directory.name}.old.", dir=directory.parent))
            old.rmdir()
            directory.replace(old)
            staging.replace(directory)
            shutil.rmtree(old, ignore_errors=True)
        else:
            staging.replace(directory)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return directory


def _matrix(value, shape: tuple[int, ...], where: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise DatasetError(f"{where} is not a numeric matrix") from None
    if arr.shape != shape or not np.all(np.isfinite(arr)):
        raise DatasetError(f"{where} must be a finite {shape} matrix")
    return arr


def _load_npz(path: Path, fields: dict[str, str], optional: tuple[str, ...] = ()) -> dict:
    """Read ``path`` with pickle disabled and check each field's dtype kind ('f' or 'i')."""
    if not path.is_file():
        raise DatasetError(f"{path}: file is missing")
    try:
        with open_npz(path) as npz:
            present = set(npz.files)
            out = {}
            for name, kind in fields.items():
                if name not in present:
                    if name in optional:
                        continue
                    raise DatasetError(f"{path}: field {name!r} is missing")
                arr = npz[name]
                if arr.dtype.kind not in (kind, "u" if kind == "i" else kind):
                    raise DatasetError(
                        f"{path}: field {name!r} has dtype {arr.dtype}, expected "
                        f"{'floating point' if kind == 'f' else 'integer'}"
                    )
                out[name] = arr
    except DatasetError:
        raise
    except (zipfile.BadZipFile, OSError, EOFError, ValueError, KeyError) as exc:
        raise DatasetError(f"{path}: cannot read ({type(exc).__name__}: {exc})") from None
    return out


def _observations(arrays: dict, prefix: str) -> FrameObservations:
    try:
        return FrameObservations(
            arrays[f"{prefix}_offsets"], arrays[f"{prefix}_ids"], arrays[f"{prefix}_measurements"]
        )
    except DatasetError as exc:
        raise DatasetError(f"{prefix}_*: {exc}") from None
    except ValueError as exc:  # measurements that cannot be reshaped to (M, 4)
        raise DatasetError(f"{prefix}_measurements: {exc}") from None


def _detections(arrays: dict, version: int) -> FrameDetections | None:
    present = [k for k in arrays if k.startswith("detection_")]
    if not present:
        return None
    if version < 4:
        raise DatasetError(f"{present[0]}: detections need format version 4, file is {version}")
    newer = [k for k in ("detection_sizes", "detection_appearance") if k in arrays]
    if newer and version < 5:
        raise DatasetError(
            f"{newer[0]}: box sizes and appearance need format version 5, file is {version}"
        )
    for name in ("detection_offsets", "detection_measurements"):
        if name not in arrays:
            raise DatasetError(f"field {name!r} is missing (the file holds {present[0]!r})")
    try:
        return FrameDetections(
            arrays["detection_offsets"],
            arrays["detection_measurements"],
            *(arrays.get(f"detection_{name}") for name in _DETECTION_FIELDS),
        )
    except DatasetError as exc:
        raise DatasetError(f"detection_*: {exc}") from None


def load_dataset(directory: str | Path) -> TeamDataset:
    """Read and validate a dataset written by :func:`save_dataset`.

    Raises
    ------
    DatasetError
        Naming the file and field of the first problem: unknown format or version, a missing
        or truncated file, wrong dtype or shape, non-finite values, ids repeated in a frame,
        non-monotone offsets, frame counts that disagree.
    """
    directory = Path(directory)
    manifest_path = directory / MANIFEST
    if not manifest_path.is_file():
        raise DatasetError(f"{directory}: no {MANIFEST}; not a teamslam dataset")
    try:
        manifest = json.loads(manifest_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DatasetError(f"{manifest_path}: not valid JSON ({exc})") from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT_NAME:
        raise DatasetError(f"{manifest_path}: format is not {FORMAT_NAME!r}")
    version = manifest.get("version")
    if version not in READABLE_VERSIONS:
        raise DatasetError(
            f"{manifest_path}: unsupported format version {version!r} "
            f"(this teamslam reads versions {', '.join(map(str, READABLE_VERSIONS))})"
        )
    try:
        cal = manifest["calibration"]
        robots_meta = manifest["robots"]
        map_file = manifest["map"]
    except (KeyError, TypeError) as exc:
        raise DatasetError(f"{manifest_path}: missing field {exc}") from None
    if not isinstance(robots_meta, list) or not robots_meta:
        raise DatasetError(f"{manifest_path}: 'robots' must be a non-empty list")
    image_size = cal.get("image_size")
    if image_size is not None and (
        not isinstance(image_size, list) or len(image_size) != 2 or min(image_size) <= 0
    ):
        raise DatasetError(f"{manifest_path}: calibration.image_size must be [width, height]")
    try:
        k = _matrix(cal["K"], (3, 3), f"{manifest_path}: calibration.K")
        t_left_right = _matrix(
            cal["T_left_right"], (4, 4), f"{manifest_path}: calibration.T_left_right"
        )
        t_cam_body = _matrix(cal["T_cam_body"], (4, 4), f"{manifest_path}: calibration.T_cam_body")
    except KeyError as exc:
        raise DatasetError(f"{manifest_path}: calibration field {exc} is missing") from None
    try:
        calibration = Calibration(
            StereoCamera(k, t_left_right),
            t_cam_body,
            tuple(int(v) for v in image_size) if image_size else None,
        )
    except ValueError as exc:
        raise DatasetError(f"{manifest_path}: calibration: {exc}") from None

    robot_fields = {
        "T_world_body": "f",
        "odometry": "f",
        "feature_offsets": "i",
        "feature_ids": "i",
        "feature_measurements": "f",
        "object_offsets": "i",
        "object_ids": "i",
        "object_measurements": "f",
        "timestamps": "f",
        "object_classes": "i",
        "object_appearance_ids": "i",
        "object_appearance": "f",
        "detection_offsets": "i",
        "detection_measurements": "f",
        "detection_classes": "i",
        "detection_scores": "f",
        "detection_truth": "i",
        "detection_sizes": "f",
        "detection_appearance": "f",
    }
    detection_fields = tuple(k for k in robot_fields if k.startswith("detection_"))
    robots = []
    for i, meta in enumerate(robots_meta):
        if not isinstance(meta, dict) or not isinstance(meta.get("file"), str):
            raise DatasetError(f"{manifest_path}: robots[{i}] must name its file")
        name = meta["file"]
        if "/" in name or "\\" in name or name.startswith("."):
            raise DatasetError(
                f"{manifest_path}: robots[{i}].file {name!r} is not a plain file name"
            )
        path = directory / name
        arrays = _load_npz(
            path,
            robot_fields,
            optional=(
                "timestamps",
                "object_classes",
                "object_appearance_ids",
                "object_appearance",
                *detection_fields,
            ),
        )
        looks = [k for k in ("object_appearance_ids", "object_appearance") if k in arrays]
        if looks and version < 5:
            raise DatasetError(
                f"{path}: field {looks[0]!r} needs format version 5, file is {version}"
            )
        if len(looks) == 1:
            raise DatasetError(
                f"{path}: field {looks[0]!r} without its partner (object_appearance_ids and "
                "object_appearance come together)"
            )
        classes = arrays.get("object_classes")
        if classes is not None and (classes.ndim != 2 or classes.shape[1] != 2):
            raise DatasetError(
                f"{path}: field 'object_classes' must be (C, 2) rows (object id, class), "
                f"got shape {classes.shape}"
            )
        try:
            robot = RobotSequence(
                T_world_body=arrays["T_world_body"],
                odometry=arrays["odometry"],
                features=_observations(arrays, "feature"),
                objects=_observations(arrays, "object"),
                timestamps=arrays.get("timestamps"),
                object_classes=classes,
                detections=_detections(arrays, version),
                object_appearance_ids=arrays.get("object_appearance_ids"),
                object_appearance=arrays.get("object_appearance"),
            )
            robot.validate(f"robot {i}")
        except DatasetError as exc:
            raise DatasetError(f"{path}: {exc}") from None
        frames = meta.get("frames")
        if frames is None:
            raise DatasetError(
                f"{manifest_path}: robots[{i}].frames is missing ({name} holds {robot.frames} "
                "frames)"
            )
        if isinstance(frames, bool) or not isinstance(frames, int):
            raise DatasetError(
                f"{manifest_path}: robots[{i}].frames must be a whole number of frames, got "
                f"{frames!r} ({name} holds {robot.frames})"
            )
        if frames != robot.frames:
            raise DatasetError(f"{path}: manifest says {frames} frames, file holds {robot.frames}")
        robots.append(robot)

    metadata = manifest.get("metadata") or {}
    if not isinstance(metadata, dict):
        raise DatasetError(f"{manifest_path}: metadata must be a mapping")
    sensor_model = None
    if "sensor_model" in manifest:
        try:
            sensor_model = SensorModel.from_json(manifest["sensor_model"], robots=len(robots))
        except DatasetError as exc:
            raise DatasetError(f"{manifest_path}: {exc}") from None
    elif version == 1:
        sensor_model = _version1_simulation_noise(metadata)

    scope = manifest.get("object_ids", "global")
    if scope not in OBJECT_ID_SCOPES:
        raise DatasetError(
            f"{manifest_path}: object_ids must be one of {', '.join(OBJECT_ID_SCOPES)}, "
            f"got {scope!r}"
        )
    map_path = directory / str(map_file)
    m = _load_npz(
        map_path,
        {
            "object_ids": "i",
            "object_positions": "f",
            "landmark_ids": "i",
            "landmark_positions": "f",
            "track_landmarks": "i",
            "object_identity": "i",
        },
        optional=("object_identity",),
    )
    identity = m.get("object_identity", np.zeros((0, 3), np.int64))
    if identity.ndim != 2 or identity.shape[1] != 3:
        raise DatasetError(
            f"{map_path}: field 'object_identity' must be (K, 3) rows (robot, object id, "
            f"team object id), got shape {identity.shape}"
        )
    try:
        return TeamDataset(
            name=str(manifest.get("name", directory.name)),
            calibration=calibration,
            robots=robots,
            object_ids=m["object_ids"],
            object_positions=m["object_positions"],
            landmark_ids=m["landmark_ids"],
            landmark_positions=m["landmark_positions"],
            track_landmarks=m["track_landmarks"],
            metadata=metadata,
            sensor_model=sensor_model,
            object_id_scope=scope,
            object_identity=identity,
        )
    except DatasetError as exc:
        raise DatasetError(f"{map_path}: {exc}") from None


def _version1_simulation_noise(metadata: dict) -> SensorModel | None:
    """A version-1 simulated team recorded its generator's noise in its metadata; keep it."""
    sim = metadata.get("simulation")
    keys = (
        "odometry_translation_noise",
        "odometry_rotation_noise",
        "pixel_noise",
        "object_pixel_noise",
        "object_max_depth",
        "min_depth",
    )
    if not isinstance(sim, dict) or not all(isinstance(sim.get(k), int | float) for k in keys):
        return None
    if min(sim[k] for k in keys) <= 0:
        return None  # a noise-free team: no noise to record
    try:
        noise = SensorNoise(
            odometry_std=(sim["odometry_translation_noise"],) * 3
            + (sim["odometry_rotation_noise"],) * 3,
            feature_std=sim["pixel_noise"],
            object_std=sim["object_pixel_noise"],
            object_depth_range=(sim["min_depth"], sim["object_max_depth"]),
        )
    except DatasetError:
        return None
    return SensorModel(noise, origin="simulation", note="generator noise (format version 1)")
