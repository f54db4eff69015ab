"""The experiments behind the papers' tables and figures, as library calls.

Each runs what ``teamslam run`` (or ``teamslam fej``) would run, with settings resolved from
the data (:func:`teamslam.msckf.configure.build_settings`), and returns plain numbers:
:func:`kitti_pair`, :func:`team_pairs`, :func:`loss_sweep`, :func:`fej_experiment`. Each is also an
:class:`Experiment` (its independent tasks and how its result is built from theirs), so that
:func:`run_experiments` runs the tasks of many in one process pool, longest first, each task
once; the results do not depend on the number of workers.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

from teamslam.errors import InputError

__all__ = [
    "FEJ_RUNS_PER_TASK",
    "TEAM_FILTERS",
    "Experiment",
    "PaperSettings",
    "fej_experiment",
    "kitti_experiment",
    "kitti_pair",
    "loss_experiment",
    "loss_sweep",
    "run_experiments",
    "settings_summary",
    "stage_statistics",
    "task_label",
    "team_experiment",
    "team_pairs",
    "victoria_park_experiment",
]

#: The two filters of every distributed-MSCKF table: without and with consensus averaging.
TEAM_FILTERS = ("separate", "consensus")

# what a team run's metrics keep for the tables and figures
_KEPT = (
    "trajectory_rmse_m",
    "trajectory_rmse_avg_m",
    "odometry_rmse_m",
    "object_error_m",
    "object_error_avg_m",
    "object_disagreement_m",
    "object_disagreement_avg_m",
    "time_per_robot_step_ms",
    "frames_per_robot",
    "nees_pose_avg",
)


@dataclass(frozen=True)
class PaperSettings:
    """How large the experiments are.

    Attributes
    ----------
    team_sizes
        Robots of the simulated teams (DVI Table IV and Fig. 4; the paper: 3, 5, 10, 15).
    seeds
        Simulated teams per size (different maps, paths and noise), averaged.
    steps
        Motion steps of each simulated robot.
    loss_rates
        Link loss rates of DVI Fig. 4.
    fej_runs
        Monte Carlo runs per FEJ environment and feature count (the paper: 100).
    fej_features
        Feature counts of the FEJ environments (the paper: 20, 60, 100).
    frames
        Only the first ``frames`` frames of each robot of the real data (``None``: all).
    workers
        Processes for the parallel runs (``None``: all cores).
    scheduler
        The address of a Dask scheduler to run every task on instead (the ``cluster`` extra).
    progress
        Progress bars (``None``: when standard error is a terminal).
    label
        A name for the output (``full``, ``quick``, ``custom``).
    """

    team_sizes: tuple[int, ...] = (3, 5, 10, 15)
    seeds: int = 3
    steps: int = 300
    loss_rates: tuple[float, ...] = (0.0, 0.3, 0.6, 0.9)
    fej_runs: int = 100
    fej_features: tuple[int, ...] = (20, 60, 100)
    frames: int | None = None
    workers: int | None = None
    progress: bool | None = None
    label: str = "full"
    scheduler: str | None = None

    def __post_init__(self) -> None:
        if not self.team_sizes or min(self.team_sizes) < 2:
            raise InputError("team sizes must be at least 2 robots")
        if self.seeds < 1 or self.steps < 2 or self.fej_runs < 1:
            raise InputError("seeds and Monte Carlo runs must be ≥ 1, steps ≥ 2")
        if not self.loss_rates or not all(0.0 <= r <= 1.0 for r in self.loss_rates):
            raise InputError("loss rates must be in [0, 1]")
        if not set(self.fej_features) <= {20, 60, 100}:
            raise InputError("FEJ feature counts are 20, 60 or 100")
        if self.frames is not None and self.frames < 2:
            raise InputError("frames must be at least 2")

    @classmethod
    def quick(cls, **changes) -> PaperSettings:
        """Fewer Monte Carlo runs and seeds, shorter simulated teams: every table and figure
        in minutes (what ``--quick`` runs)."""
        base = {
            "seeds": 1,
            "steps": 60,
            "loss_rates": (0.0, 0.5, 0.9),
            "fej_runs": 10,
            "label": "quick",
        }
        return cls(**{**base, **changes})

    def describe(self) -> str:
        """One line: the sizes used."""
        frames = "all frames" if self.frames is None else f"first {self.frames} frames"
        return (
            f"{self.label}: simulated teams of {', '.join(map(str, self.team_sizes))} robots, "
            f"{self.steps} steps, {self.seeds} seed(s); loss rates "
            f"{', '.join(f'{r:g}' for r in self.loss_rates)}; FEJ {self.fej_runs} Monte Carlo "
            f"runs (paper: 100); real data: {frames}"
        )


def _kept(metrics: dict) -> dict:
    return {k: metrics[k] for k in _KEPT}


def stage_statistics(result) -> dict[str, list[float]]:
    """Per stage and ``total``: mean, median and 95th percentile of the ms per robot per frame
    of a :class:`~teamslam.msckf.team.TeamResult` (frame 0 excluded)."""
    import numpy as np

    from teamslam.eval.runs import STAGES

    times = 1e3 * np.concatenate([f[1:] for f in result.frame_times])  # (robot-steps, stages)
    columns = {s: times[:, k] for k, s in enumerate(STAGES)}
    columns["total"] = times.sum(axis=1)
    return {
        s: [float(c.mean()), float(np.median(c)), float(np.percentile(c, 95))]
        for s, c in columns.items()
    }


def _team_run(dataset, mode: str, effective, loss: float = 0.0, seed: int = 0) -> dict:
    from teamslam import api

    run = api.run(dataset, mode=mode, settings=effective, loss=loss, seed=seed, progress=False)
    return {**_kept(run.by_mode[mode]), "stage_ms": stage_statistics(run.results[mode])}


def settings_summary(dataset, effective) -> str:
    """The settings that matter for the tables, and where they came from."""
    config = effective.config
    sources = effective.sources
    tracks = sum(r.features.ids.size for r in dataset.robots)
    features = "on" if config.filter.use_geometric_features else "off"
    parts = [
        f"window {config.filter.window} ({sources.get('filter.window', 'default')})",
        f"geometric features {features}" if tracks else "no geometric features in the data",
        f"noise levels from the {sources.get('odometry_std', 'default')}",
    ]
    return ", ".join(parts)


# ---------------------------------------------------------------------- experiments as tasks
# Every experiment is a list of tasks and a function building its result from theirs, so that
# the tasks of several experiments share one process pool (:func:`run_experiments`). A task's
# key names everything its result depends on: two experiments listing the same key (the
# separate filters of Table IV and of Fig. 4) run it once. The costs only order the tasks
# (longest chain first); they are estimates in robot-frames of the MSCKF.


@dataclass
class Experiment:
    """The tasks of an experiment and how its result is built from their results.

    Attributes
    ----------
    tasks
        :class:`~teamslam.eval.schedule.Task` objects.
    collect
        Called with every task's result (``{key: result}``); returns the experiment's result.
    """

    tasks: list
    collect: Callable[[dict], Any]


def run_experiments(
    experiments: dict[str, Experiment],
    workers: int | None = None,
    progress: bool | None = None,
    description: str = "experiments",
    scheduler: str | None = None,
    store=None,
):
    """The tasks of all ``experiments`` in one process pool (or on the Dask cluster of
    ``scheduler``), longest chain first, each task once, each kept in ``store`` as it
    finishes and read back from it when it holds it (:func:`teamslam.eval.schedule.run_tasks`).

    Returns
    -------
    results, schedule
        Per experiment name its result, and the :class:`~teamslam.eval.schedule.Schedule`.
    """
    from teamslam.eval.schedule import run_tasks

    tasks: dict = {}
    for experiment in experiments.values():
        for task in experiment.tasks:
            tasks.setdefault(task.key, task)
    done, schedule = run_tasks(tasks.values(), workers, progress, description, scheduler, store)
    return {name: e.collect(done) for name, e in experiments.items()}, schedule


def task_label(key: tuple) -> str:
    """A task's key for people: its parts without directories and empty settings."""
    parts = [p for p in key if not (isinstance(p, str) and ("/" in p or p == "[]"))]
    return " ".join(str(p) for p in parts if p is not None)


