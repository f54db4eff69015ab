"""Importer for the data published with the distributed-MSCKF paper (KITTI 00 and simulated teams).

The published files are Python pickles and ``.npz`` archives. Unpickling an untrusted file can
run arbitrary code, so :class:`RestrictedUnpickler` resolves exactly the four numpy globals the
published pickles reference — ``numpy.core.multiarray._reconstruct``,
``numpy.core.multiarray.scalar``, ``numpy.ndarray``, ``numpy.dtype`` (also under their numpy ≥ 2
module name ``numpy._core.multiarray``, which are the same objects) — and refuses every other
global with :class:`UnsafePickleError` *before* anything is called. ``.npz`` files are read
with ``allow_pickle=False``.

Files of a published set (see the data README): ``calib``, ``inputs.npz`` (odometry),
``poses.npz`` (ground truth), ``obj_features_messages``, ``obj_features_gt`` and, when
available, ``geo_features_messages``. The simulated sets store the *inverse* relative pose in
``inputs.npz`` (``inverted_odometry=True``) and object truth as an ``(M, 3)`` array indexed by id.
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
    Calibration,
    DatasetError,
    FrameObservations,
    RobotSequence,
    TeamDataset,
)
from teamslam.geometry import se3
from teamslam.geometry.camera import StereoCamera

__all__ = ["RestrictedUnpickler", "UnsafePickleError", "import_reference", "safe_unpickle"]


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
        with np.load(path, allow_pickle=False) as npz:
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


def import_reference(
    source: str | Path,
    inverted_odometry: bool = False,
    name: str | None = None,
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
    """
    source = Path(source)
    if not source.is_dir():
        raise DatasetError(f"{source}: not a directory")
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
        object_ids = np.array([int(i) for i in truth], dtype=np.int64)
        object_positions = np.array([np.asarray(v, dtype=float).ravel() for v in truth.values()])
    elif isinstance(truth, np.ndarray) and truth.ndim == 2 and truth.shape[1] == 3:
        object_ids = np.arange(truth.shape[0], dtype=np.int64)
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
    return TeamDataset(
        name=name or source.name,
        calibration=calibration,
        robots=sequences,
        object_ids=object_ids,
        object_positions=object_positions.reshape(-1, 3),
        metadata={
            "source": "distributed-MSCKF published data",
            "source_directory": source.name,
            "inverted_odometry": inverted_odometry,
            "geometric_features": geo_path.exists(),
        },
    )
