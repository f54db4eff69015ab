"""Importer for the data published with the distributed-MSCKF paper (KITTI 00 and simulated teams).

The published pickles are read by :class:`RestrictedUnpickler`, which resolves exactly the four
numpy globals they reference and refuses every other global with :class:`UnsafePickleError`
before anything is called; ``.npz`` files are read with ``allow_pickle=False``. The simulated
sets store the inverse relative pose (``inverted_odometry=True``). A publisher's ``params.yaml``
(:func:`read_reference_params`) gives the noise levels, used by the published code as
variances (``W = q·I₆``, ``V = r·I₄``, so σ = √q and √r). :func:`export_reference` writes a team
in the published layout.
"""

from __future__ import annotations

import io
import pickle
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from teamslam.datasets.model import (
    OBJECT_ID_SCOPES,
    Calibration,
    DatasetError,
    FrameObservations,
    RobotSequence,
    TeamDataset,
)
from teamslam.datasets.sensor_model import SensorModel, SensorNoise
from teamslam.geometry import se3
from teamslam.geometry.camera import StereoCamera
from teamslam.textio import open_npz, read_yaml

__all__ = [
    "RestrictedUnpickler",
    "UnsafePickleError",
    "export_reference",
    "import_reference",
    "read_reference_params",
    "safe_unpickle",
]


class UnsafePickleError(DatasetError):
    """A pickle asked for something other than the allowed numpy classes."""


def _allowed_globals() -> dict[tuple[str, str], Any]:
    try:
        from numpy._core import multiarray  # numpy ≥ 2
    except ImportError:  # pragma: no cover - numpy < 2
        from numpy.core import multiarray  # type: ignore[no-redef]
    allowed = {
        ("numpy", "ndarray"): np.ndarray,
        ("numpy", "dtype"): np.dtype,
    }
    for module in ("numpy.core.multiarray", "numpy._core.multiarray"):
        allowed[(module, "_reconstruct")] = multiarray._reconstruct
        allowed[(module, "scalar")] = multiarray.scalar
    return allowed


class RestrictedUnpickler(pickle.Unpickler):
    """An unpickler that can build numpy arrays and scalars and nothing else."""

    _ALLOWED = _allowed_globals()

    def find_class(self, module: str, name: str) -> Any:
        try:
            return self._ALLOWED[(module, name)]
        except KeyError:
            raise UnsafePickleError(
                f"pickle refers to {module}.{name}, which is not an allowed numpy class"
            ) from None

    def persistent_load(self, pid: Any) -> Any:
        raise UnsafePickleError("pickle uses persistent ids, which are not allowed")