def _settings_key(settings: dict | None) -> str:
    return repr(sorted((settings or {}).items()))


#: estimated cost of a consensus run against a separate one, per robot-frame
_CONSENSUS_COST = 2.0
#: estimated calibration passes (each a separate filter over the calibration frames)
_CALIBRATION_PASSES = 6


def _team_cost(robots: int, frames: int, mode: str) -> float:
    return robots * frames * (_CONSENSUS_COST if mode == "consensus" else 1.0)


def _reference_frames(directory: Path, frames: int | None) -> tuple[int, int]:
    """Robots and frames per robot of a published team directory (for the cost estimates)."""
    from teamslam.textio import open_npz

    try:
        with open_npz(directory / "poses.npz") as poses:
            lengths = [poses[k].shape[0] for k in poses.files]
    except (OSError, ValueError):
        lengths = [1]  # the import will say what is wrong
    longest = max(lengths) if frames is None else min(max(lengths), frames)
    return len(lengths), longest


def _kitti_prepare(directory: Path, frames: int | None, settings: dict | None):
    from teamslam.datasets import import_reference
    from teamslam.msckf.configure import build_settings

    dataset = import_reference(directory)
    if frames is not None:
        dataset = dataset.head(frames)
    return dataset, build_settings(dataset, flags=settings)


