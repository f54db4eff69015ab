"""Trajectory files in the TUM and KITTI text formats, so results drop straight into ``evo``.

* TUM: one pose per line, ``timestamp tx ty tz qx qy qz qw`` (Hamilton quaternion, scalar last).
* KITTI: one pose per line, the first three rows of the 4×4 matrix, row-major (12 numbers).

Numbers are written with 17 significant digits, enough for float64 to round-trip exactly.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from teamslam.datasets.model import DatasetError
from teamslam.errors import InputError

__all__ = ["read_kitti", "read_tum", "write_kitti", "write_tum"]

_FMT = "%.17g"


def _poses(poses: np.ndarray) -> np.ndarray:
    poses = np.asarray(poses, dtype=float)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise InputError(f"poses must be (N, 4, 4), got {poses.shape}")
    if not np.all(np.isfinite(poses)):
        raise InputError("poses contain NaN or infinite values")
    return poses


def _atomic_savetxt(path: Path, rows: np.ndarray, header: str = "") -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    np.savetxt(tmp, rows, fmt=_FMT, header=header)
    tmp.replace(path)


def write_tum(path: str | Path, poses: np.ndarray, timestamps: np.ndarray | None = None) -> None:
    """Write ``(N, 4, 4)`` poses as a TUM file (timestamps default to the frame index)."""
    poses = _poses(poses)
    ts = np.arange(len(poses), dtype=float) if timestamps is None else np.asarray(timestamps, float)
    if ts.shape != (len(poses),):
        raise InputError(f"{len(poses)} poses but {ts.shape} timestamps")
    quat = Rotation.from_matrix(poses[:, :3, :3]).as_quat()  # x, y, z, w
    _atomic_savetxt(Path(path), np.column_stack([ts, poses[:, :3, 3], quat]))


def write_kitti(path: str | Path, poses: np.ndarray) -> None:
    """Write ``(N, 4, 4)`` poses as a KITTI file."""
    poses = _poses(poses)
    _atomic_savetxt(Path(path), poses[:, :3, :].reshape(len(poses), 12))


def _read_rows(path: Path, width: int, what: str) -> np.ndarray:
    try:
        rows = np.loadtxt(path, ndmin=2, comments="#")
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: cannot read {what} trajectory ({exc})") from None
    if rows.size == 0:
        return np.zeros((0, width))
    if rows.shape[1] != width:
        raise DatasetError(f"{path}: {what} lines need {width} numbers, found {rows.shape[1]}")
    if not np.all(np.isfinite(rows)):
        raise DatasetError(f"{path}: non-finite values")
    return rows


def read_tum(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a TUM file: ``(timestamps (N,), poses (N, 4, 4))``."""
    rows = _read_rows(Path(path), 8, "TUM")
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, 3] = rows[:, 1:4]
    if len(rows):
        poses[:, :3, :3] = Rotation.from_quat(rows[:, 4:8]).as_matrix()
    return rows[:, 0], poses


def read_kitti(path: str | Path) -> np.ndarray:
    """Read a KITTI file: ``(N, 4, 4)`` poses."""
    rows = _read_rows(Path(path), 12, "KITTI")
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :] = rows.reshape(-1, 3, 4)
    return poses
