"""A run's estimates on disk: what the trajectory files leave out (covariances, the map).

``estimates.npz`` (compressed numpy, read with ``allow_pickle=False``) holds per robot ``i``
``robot_<i>_poses``, ``robot_<i>_pose_covs``, ``robot_<i>_stamps_ns``, optionally
``robot_<i>_ground_truth``, and the final map ``robot_<i>_object_ids``, ``robot_<i>_objects``
and (when kept) ``robot_<i>_object_covs``; ``meta`` is a JSON string (dataset name, robot count,
whether stamps are the dataset's).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from teamslam.errors import InputError
from teamslam.textio import read_npz

__all__ = ["RobotEstimates", "load_estimates", "robot_estimates", "save_estimates", "stamps_ns"]

FILENAME = "estimates.npz"


@dataclass
class RobotEstimates:
    """One robot's estimates of one run (see the module docstring for the fields)."""

    poses: np.ndarray
    pose_covs: np.ndarray
    stamps_ns: np.ndarray
    object_ids: np.ndarray
    objects: np.ndarray
    object_covs: np.ndarray | None = None
    ground_truth: np.ndarray | None = None


def stamps_ns(timestamps: np.ndarray | None, frames: int, period: float) -> np.ndarray:
    """Integer nanosecond stamps: ``timestamps`` (seconds) or ``frame index × period``."""
    if timestamps is None:
        if not (np.isfinite(period) and period > 0):
            raise InputError(f"period must be a positive number of seconds, got {period}")
        return np.rint(np.arange(frames) * (period * 1e9)).astype(np.int64)
    return np.rint(np.asarray(timestamps, dtype=float) * 1e9).astype(np.int64)


def has_ground_truth(dataset) -> bool:
    """Whether ``dataset.T_world_body`` is ground truth (an imported bag may have none)."""
    return bool(dataset.metadata.get("ground_truth", True))


def robot_estimates(dataset, result, period: float = 1.0) -> list[RobotEstimates]:
    """Per-robot estimates of a :class:`~teamslam.msckf.team.TeamResult` over ``dataset``."""
    gt = has_ground_truth(dataset)
    covs = getattr(result, "object_covs", None) or [None] * len(result.poses)
    return [
        RobotEstimates(
            poses=np.asarray(result.poses[i]),
            pose_covs=np.asarray(result.pose_covs[i]),
            stamps_ns=stamps_ns(robot.timestamps, robot.frames, period),
            object_ids=np.asarray(result.object_ids[i], dtype=np.int64),
            objects=np.asarray(result.objects[i], dtype=float).reshape(-1, 3),
            object_covs=None if covs[i] is None else np.asarray(covs[i]).reshape(-1, 3, 3),
            ground_truth=robot.T_world_body if gt else None,
        )
        for i, robot in enumerate(dataset.robots)
    ]


def save_estimates(path: str | Path, dataset, result, period: float = 1.0) -> Path:
    """Write ``estimates.npz`` of ``result`` (a run over ``dataset``) atomically to ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays: dict[str, np.ndarray] = {}
    robots = robot_estimates(dataset, result, period)
    for i, r in enumerate(robots):
        for name in ("poses", "pose_covs", "stamps_ns", "object_ids", "objects"):
            arrays[f"robot_{i}_{name}"] = getattr(r, name)
        if r.object_covs is not None:
            arrays[f"robot_{i}_object_covs"] = r.object_covs
        if r.ground_truth is not None:
            arrays[f"robot_{i}_ground_truth"] = r.ground_truth
    meta = {
        "dataset": dataset.name,
        "robots": len(robots),
        "stamps": "dataset timestamps"
        if all(r.timestamps is not None for r in dataset.robots)
        else f"frame index x {period} s",
    }
    arrays["meta"] = np.array(json.dumps(meta))
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, path)
    return path


def load_estimates(path: str | Path) -> tuple[dict, list[RobotEstimates]]:
    """``(meta, robots)`` from an ``estimates.npz``; a malformed file raises InputError."""
    path = Path(path)
    try:
        arrays = read_npz(path)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a readable estimates file ({exc})") from None
    if "meta" not in arrays:
        raise InputError(f"{path}: no 'meta' entry")
    meta = json.loads(str(arrays["meta"]))
    robots = []
    for i in range(int(meta.get("robots", 0))):
        try:
            r = RobotEstimates(
                poses=arrays[f"robot_{i}_poses"],
                pose_covs=arrays[f"robot_{i}_pose_covs"],
                stamps_ns=arrays[f"robot_{i}_stamps_ns"],
                object_ids=arrays[f"robot_{i}_object_ids"],
                objects=arrays[f"robot_{i}_objects"],
                object_covs=arrays.get(f"robot_{i}_object_covs"),
                ground_truth=arrays.get(f"robot_{i}_ground_truth"),
            )
        except KeyError as exc:
            raise InputError(f"{path}: robot {i} lacks {exc.args[0]}") from None
        n = r.poses.shape[0]
        if r.poses.shape != (n, 4, 4) or r.pose_covs.shape != (n, 6, 6):
            raise InputError(f"{path}: robot {i} poses {r.poses.shape}, covs {r.pose_covs.shape}")
        if r.stamps_ns.shape != (n,) or (n > 1 and np.any(np.diff(r.stamps_ns) <= 0)):
            raise InputError(f"{path}: robot {i} stamps must be ({n},) and increasing")
        m = r.object_ids.size
        if r.objects.shape != (m, 3) or (
            r.object_covs is not None and r.object_covs.shape != (m, 3, 3)
        ):
            raise InputError(f"{path}: robot {i} map arrays disagree with its {m} ids")
        if r.ground_truth is not None and r.ground_truth.shape != (n, 4, 4):
            raise InputError(f"{path}: robot {i} ground truth {r.ground_truth.shape}")
        for name in ("poses", "pose_covs", "objects"):
            if not np.all(np.isfinite(getattr(r, name))):
                raise InputError(f"{path}: robot {i} {name} not finite")
        robots.append(r)
    return meta, robots