def _kitti_run(prepared, mode: str) -> dict:
    dataset, effective = prepared
    return _team_run(dataset, mode, effective)


@dataclass
class KittiPair:
    """Separate and consensus on the KITTI 00 team: per filter the run's metrics."""

    metrics: dict[str, dict]
    settings: str
    frames: list[int] = field(default_factory=list)


def kitti_experiment(
    directory: str | Path, frames: int | None = None, settings: dict | None = None
) -> Experiment:
    """:func:`kitti_pair` as tasks: the import and the settings (with the noise calibration)
    once, then the two filters on the imported team."""
    from teamslam.eval.schedule import Task
    from teamslam.msckf.calibration import default_frames

    directory = Path(directory)
    base = ("kitti", str(directory), frames, _settings_key(settings))
    robots, length = _reference_frames(directory, frames)
    calibration = _CALIBRATION_PASSES * robots * min(length, default_frames(robots))
    prepare = Task(
        (*base, "prepare"), partial(_kitti_prepare, directory, frames, settings), cost=calibration
    )
    runs = [
        Task(
            (*base, mode),
            partial(_kitti_run, mode=mode),
            cost=_team_cost(robots, length, mode),
            needs=prepare.key,
        )
        for mode in TEAM_FILTERS
    ]

    def collect(done: dict) -> KittiPair:
        dataset, effective = done[prepare.key]
        return KittiPair(
            {mode: done[(*base, mode)] for mode in TEAM_FILTERS},
            settings_summary(dataset, effective),
            [r.frames for r in dataset.robots],
        )

    return Experiment([prepare, *runs], collect)


def kitti_pair(
    directory: str | Path,
    frames: int | None = None,
    settings: dict | None = None,
    workers: int | None = None,
    progress: bool | None = None,
) -> KittiPair:
    """Separate and consensus MSCKFs on a published team directory (KITTI 00), as ``teamslam
    data import-reference`` + ``teamslam run --compare`` would run them.

    Parameters
    ----------
    directory
        The published data (``calib``, ``inputs.npz``, ``poses.npz``, …).
    frames
        Only the first ``frames`` frames of each robot.
    settings
        Filter settings on top of those resolved from the data (``{group.name: value}``, as
        ``--set``).
    workers, progress
        The two filters run in parallel (:func:`run_experiments`).
    """
    experiment = kitti_experiment(directory, frames, settings)
    return run_experiments({"kitti": experiment}, workers, progress, "KITTI 00")[0]["kitti"]


