"""Reading what a team run left behind, and trajectory files, for evaluation and reports.

A run directory written by ``teamslam run --out DIR`` holds ``metrics.json`` and, per robot
``k = 1, 2, …``, ``robot_k.tum`` (the filtered estimate) and ``robot_k_groundtruth.tum``; with
``--compare`` those files are in ``separate/`` and ``consensus/`` and ``metrics.json`` is the
consensus run's with the separate run's under ``"separate"``. Each directory with the
trajectories may also hold ``series.npz`` (:func:`write_series`): per robot the pose NEES and
the time of each stage at every frame. ``run.json`` is written last: a directory without it (an
interrupted write, or not a run) is refused, naming what is missing (:func:`require_run_file`).

Trajectory files are TUM (8 numbers a line) or KITTI (12 numbers a line), told apart by their
first data line.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from teamslam.errors import InputError
from teamslam.eval.outputs import RUN_FILE
from teamslam.eval.trajectory import Trajectory
from teamslam.textio import read_npz

__all__ = [
    "STAGES",
    "TeamRun",
    "dataset_references",
    "load_runs",
    "read_series",
    "read_trajectory",
    "require_run_file",
    "write_series",
]

STAGES = ("consensus", "propagation", "update", "initialisation")
SERIES_FILE = "series.npz"
VARIANTS = ("separate", "consensus")


@dataclass
class TeamRun:
    """One team's estimate: a column of the evaluation table and of the report.

    Attributes
    ----------
    name
        Column label (``team5-run/consensus``).
    estimates
        One trajectory per robot.
    references
        The ground truth the run recorded (``None`` for bare trajectory files).
    metrics
        This run's ``metrics.json`` entries (``None`` for bare trajectory files).
    series
        Per-frame ``nees`` and ``frame_times`` per robot (``None`` if not recorded).
    directory
        Where the trajectories were read.
    shown_directory
        Where they will be, when read from a run directory still being written (staged).
    """

    name: str
    estimates: list[Trajectory]
    references: list[Trajectory] | None = None
    metrics: dict | None = None
    series: dict | None = None
    directory: Path | None = None
    shown_directory: Path | None = None


def require_run_file(directory: str | Path) -> Path:
    """``directory/run.json``, which a run directory is written with last (for ``separate/``
    or ``consensus/`` of a comparison: the comparison's).

    Raises
    ------
    InputError
        There is no such file: the directory is no run, or its write did not finish (named).
    """
    directory = Path(directory)
    path = directory / RUN_FILE
    if not path.is_file() and directory.name in VARIANTS:
        path = directory.parent / RUN_FILE
    if not path.is_file():
        raise InputError(
            f"{directory}: not a run directory (no {RUN_FILE}, which `teamslam run --out` "
            "writes last; a run whose write was interrupted has none)"
        )
    return path


def _first_data_line(path: Path) -> str:
    try:
        with path.open() as handle:
            for line in handle:
                text = line.strip()
                if text and not text.startswith("#"):
                    return text
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read trajectory ({exc})") from None
    raise InputError(f"{path}: no poses in the file")


def read_trajectory(path: str | Path, name: str = "") -> Trajectory:
    """A TUM or KITTI trajectory file (by the number of values on its first data line)."""
    from teamslam.datasets.trajectory import read_kitti, read_tum

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such trajectory file")
    width = len(_first_data_line(path).split())
    try:
        if width == 8:
            timestamps, poses = read_tum(path)
        elif width == 12:
            timestamps, poses = None, read_kitti(path)
        else:
            raise InputError(
                f"{path}: {width} values on the first line; a TUM line has 8 "
                "(t x y z qx qy qz qw), a KITTI line 12 (the 3×4 pose, row-major)"
            )
    except ValueError as exc:  # DatasetError of the readers
        raise InputError(str(exc)) from None
    return Trajectory(poses, timestamps, name or path.stem)


def _robot_files(directory: Path) -> list[tuple[Path, Path | None]]:
    out = []
    k = 0
    while (directory / f"robot_{k}.tum").is_file():
        truth = directory / f"robot_{k}_groundtruth.tum"
        out.append((directory / f"robot_{k}.tum", truth if truth.is_file() else None))
        k += 1
    return out


def write_series(directory: str | Path, nees: list[np.ndarray], frame_times: list[np.ndarray]):
    """Write ``series.npz``: per robot the pose NEES / 6 and the seconds of each stage per frame.

    Parameters
    ----------
    nees
        Per robot ``(N_i,)`` pose NEES / 6 (:func:`teamslam.eval.metrics.pose_nees`).
    frame_times
        Per robot ``(N_i, 4)`` seconds in the stages :data:`STAGES`.
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    arrays = {}
    for k, (n, t) in enumerate(zip(nees, frame_times, strict=True)):
        arrays[f"nees_{k}"] = np.asarray(n, dtype=float)
        arrays[f"frame_times_{k}"] = np.asarray(t, dtype=float).reshape(-1, len(STAGES))
    tmp = directory / (SERIES_FILE + ".tmp.npz")
    np.savez_compressed(tmp, **arrays)
    tmp.replace(directory / SERIES_FILE)


def read_series(directory: str | Path) -> dict | None:
    """``{"nees": [...], "frame_times": [...]}`` from ``series.npz``, or ``None`` if absent."""
    path = Path(directory) / SERIES_FILE
    if not path.is_file():
        return None
    try:
        arrays = read_npz(path)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read ({exc})") from None
    out: dict[str, list[np.ndarray]] = {"nees": [], "frame_times": []}
    k = 0
    while f"nees_{k}" in arrays and f"frame_times_{k}" in arrays:
        times = arrays[f"frame_times_{k}"]
        if times.ndim != 2 or times.shape[1] != len(STAGES):
            raise InputError(f"{path}: frame_times_{k} must be (N, {len(STAGES)})")
        out["nees"].append(arrays[f"nees_{k}"])
        out["frame_times"].append(times)
        k += 1
    return out


def _load_variant(directory: Path, name: str, metrics: dict | None) -> TeamRun:
    files = _robot_files(directory)
    estimates = [read_trajectory(est, f"robot {k}") for k, (est, _) in enumerate(files)]
    references = None
    if all(truth is not None for _, truth in files):
        references = [
            read_trajectory(truth, f"robot {k} ground truth") for k, (_, truth) in enumerate(files)
        ]
    return TeamRun(name, estimates, references, metrics, read_series(directory), directory)


def load_runs(spec: str | Path, label: str | None = None, writing: bool = False) -> list[TeamRun]:
    """The team runs one command-line argument names.

    * a run directory of ``teamslam run`` → one run, or two (``separate``, ``consensus``)
      if it was written with ``--compare``;
    * a trajectory file → a one-robot team;
    * trajectory files joined by commas (``a.tum,b.tum``) → one team, a robot per file.

    Parameters
    ----------
    label
        The name of a run directory's columns (default: the directory's name).
    writing
        ``spec`` is a run directory being written (its ``run.json`` comes last): read it
        without one.

    Raises
    ------
    InputError
        A directory without ``run.json`` (:func:`require_run_file`), a file that cannot be
        read (named).
    """
    text = str(spec)
    path = Path(text)
    if path.is_dir():
        if not writing:
            require_run_file(path)
        metrics = None
        if (path / "metrics.json").is_file():
            try:
                metrics = json.loads((path / "metrics.json").read_text())
            except (OSError, ValueError) as exc:
                raise InputError(f"{path / 'metrics.json'}: cannot read ({exc})") from None
            if not isinstance(metrics, dict):
                raise InputError(f"{path / 'metrics.json'}: not a JSON object")
        label = label or path.resolve().name
        variants = [v for v in VARIANTS if _robot_files(path / v)]
        if variants:
            runs = []
            for v in variants:
                m = None
                if metrics is not None:
                    if v == "separate" and isinstance(metrics.get("separate"), dict):
                        m = metrics["separate"]
                    elif v == "consensus":
                        m = {k: val for k, val in metrics.items() if k != "separate"}
                runs.append(_load_variant(path / v, f"{label}/{v}", m))
            return runs
        if _robot_files(path):
            return [_load_variant(path, label, metrics)]
        raise InputError(
            f"{path}: not a run directory (no robot_0.tum in it, nor in separate/ or consensus/)"
        )
    parts = [p for p in text.split(",") if p]
    if not parts:
        raise InputError(f"{text!r}: no run directory or trajectory file given")
    estimates = [read_trajectory(p, f"robot {k}") for k, p in enumerate(parts)]
    label = ",".join(Path(p).stem for p in parts)
    return [TeamRun(label, estimates)]


def dataset_references(directory: str | Path) -> list[Trajectory]:
    """Every robot's ground truth ``T_world_body`` (with its timestamps) in a team dataset."""
    from teamslam.datasets import load_dataset

    dataset = load_dataset(directory)
    return [
        Trajectory(r.T_world_body, r.timestamps, f"robot {k} ground truth")
        for k, r in enumerate(dataset.robots)
    ]