def safe_unpickle(path: str | Path) -> Any:
    """Load a pickle allowing only numpy arrays, dtypes and scalars (and plain containers)."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise DatasetError(f"{path}: cannot read ({exc})") from None
    try:
        return RestrictedUnpickler(io.BytesIO(data)).load()
    except UnsafePickleError as exc:
        raise UnsafePickleError(f"{path}: {exc}") from None
    except Exception as exc:  # malformed pickles raise many types
        raise DatasetError(f"{path}: not a readable pickle ({type(exc).__name__}: {exc})") from None


def _load_npz_list(path: Path) -> list[np.ndarray]:
    if not path.is_file():
        raise DatasetError(f"{path}: file is missing")
    try:
        with open_npz(path) as npz:
            names = sorted(npz.files, key=lambda s: int(s.split("_")[-1]))
            return [np.asarray(npz[n], dtype=float) for n in names]
    except (zipfile.BadZipFile, OSError, EOFError, ValueError) as exc:
        raise DatasetError(f"{path}: cannot read ({type(exc).__name__}: {exc})") from None


def _frames(messages: Any, path: Path, robots: int) -> list[FrameObservations]:
    if not isinstance(messages, list) or len(messages) != robots:
        raise DatasetError(f"{path}: expected a list over {robots} robots")
    out = []
    for i, frames in enumerate(messages):
        if not isinstance(frames, list):
            raise DatasetError(f"{path}: robot {i} is not a list over frames")
        parsed = []
        for k, frame in enumerate(frames):
            if not isinstance(frame, Mapping):
                raise DatasetError(f"{path}: robot {i} frame {k} is not a dict")
            ids, rows = [], []
            for key, value in frame.items():
                z = np.asarray(value, dtype=float).ravel()
                if z.shape != (4,):
                    raise DatasetError(f"{path}: robot {i} frame {k} id {key}: not 4 numbers")
                ids.append(int(key))
                rows.append(z)
            parsed.append((np.array(ids, dtype=np.int64), np.array(rows).reshape(-1, 4)))
        try:
            out.append(FrameObservations.from_frames(parsed))
        except DatasetError as exc:
            raise DatasetError(f"{path}: robot {i}: {exc}") from None
    return out


def read_reference_params(path: str | Path) -> SensorModel:
    """A publisher's parameter file (``params.yaml``) as a sensor model (see the module
    docstring for the conversion from variances to σ)."""
    path = Path(path)
    data = read_yaml(path, DatasetError)
    if not isinstance(data, Mapping):
        raise DatasetError(f"{path}: expected 'name: value' lines")

    def variance_std(key: str) -> float | None:
        if key not in data:
            return None
        value = data[key]
        if isinstance(value, bool) or not isinstance(value, int | float) or not value > 0:
            raise DatasetError(f"{path}: {key} must be a positive variance, got {value!r}")
        return float(np.sqrt(value))

    motion = variance_std("motion_noise")
    depth = None
    if "obj_init_dist_min_thre" in data or "obj_init_dist_max_thre" in data:
        try:
            depth = (float(data["obj_init_dist_min_thre"]), float(data["obj_init_dist_max_thre"]))
        except (KeyError, TypeError, ValueError):
            raise DatasetError(
                f"{path}: obj_init_dist_min_thre and obj_init_dist_max_thre must both be numbers"
            ) from None
    try:
        noise = SensorNoise(
            odometry_std=None if motion is None else (motion,) * 6,
            feature_std=variance_std("geo_obs_noise"),
            object_std=variance_std("obj_obs_noise"),
            object_depth_range=depth,
        )
    except DatasetError as exc:
        raise DatasetError(f"{path}: {exc}") from None
    note = (
        f"{path.name}: variances converted to σ (odometry √motion_noise on every axis, "
        "features √geo_obs_noise, objects √obj_obs_noise)"
    )
    return SensorModel(noise, origin="params file", note=note)


def export_reference(
    dataset: TeamDataset, directory: str | Path, inverted_odometry: bool = False
) -> Path:
    """Write ``dataset`` in the published layout (pickles + ``.npz``; no noise levels).

    Object ids are written as ``numpy.int64`` keys and the object truth as a dict, geometric
    tracks (when any) as ``geo_features_messages``; ``inverted_odometry`` stores
    ``T_{k+1}⁻¹ T_k`` as the published simulated teams do.
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    cal = dataset.calibration
    calib = {
        "opt_T_b": cal.T_cam_body,
        "K_mono": cal.camera.intrinsics,
        "o0To1": cal.camera.T_left_right,
        "fsu_b": np.float64(cal.camera.fx_baseline),
    }
    (directory / "calib").write_bytes(pickle.dumps(calib))
    odometry = [r.odometry for r in dataset.robots]
    if inverted_odometry:
        odometry = [se3.inverse(o) for o in odometry]
    np.savez(directory / "inputs.npz", *odometry)
    np.savez(directory / "poses.npz", *[r.T_world_body for r in dataset.robots])

    def messages(kind: str) -> list:
        out = []
        for robot in dataset.robots:
            obs = getattr(robot, kind)
            frames = []
            for k in range(obs.frames):
                ids, z = obs.frame(k)
                frames.append({np.int64(i): row.copy() for i, row in zip(ids, z, strict=True)})
            out.append(frames)
        return out

    (directory / "obj_features_messages").write_bytes(pickle.dumps(messages("objects")))
    if any(r.features.ids.size for r in dataset.robots):
        (directory / "geo_features_messages").write_bytes(pickle.dumps(messages("features")))
    truth = {
        np.int64(i): p.copy()
        for i, p in zip(dataset.object_ids, dataset.object_positions, strict=True)
    }
    (directory / "obj_features_gt").write_bytes(pickle.dumps(truth))
    return directory