def _simulated(robots: int, steps: int, seed: int):
    from teamslam.sim import lissajous_team

    return lissajous_team(robots=robots, steps=steps, seed=seed)


def _pair_job(case: tuple, steps: int, settings: dict | None) -> dict:
    from teamslam.msckf.configure import build_settings

    robots, seed, mode, loss = case
    dataset = _simulated(robots, steps, seed)
    effective = build_settings(dataset, flags=settings)
    out = _team_run(dataset, mode, effective, loss=loss, seed=1)
    out["settings"] = settings_summary(dataset, effective)
    return out


def _case_tasks(cases, steps: int, settings: dict | None) -> dict[tuple, Any]:
    """Per case ``(robots, seed, mode, loss)`` of a simulated team its task."""
    from teamslam.eval.schedule import Task

    return {
        case: Task(
            ("team", *case, steps, _settings_key(settings)),
            partial(_pair_job, case, steps, settings),
            cost=_team_cost(case[0], steps, case[2]),
        )
        for case in cases
    }


def team_experiment(
    team_sizes: Sequence[int], seeds: int, steps: int, settings: dict | None = None
) -> Experiment:
    """:func:`team_pairs` as tasks: one per team size, seed and filter."""
    cases = [(n, s, m, 0.0) for n in team_sizes for s in range(seeds) for m in TEAM_FILTERS]
    tasks = _case_tasks(cases, steps, settings)

    def collect(done: dict) -> dict[int, dict[str, list[dict]]]:
        out: dict[int, dict[str, list[dict]]] = {
            n: {m: [] for m in TEAM_FILTERS} for n in team_sizes
        }
        for case, task in tasks.items():
            out[case[0]][case[2]].append(done[task.key])
        return out

    return Experiment(list(tasks.values()), collect)


def team_pairs(
    team_sizes: Sequence[int],
    seeds: int,
    steps: int,
    settings: dict | None = None,
    workers: int | None = None,
    progress: bool | None = None,
) -> dict[int, dict[str, list[dict]]]:
    """Separate and consensus MSCKFs on simulated Lissajous teams (complete graph, no loss).

    Returns
    -------
    dict
        Per team size, per filter (``separate``, ``consensus``) the metrics of each seed.
    """
    experiment = team_experiment(team_sizes, seeds, steps, settings)
    return run_experiments({"teams": experiment}, workers, progress, "simulated teams")[0]["teams"]


def loss_experiment(
    team_sizes: Sequence[int],
    rates: Sequence[float],
    steps: int,
    seed: int = 0,
    settings: dict | None = None,
) -> Experiment:
    """:func:`loss_sweep` as tasks: one per team size and rate, and the separate filters."""
    cases = [(n, seed, "separate", 0.0) for n in team_sizes]
    cases += [(n, seed, "consensus", float(r)) for n in team_sizes for r in rates]
    tasks = _case_tasks(cases, steps, settings)

    def collect(done: dict) -> dict[int, dict[str, Any]]:
        out: dict[int, dict[str, Any]] = {n: {"consensus": {}} for n in team_sizes}
        for (n, _, mode, r), task in tasks.items():
            if mode == "separate":
                out[n]["separate"] = done[task.key]
            else:
                out[n]["consensus"][r] = done[task.key]
        return out

    return Experiment(list(tasks.values()), collect)


