"""The Victoria Park dataset as split into two robots by the FEJ multi-robot EKF paper (§4.2).

Source files (MATLAB v5, read with ``scipy.io.loadmat``):

* ``Zstate_VicPark_6898_loops.mat`` — every measurement of the single-robot run, one scalar a
  row ``[value, type, id, pose]`` (type 1: odometry ``dx, dy, dθ`` from ``pose`` to ``id``;
  type 2: observation ``x forward, y left`` of landmark ``id`` from ``pose``);
* ``CovMatrixInv_VicPark_6898_loops.mat`` — the block-diagonal information matrix of those rows;
* ``VicP_Parameters.mat`` — the reference solution (the unweighted batch Gauss–Newton of the
  whole run: poses and features) in the split's numbering.

Robot 1 is poses 719–3264 and robot 2 poses 3265–5810 of the original run, each renumbered
0..2545; each measurement keeps its own covariance (the inverse of its information block).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from teamslam.datasets.model import DatasetError

__all__ = ["PAPER_SPLIT", "VictoriaParkRobot", "VictoriaParkSplit", "load_victoria_park"]

PAPER_SPLIT = ((719, 3264), (3265, 5810))


@dataclass
class VictoriaParkRobot:
    """One robot's part of the split.

    Attributes
    ----------
    odometry, odometry_cov
        ``(K, 3)`` odometry ``(dx, dy, dθ)`` from step ``k`` to ``k + 1`` and ``(K, 3, 3)`` its
        covariance.
    obs_step, obs_feature, obs_z, obs_cov
        Observations: step, feature id, ``(x forward, y left)`` and ``(M, 2, 2)`` covariance.
    reference_poses
        ``(K + 1, 3)`` reference poses ``(x, y, φ)``.
    """

    odometry: np.ndarray
    odometry_cov: np.ndarray
    obs_step: np.ndarray
    obs_feature: np.ndarray
    obs_z: np.ndarray
    obs_cov: np.ndarray
    reference_poses: np.ndarray

    @property
    def steps(self) -> int:
        """Motion steps ``K``."""
        return self.odometry.shape[0]


@dataclass
class VictoriaParkSplit:
    """Both robots plus the reference feature map (``feature_ids`` ↔ ``reference_features``)."""

    robots: list[VictoriaParkRobot]
    feature_ids: np.ndarray
    reference_features: np.ndarray


def _loadmat(path: Path, names: tuple[str, ...]) -> dict:
    import scipy.io

    if not path.is_file():
        raise DatasetError(f"{path}: file is missing")
    try:
        data = scipy.io.loadmat(path)
    except (OSError, ValueError, NotImplementedError, TypeError) as exc:
        raise DatasetError(f"{path}: cannot read MATLAB file ({exc})") from None
    missing = [n for n in names if n not in data]
    if missing:
        raise DatasetError(f"{path}: variable(s) {', '.join(missing)} missing")
    return data


def _blocks(info, starts: np.ndarray, size: int) -> np.ndarray:
    """Covariances: inverses of the ``size×size`` diagonal information blocks at ``starts``."""
    blocks = np.empty((starts.size, size, size))
    for a in range(size):
        for b in range(size):
            blocks[:, a, b] = np.asarray(info[starts + a, starts + b]).ravel()
    try:
        return np.linalg.inv(blocks)
    except np.linalg.LinAlgError:
        raise DatasetError("an information block of the Victoria Park data is singular") from None


def _interleaved(arr: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray]:
    """Rows ``[key, x]``, ``[key, y]`` → (keys, (n, 2))."""
    arr = np.asarray(arr, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] % 2:
        raise DatasetError(f"{what} must have an even number of rows [key, value]")
    keys = arr[0::2, 0]
    if not np.array_equal(keys, arr[1::2, 0]):
        raise DatasetError(f"{what}: x and y rows do not pair up")
    return keys.astype(np.int64), np.column_stack([arr[0::2, 1], arr[1::2, 1]])


def load_victoria_park(
    directory: str | Path, split: tuple[tuple[int, int], ...] = PAPER_SPLIT
) -> VictoriaParkSplit:
    """Read the data in ``directory`` and split it into robots (default: the paper's split)."""
    directory = Path(directory)
    z = _loadmat(directory / "Zstate_VicPark_6898_loops.mat", ("Zstate",))["Zstate"]
    info = _loadmat(directory / "CovMatrixInv_VicPark_6898_loops.mat", ("CovMatrixInv",))[
        "CovMatrixInv"
    ]
    names = (
        *(f"R{i + 1}{n}" for i in range(len(split)) for n in ("XrTrue", "XphiT")),
        "XfTrueAll",
    )
    params = _loadmat(directory / "VicP_Parameters.mat", names)
    z = np.asarray(z, dtype=float)
    if z.ndim != 2 or z.shape[1] != 4 or not np.all(np.isfinite(z)):
        raise DatasetError("Zstate must be a finite (rows, 4) array")
    if info.shape != (z.shape[0], z.shape[0]):
        raise DatasetError("CovMatrixInv does not match the rows of Zstate")
    info = info.tocsr()
    kind = z[:, 1].astype(int)
    odo_rows = np.flatnonzero(kind == 1)
    obs_rows = np.flatnonzero(kind == 2)
    if odo_rows.size % 3 or obs_rows.size % 2:
        raise DatasetError("Zstate odometry rows must come in threes and observations in pairs")
    odo_start = odo_rows[0::3]
    obs_start = obs_rows[0::2]
    odo_from = z[odo_start, 3].astype(np.int64)
    obs_pose = z[obs_start, 3].astype(np.int64)

    robots = []
    for i, (first, last) in enumerate(split):
        sel = (odo_from >= first) & (odo_from < last)
        starts = odo_start[sel]
        order = np.argsort(odo_from[sel])
        starts = starts[order]
        if starts.size != last - first:
            raise DatasetError(
                f"robot {i + 1}: expected {last - first} odometry steps, found {starts.size}"
            )
        odometry = np.column_stack([z[starts + a, 0] for a in range(3)])
        sel = (obs_pose >= first) & (obs_pose <= last)
        ostarts = obs_start[sel]
        _, positions = _interleaved(params[f"R{i + 1}XrTrue"], f"R{i + 1}XrTrue")
        heading = np.asarray(params[f"R{i + 1}XphiT"], dtype=float)
        reference = np.column_stack([positions, heading[:, 1]])
        if reference.shape[0] != last - first + 1:
            raise DatasetError(f"robot {i + 1}: reference has {reference.shape[0]} poses")
        robots.append(
            VictoriaParkRobot(
                odometry=odometry,
                odometry_cov=_blocks(info, starts, 3),
                obs_step=obs_pose[sel] - first,
                obs_feature=z[ostarts, 2].astype(np.int64),
                obs_z=np.column_stack([z[ostarts, 0], z[ostarts + 1, 0]]),
                obs_cov=_blocks(info, ostarts, 2),
                reference_poses=reference,
            )
        )
    ids, feats = _interleaved(params["XfTrueAll"], "XfTrueAll")
    return VictoriaParkSplit(robots, ids, feats)
