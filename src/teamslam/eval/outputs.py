"""Writing a team run's results: metrics.json, TUM trajectories, estimates, results, figures.

A run directory holds ``metrics.json`` and, per run (the directory itself, or ``separate/`` and
``consensus/`` for a comparison): ``robot_k.tum`` and ``robot_k_groundtruth.tum`` per robot,
``estimates.npz`` (:mod:`teamslam.eval.estimates`) and the run's
:class:`~teamslam.msckf.team.TeamResult` (``result.npz``, ``result.json``,
:func:`~teamslam.msckf.team.save_result`); then the top-view and error figures, and last
``run.json`` (:data:`RUN_FILE`: what ran, and ``complete``).

A run directory is written whole or not at all (:func:`stage_run_directory`,
:class:`~teamslam.staging.StagedDirectory`): into a staging folder beside it, moved into place
at the end. A target that is a file, or a non-empty directory without ``run.json``, is refused;
an earlier run is replaced (entirely) only when asked. Readers refuse a directory without
``run.json`` (:func:`teamslam.eval.runs.require_run_file`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from teamslam.errors import InputError, OutputError
from teamslam.staging import StagedDirectory

__all__ = [
    "RUN_FILE",
    "check_run_directory",
    "json_safe",
    "run_prefix",
    "stage_run_directory",
    "write_json",
    "write_partial_outputs",
    "write_team_outputs",
    "writing",
]


def json_safe(value):
    """NaN and infinities become ``null`` (strict JSON has no NaN)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    return value


@contextmanager
def writing(path: Path) -> Iterator[None]:
    """Turn an ``OSError`` while writing ``path`` into an :class:`OutputError` naming it."""
    try:
        yield
    except OutputError:
        raise
    except OSError as exc:
        where = exc.filename or path
        raise OutputError(f"cannot write {where}: {exc.strerror or exc}") from exc


def write_json(path: Path, payload: dict) -> None:
    """Write JSON atomically: a partial file never replaces a complete one.

    Raises
    ------
    OutputError
        The file cannot be written (named).
    """
    with writing(path):
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(path.suffix + ".tmp")
        tmp.write_text(json.dumps(json_safe(payload), indent=2, sort_keys=True) + "\n")
        tmp.replace(path)


#: The file a run directory is written with last: a directory without it is no run.
RUN_FILE = "run.json"


def _refusal(out: Path, overwrite: bool) -> str | None:
    """Why ``out`` cannot take a run directory (``None``: it can)."""
    if (out.exists() or out.is_symlink()) and not out.is_dir():
        return f"{out} exists and is not a directory; the run needs a directory there"
    if not out.is_dir():
        blocked = next((p for p in out.parents if p.exists() or p.is_symlink()), None)
        if blocked is not None and not blocked.is_dir():
            return f"{blocked} exists and is not a directory; cannot make {out} in it"
        return None
    try:
        empty = next(out.iterdir(), None) is None
    except OSError as exc:
        return f"{out}: cannot read ({exc.strerror or exc})"
    if empty:
        return None
    if not (out / RUN_FILE).is_file():
        return (
            f"{out} is not empty and holds no {RUN_FILE} (not a teamslam run); refusing to "
            "replace it — choose another directory"
        )
    if not overwrite:
        return f"{out} holds an earlier run; refusing to replace it without --overwrite"
    return None


def stage_run_directory(out: str | Path, overwrite: bool = False) -> StagedDirectory:
    """The staging folder of the run directory ``out``, created now (before any data is read).

    Raises
    ------
    InputError
        ``out`` is a file, a non-empty directory that is no run, an earlier run without
        ``overwrite``, or its parent cannot be written (each named).
    """
    out = Path(out)
    reason = _refusal(out, overwrite)
    if reason is not None:
        raise InputError(reason)
    try:
        return StagedDirectory(out)
    except OSError as exc:
        where = exc.filename or out.parent
        raise InputError(
            f"{out}: cannot write a run directory there ({where}: {exc.strerror or exc})"
        ) from None


def check_run_directory(out: str | Path, overwrite: bool = False) -> None:
    """Check that ``out`` can take a run directory (:func:`stage_run_directory`, nothing left
    behind).

    Raises
    ------
    InputError
        As :func:`stage_run_directory`.
    """
    stage_run_directory(out, overwrite).discard()


def run_prefix(out: Path, name: str, names: list[str]) -> Path:
    """Where run ``name`` of the runs ``names`` writes its files in the directory ``out``."""
    return out if len(names) == 1 else out / name


def _write_trajectories(prefix: Path, dataset, result) -> None:
    """Each robot's estimate and ground truth over the frames the result holds."""
    from teamslam.datasets import write_tum

    for i, robot in enumerate(dataset.robots):
        n = min(robot.frames, len(result.poses[i]))
        if n == 0:
            continue
        stamps = None if robot.timestamps is None else robot.timestamps[:n]
        write_tum(prefix / f"robot_{i}.tum", result.poses[i][:n], stamps)
        write_tum(prefix / f"robot_{i}_groundtruth.tum", robot.T_world_body[:n], stamps)


def write_team_outputs(out: Path, dataset, results: dict, payload: dict) -> None:
    """``metrics.json`` (``payload``), per run its TUM trajectories (estimate and truth),
    ``estimates.npz`` and result files, and the top-view and error figures.

    Raises
    ------
    OutputError
        Something cannot be written (named).
    """
    from teamslam.eval.estimates import save_estimates
    from teamslam.eval.plots import plot_team_errors, plot_team_topview
    from teamslam.msckf.team import save_result

    out = Path(out)
    write_json(out / "metrics.json", payload)
    names = list(results)
    with writing(out):
        for name, result in results.items():
            prefix = run_prefix(out, name, names)
            save_estimates(prefix / "estimates.npz", dataset, result)
            _write_trajectories(prefix, dataset, result)
            save_result(result, prefix)
        plot_team_topview(dataset, results, out / "topview.png")
        plot_team_errors(dataset, results, out / "errors.png")


def write_partial_outputs(out: Path, dataset, results: dict, names: list[str]) -> None:
    """What runs that stopped early computed: per run its result files (``complete: false``)
    and the TUM trajectories of the frames done; ``names`` are every run that was asked for
    (so the layout is that of the full run)."""
    from teamslam.msckf.team import save_result

    out = Path(out)
    with writing(out):
        for name, result in results.items():
            prefix = run_prefix(out, name, names)
            save_result(result, prefix)
            _write_trajectories(prefix, dataset, result)