def loss_sweep(
    team_sizes: Sequence[int],
    rates: Sequence[float],
    steps: int,
    seed: int = 0,
    settings: dict | None = None,
    workers: int | None = None,
    progress: bool | None = None,
) -> dict[int, dict[str, Any]]:
    """Consensus on simulated teams when each link is lost at each step with probability ``r``
    (complete graph), and the separate filters for reference.

    Returns
    -------
    dict
        Per team size: ``separate`` (metrics) and ``consensus`` (rate → metrics).
    """
    experiment = loss_experiment(team_sizes, rates, steps, seed, settings)
    return run_experiments({"loss": experiment}, workers, progress, "link loss")[0]["loss"]


@dataclass
class FejTables:
    """FEJ Monte Carlo of one environment: per feature count the result, and where each
    environment came from."""

    results: dict[int, Any]
    sources: dict[int, str]
    published: dict[int, bool]


#: Monte Carlo runs per FEJ task
FEJ_RUNS_PER_TASK = 5


def _fej_environment(env: int, count: int, data: str | Path | None):
    """The environment of ``env`` with ``count`` features, and whether it is the paper's own."""
    from teamslam import api

    files: tuple[Path, ...] = ()
    if data is not None:
        folder = Path(data) / "fej-environments"
        pair = (
            folder / f"RobotsWaypoints_{env}.mat",
            folder / f"CheckedTrueState_{count}features_{env}.mat",
        )
        files = pair if all(f.is_file() for f in pair) else ()
    source = (
        "the published environment files " + " + ".join(f.name for f in files)
        if files
        else f"our generated environment {env} with the paper's parameters"
    )
    return api.fej_environment(env, count, files), source, bool(files)


def fej_experiment(
    env: int, features: Sequence[int], runs: int, data: str | Path | None = None, seed: int = 0
) -> Experiment:
    """Monte Carlo of the standard, ideal and FEJ EKFs on FEJ environment ``env`` for each
    feature count, as tasks: the runs of each count in parts of :data:`FEJ_RUNS_PER_TASK` runs.

    Where ``data/fej-environments`` holds the paper's own environment files for a feature
    count they are used; otherwise the generated environment with the paper's parameters.
    """
    from teamslam.ekf2d.experiments import run_seeds, run_seeds_of, summarise_runs
    from teamslam.eval.schedule import Task

    seeds = run_seeds_of(runs, seed)
    environments = {count: _fej_environment(env, count, data) for count in features}
    parts: dict[int, list] = {}
    for count, (environment, _, _) in environments.items():
        base = ("fej", env, count, str(data), seed)
        parts[count] = [
            Task(
                (*base, chunk[0], len(chunk)),
                partial(run_seeds, chunk, environment),
                # per run: the three EKFs over every robot and feature at every step
                cost=3 * environment.steps * (environment.n_robots + count) / 600,
            )
            for chunk in (
                seeds[k : k + FEJ_RUNS_PER_TASK] for k in range(0, runs, FEJ_RUNS_PER_TASK)
            )
        ]

    def collect(done: dict) -> FejTables:
        results = {
            count: summarise_runs(
                environments[count][0], [r for t in parts[count] for r in done[t.key]]
            )
            for count in features
        }
        return FejTables(
            results,
            {count: e[1] for count, e in environments.items()},
            {count: e[2] for count, e in environments.items()},
        )

    return Experiment([t for tasks in parts.values() for t in tasks], collect)


def _victoria_park(path: Path) -> tuple[dict, bytes]:
    import tempfile

    from teamslam import api

    with tempfile.TemporaryDirectory() as tmp:
        summary = api.victoria_park(path, out=tmp)
        return summary, (Path(tmp) / "victoria_park.png").read_bytes()


def victoria_park_experiment(path: str | Path) -> Experiment:
    """The std and FEJ EKFs on the Victoria Park split (:func:`teamslam.api.victoria_park`):
    one task; its result is the summary and the figure's PNG."""
    from teamslam.eval.schedule import Task

    task = Task(("victoria-park", str(path)), partial(_victoria_park, Path(path)), cost=1.0)
    return Experiment([task], lambda done: done[task.key])