def import_reference(
    source: str | Path,
    inverted_odometry: bool = False,
    name: str | None = None,
    params: str | Path | None = None,
    object_ids: str = "global",
    seed: int = 0,
) -> TeamDataset:
    """Read a published distributed-MSCKF data directory into a :class:`TeamDataset`.

    Parameters
    ----------
    source
        Directory holding ``calib``, ``inputs.npz``, ``poses.npz``, ``obj_features_messages``,
        ``obj_features_gt`` and optionally ``geo_features_messages``.
    inverted_odometry
        Invert each relative pose of ``inputs.npz`` (the published simulated teams store
        ``T_{k+1}⁻¹ T_k``; KITTI stores ``T_k⁻¹ T_{k+1}``).
    name
        Dataset name (default: the directory name).
    params
        A publisher's parameter file: its noise levels become the dataset's sensor model
        (origin ``params file``; :func:`read_reference_params`). Without it the dataset has
        no sensor model, and ``teamslam run`` calibrates one from the data.
    object_ids
        ``"global"`` (default): the published ids are team-wide, as the publishers made them
        (instance annotations). ``"per-robot"``: each robot's objects are renumbered on their
        own (:func:`~teamslam.datasets.identity.strip_object_ids`), and which of them are the
        same object is kept as ground truth only.
    seed
        Seed of the renumbering with ``object_ids="per-robot"``.
    """
    if object_ids not in OBJECT_ID_SCOPES:
        raise DatasetError(
            f"object_ids must be one of {', '.join(OBJECT_ID_SCOPES)}, got {object_ids!r}"
        )
    source = Path(source)
    if not source.is_dir():
        raise DatasetError(f"{source}: not a directory")
    sensor_model = read_reference_params(params) if params is not None else None
    calib = safe_unpickle(source / "calib")
    if not isinstance(calib, Mapping):
        raise DatasetError(f"{source / 'calib'}: expected a dict")
    try:
        k = np.asarray(calib["K_mono"], dtype=float)
        t_left_right = np.asarray(calib["o0To1"], dtype=float)
        t_cam_body = np.asarray(calib["opt_T_b"], dtype=float)
    except KeyError as exc:
        raise DatasetError(f"{source / 'calib'}: field {exc} is missing") from None
    try:
        calibration = Calibration(StereoCamera(k, t_left_right), t_cam_body)
    except ValueError as exc:
        raise DatasetError(f"{source / 'calib'}: {exc}") from None

    odometry = _load_npz_list(source / "inputs.npz")
    poses = _load_npz_list(source / "poses.npz")
    if len(odometry) != len(poses):
        raise DatasetError(
            f"{source}: inputs.npz has {len(odometry)} robots, poses.npz has {len(poses)}"
        )
    robots = len(poses)
    if inverted_odometry:
        odometry = [se3.inverse(o) for o in odometry]
    objects = _frames(
        safe_unpickle(source / "obj_features_messages"), source / "obj_features_messages", robots
    )
    geo_path = source / "geo_features_messages"
    if geo_path.exists():
        features = _frames(safe_unpickle(geo_path), geo_path, robots)
    else:
        features = [FrameObservations.empty(p.shape[0]) for p in poses]

    truth = safe_unpickle(source / "obj_features_gt")
    if isinstance(truth, Mapping):
        truth_ids = np.array([int(i) for i in truth], dtype=np.int64)
        object_positions = np.array([np.asarray(v, dtype=float).ravel() for v in truth.values()])
    elif isinstance(truth, np.ndarray) and truth.ndim == 2 and truth.shape[1] == 3:
        truth_ids = np.arange(truth.shape[0], dtype=np.int64)
        object_positions = truth.astype(float)
    else:
        raise DatasetError(f"{source / 'obj_features_gt'}: expected a dict or an (M, 3) array")

    sequences = []
    for i in range(robots):
        seq = RobotSequence(poses[i], odometry[i], features[i], objects[i])
        try:
            seq.validate(f"robot {i}")
        except DatasetError as exc:
            raise DatasetError(f"{source}: {exc}") from None
        sequences.append(seq)
    dataset = TeamDataset(
        name=name or source.name,
        calibration=calibration,
        robots=sequences,
        object_ids=truth_ids,
        object_positions=object_positions.reshape(-1, 3),
        metadata={
            "source": "distributed-MSCKF published data",
            "source_directory": source.name,
            "inverted_odometry": inverted_odometry,
            "geometric_features": geo_path.exists(),
        },
        sensor_model=sensor_model,
    )
    if object_ids == "per-robot":
        from teamslam.datasets.identity import strip_object_ids

        dataset = strip_object_ids(dataset, seed=seed)
    return dataset
